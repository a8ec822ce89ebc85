"""What took the per-frame and per-node Python out of a rig's cycle, checked for doing the same
as before: batch datagrams on the loopback bus (every receiver still sees every frame), the
captures' own candump lines (python-can's, byte for byte), the rig plant's grouped channels
(bit for bit the per-channel plant), the supervisors asked together (only when each would say
nothing), the emulator's RPDO values (what an SDO read returns), and a CAN FD rig end to end."""
from __future__ import annotations

import io
import random
import struct
import time
import uuid
from pathlib import Path

import can
import numpy as np
import pytest

from dbc import profile as P
from gateway.capture import CandumpLines
from plant.model import PlantModel
from plant.rig import RigModel
from standbus import wire
from standbus.loopback import LoopbackBus

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "rig.toml"


def frames_of(n: int, fd: bool = False) -> list[tuple[int, int, int, bytes]]:
    flags = (wire.FLAG_FD | wire.FLAG_BRS) if fd else 0
    return [(flags, 0x181 + i, 4 + i % 2, bytes(range(i, i + 4 + i % 2))) for i in range(n)]


def test_a_batch_reaches_a_python_can_receiver_frame_by_frame_in_order(channel):
    tx, rx = LoopbackBus(channel), can.Bus(interface="udp_loopback", channel=channel)
    try:
        stamp = tx.send_frames(frames_of(8))
        got = [rx.recv(2.0) for _ in range(8)]
        assert [m.arbitration_id for m in got] == [0x181 + i for i in range(8)]
        assert [bytes(m.data) for m in got] == [f[3] for f in frames_of(8)]
        assert all(m.timestamp == stamp and m.is_rx and not m.is_fd for m in got)
        assert rx.recv(0.05) is None
        # one frame alone is a version-1 datagram, as every frame was before
        tx.send_frames(frames_of(1))
        assert rx.recv(2.0).arbitration_id == 0x181
    finally:
        tx.shutdown(); rx.shutdown()


def test_raw_frames_keep_the_rules_own_frames_fd_and_oversized_classic(channel):
    tx, rx, classic = LoopbackBus(channel), LoopbackBus(channel), LoopbackBus(channel, fd=False)
    try:
        tx.send_frames(frames_of(3, fd=True))
        stamp, got = rx.recv_frames(2.0)
        assert got == frames_of(3, fd=True)
        assert tx.recv_frames(0.05) is None                 # a sender does not hear itself
        assert classic.recv_frames(0.05) is None            # FD frames never reach a classic bus
        bad = wire.pack_batch([(0, 0x181, 12, bytes(12)), (0, 0x182, 1, b"\x01")], 7, time.time())
        tx._send_datagram(bad, None)
        _, kept = rx.recv_frames(2.0)
        assert kept == [(0, 0x182, 1, b"\x01")] and rx.malformed_datagrams == 1
        with pytest.raises(can.CanOperationError):
            classic.send_frames(frames_of(1, fd=True))
    finally:
        tx.shutdown(); rx.shutdown(); classic.shutdown()


def test_malformed_batches_are_counted_not_delivered():
    good = wire.pack_batch(frames_of(3), 1, 2.0)
    for broken in (good[:-1], good + b"\x00", good[:3] + b"\x00" + good[4:]):
        with pytest.raises(wire.WireFormatError):
            wire.unpack_frames(broken)
    assert wire.unpack_frames(good) == (1, 2.0, frames_of(3))


def _kept_the_old_way(datagram: bytes, fd: bool):
    """The receive path before unpack_for_bus: unpack_frames, then the bus's rules per frame."""
    sender, stamp, frames = wire.unpack_frames(datagram)
    kept, oversized = [], 0
    for frame in frames:
        if frame[0] & wire.FLAG_FD:
            if fd:
                kept.append(frame)
        elif len(frame[3]) > 8:
            oversized += 1
        else:
            kept.append(frame)
    return sender, stamp, kept, oversized


def test_unpacking_for_a_bus_in_one_pass_is_unpacking_then_the_rules():
    """wire.unpack_for_bus (the receive path) against unpack_frames and the bus's rules after
    it, on 3,000 random datagrams: batches and single frames, FD frames, classic frames over 8
    bytes, and every kind of damage (cut, lengthened, a byte changed). The same frames, the
    same count of oversized ones, and a malformed datagram refused by both."""
    rng = random.Random(41)
    for _ in range(3000):
        frames = []
        for _ in range(rng.randint(1, 6)):
            flags = rng.choice([0, 0, wire.FLAG_FD, wire.FLAG_FD | wire.FLAG_BRS, wire.FLAG_EXTENDED])
            n = rng.choice([0, 1, 4, 8, 8, 12, 64]) if flags & wire.FLAG_FD else rng.choice([0, 2, 4, 8, 12])
            frames.append((flags, rng.randrange(0x800), n if n <= 15 else 15, bytes(rng.randrange(256) for _ in range(n))))
        if len(frames) == 1:
            f = frames[0]
            datagram = wire.HEADER.pack(wire.MAGIC, wire.VERSION, f[0], 9, 3.0, f[1], f[2], len(f[3])) + f[3]
        else:
            datagram = wire.pack_batch(frames, 9, 3.0)
        damage = rng.random()
        if damage < 0.15:
            datagram = datagram[:rng.randrange(len(datagram))]
        elif damage < 0.2:
            datagram += bytes(rng.randint(1, 3))
        elif damage < 0.3:
            k = rng.randrange(len(datagram))
            datagram = datagram[:k] + bytes((rng.randrange(256),)) + datagram[k + 1:]
        for fd in (False, True):
            try:
                want = _kept_the_old_way(datagram, fd)
            except wire.WireFormatError:
                with pytest.raises(wire.WireFormatError):
                    wire.unpack_for_bus(datagram, fd)
                continue
            assert wire.unpack_for_bus(datagram, fd) == want


def test_candump_lines_are_python_cans_byte_for_byte():
    rng = random.Random(3)
    msgs = []
    for k in range(400):
        kind = rng.random()
        fd = kind < 0.3
        msgs.append(can.Message(
            timestamp=1_700_000_000 + k * 0.001 - (0.5 if k % 97 == 5 else 0.0),   # some go back
            arbitration_id=rng.randrange(1 << 29) if kind > 0.9 else rng.randrange(0x800),
            is_extended_id=kind > 0.9, is_remote_frame=0.85 < kind <= 0.9,
            is_error_frame=0.8 < kind <= 0.85, is_fd=fd, bitrate_switch=fd and rng.random() < 0.5,
            error_state_indicator=fd and rng.random() < 0.2,
            data=rng.randbytes(rng.choice((0, 1, 4, 8, 12, 64) if fd else (0, 1, 4, 5, 8))),
            channel=rng.choice(("can0", "bench-B", 3, None)), is_rx=rng.random() < 0.5, check=False))
    theirs = io.StringIO()
    writer = can.io.CanutilsLogWriter(theirs)
    ours = CandumpLines()
    out = []
    for m in msgs:
        writer.on_message_received(m)
        out.append(ours.lines(m.timestamp, m.channel, [wire.raw_of(m)], m.is_rx))
    assert "".join(out) == theirs.getvalue()


def _chain(models: list[PlantModel]) -> RigModel:
    n = len(models)
    return RigModel(models, 100.0 * (np.eye(n) + 0.3 * (np.eye(n, k=1) + np.eye(n, k=-1))))


@pytest.mark.parametrize("specs", [
    ["base+reversal"] * 8,                                    # one group
    ["base+reversal", "base+reversal+lag"] * 3,               # two groups
    ["base+backlash+reversal+sensor_lag"] * 4 + ["base"],     # a sensor effect, one alone
    ["base+stiffness+reversal"] * 4,                          # the force-dependent integration
])
def test_grouped_channels_are_the_per_channel_plant_bit_for_bit(specs):
    models = [PlantModel.from_spec(s, {}).with_params({"delta": 2.0 * i})
              for i, s in enumerate(specs)]
    rig = _chain(models)
    rng = np.random.default_rng(1)
    u = np.sign(rng.normal(size=(rig.n, 300))) * rng.uniform(0.5, 8, size=(rig.n, 1))
    alone = RigModel(rig.channels, rig.G)
    alone.groups = [[i] for i in range(rig.n)]
    assert len(rig.groups) < rig.n
    s1, s2 = rig.new_state(0.0005, 50.0), alone.new_state(0.0005, 50.0)
    for k in range(0, 300, 60):
        a = rig.advance(s1, u[:, k:k + 60], 0.0005)
        b = alone.advance(s2, u[:, k:k + 60], 0.0005)
        assert np.array_equal(a, b)
    for x, y in zip(s1, s2):             # and every channel's state is its own, equal
        assert np.array_equal(x.y, y.y) and np.array_equal(x.history, y.history)
        assert np.array_equal(x.reading, y.reading)


def test_the_supervisors_together_are_quiet_only_when_each_would_say_nothing():
    from gateway import SafetyLimits
    from gateway.capture import TappedNetwork
    from gateway.master import StandMaster
    from gateway.supervisor import Supervisor, SupervisorBank
    sups = []
    for k in range(6):
        master = StandMaster(TappedNetwork(None), 2 * k + 1, 2 * k + 2)
        sups.append(Supervisor(master, SafetyLimits(force_limit_kgf=5000.0), 0.002))
    bank = SupervisorBank(sups)
    rng = random.Random(5)
    for trial in range(3000):
        now = time.monotonic()
        for s in sups:
            s.reset()
            s._stale_run = int(rng.random() < 0.03)
            s._inactive_run = int(rng.random() < 0.03)
            if rng.random() < 0.03:
                s._indicated.add("force_limit")
            if rng.random() < 0.02:
                s._emcy.append(("EMCY", now))
            for link in s.master.links:
                link.last_heartbeat = None if rng.random() < 0.01 else now - rng.choice((0.0, 0.1, 0.45, 3.0))
                link.nmt_state = 5 if rng.random() > 0.02 else 127
        ys = [rng.choice((0.0, 4000.0, 4800.0, -5200.0, float("nan"))) if rng.random() < 0.1
              else rng.uniform(-4000, 4000) for _ in sups]
        statuses = [rng.choice((0x0F, 0x0F, 0x0F, 0x0B, 0x03, 0x0)) if rng.random() < 0.1 else 0x0F
                    for _ in sups]
        before = [(s._stale_run, s._inactive_run, set(s._indicated)) for s in sups]
        quiet = bank.quiet(ys, statuses)
        each = [s.check(y, False, st, 0.0) for s, y, st in zip(sups, ys, statuses)]
        if quiet:
            assert all(t is None for t in each), trial
            assert before == [(s._stale_run, s._inactive_run, s._indicated) for s in sups], trial


def test_a_held_command_is_shaped_as_every_command_is():
    """Supervisor.shape_command returns a command asked for again at once when it passed
    unchanged the time before: on random sequences (repeats, values beyond the limit, NaN,
    infinities, a slew limit or none, a smaller declared maximum, resets) every result, the
    count of shaped commands and the last command are those of the full rule."""
    import math
    from gateway import SafetyLimits
    from gateway.capture import TappedNetwork
    from gateway.master import StandMaster
    from gateway.supervisor import Supervisor

    def full(sup, u, state):             # the rule as written before the shortcut
        u_in, u_max = u, sup.u_max
        if not (-u_max <= u <= u_max):
            u = max(-u_max, min(u_max, u)) if math.isfinite(u) else 0.0
        if sup.limits.slew_pct_per_s:
            step = sup.limits.slew_pct_per_s * sup.period_s
            u = max(state["last"] - step, min(state["last"] + step, u))
        if u != u_in:
            state["clamped"] += 1
        state["last"] = u
        return u

    rng = random.Random(11)
    master = StandMaster(TappedNetwork(None), 1, 2)
    for slew in (None, 50.0, 5000.0):
        sup = Supervisor(master, SafetyLimits(force_limit_kgf=5000.0, slew_pct_per_s=slew), 0.002)
        for trial in range(200):
            sup.reset(rng.choice((None, None, 20.0, 80.0)))
            state = {"last": 0.0, "clamped": 0}
            u = 0.0
            for _ in range(60):
                if rng.random() < 0.4:       # a new command, else the last one again
                    u = rng.choice((rng.uniform(-150, 150), rng.uniform(-5, 5), 0.0, -0.0, 100.0,
                                    float("nan"), float("inf"), -float("inf")))
                got, want = sup.shape_command(u), full(sup, u, state)
                assert got == want or (math.isnan(got) and math.isnan(want)), (slew, trial, u)
                assert sup.clamped == state["clamped"] and sup._last_u == state["last"]


def test_an_sdo_read_of_a_commanded_object_returns_the_last_rpdo_then_the_sdo_write():
    from plant_emulator import EmulatedStand, EmulatorOptions
    from tests.support.stand import plant
    channel = f"rpdo-{uuid.uuid4().hex[:8]}"
    bus, master = can.Bus(interface="virtual", channel=channel), can.Bus(interface="virtual", channel=channel)
    stand = EmulatedStand(bus, plant(), EmulatorOptions(lockstep=True, seed=1))
    stand.start()
    try:
        valve = stand.valve
        setpoint = lambda: valve.local.sdo[P.SETPOINT[0]][P.SETPOINT[1]].raw
        default = setpoint()
        master.send(can.Message(arbitration_id=0, data=[1, 0], is_extended_id=False))   # NMT start
        deadline = time.monotonic() + 2
        while not valve.operational and time.monotonic() < deadline:
            time.sleep(0.01)
        master.send(can.Message(arbitration_id=0x200 + valve.id, is_extended_id=False,
                                data=struct.pack("<Hh", int(P.CW_ACTIVE), 1234)))
        deadline = time.monotonic() + 2
        while valve.setpoint_counts != 1234 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert valve.setpoint_counts == 1234 and setpoint() == 1234 == valve.value(*P.SETPOINT)
        valve.local.sdo[P.SETPOINT[0]][P.SETPOINT[1]].raw = -77        # an SDO write wins
        assert setpoint() == -77 == valve.value(*P.SETPOINT)
        master.send(can.Message(arbitration_id=0x200 + valve.id, is_extended_id=False,
                                data=struct.pack("<Hh", int(P.CW_ACTIVE), 99)))
        deadline = time.monotonic() + 2
        while setpoint() != 99 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert setpoint() == 99
        master.send(can.Message(arbitration_id=0, data=[0x81, valve.id], is_extended_id=False))
        deadline = time.monotonic() + 2
        while setpoint() != default and time.monotonic() < deadline:
            time.sleep(0.01)
        assert setpoint() == default                                  # reset node: the EDS's
    finally:
        stand.stop(); bus.shutdown(); master.shutdown()


@pytest.mark.e2e
def test_a_can_fd_rig_runs_in_lockstep_with_fd_frames_and_fits_twice_the_channels(tmp_path):
    """8 chain channels on one CAN FD bus (1/5 Mbit/s; a classic bus carries 4): the budget
    lets them run, the cyclic frames on the wire are FD with the bit-rate switch on both sides,
    every cycle fresh."""
    from gateway import Gateway, GatewayConfig, load_run
    from gateway.experiments import Meander
    from plant_emulator.process import RigEmulatorProcess
    from rig.budget import bus_budgets
    from rig.chain import chain_rig
    from rig.config import load_rig_file
    from rig.files import rig_to_toml
    template = load_rig_file(EXAMPLE).channels[0]
    tag = f"fd-{uuid.uuid4().hex[:6]}"
    rig = chain_rig(template, 8, 1, tag=tag, data_bitrate=5_000_000)
    (budget,) = bus_budgets(rig)
    assert budget.fits and budget.max_channels >= 8
    assert not bus_budgets(chain_rig(template, 8, 1, tag=tag))[0].fits
    path = tmp_path / "fd.toml"
    path.write_text(rig_to_toml(rig, path=path))
    rig = load_rig_file(path)
    with RigEmulatorProcess(path, lockstep=True, seed=1), \
            Gateway(GatewayConfig(rig=rig, lockstep=True)) as gw:
        result = gw.run(Meander(5, 1.0, 1), tmp_path / "run", progress=False, channels=[rig.names[0]])
    assert result.status == "complete"
    run = load_run(tmp_path / "run")
    assert not any(run.signals[f"stale.{n}"].any() for n in rig.names)
    frames = list(can.LogReader(str(tmp_path / "run" / "capture-can0.log")))
    cyclic = [f for f in frames if f.arbitration_id == 0x80 or 0x180 < f.arbitration_id < 0x280]
    assert len(cyclic) >= 25 * len(run) and all(f.is_fd and f.bitrate_switch for f in cyclic)
    assert np.ptp(run.signals[f"y.{rig.names[0]}"]) > 100
