"""Fuzzing the frame decoders (hypothesis): the loopback wire format, the gateway's acceptance
filter with the canopen stack, heartbeat/EMCY/PDO handling behind it, and the whole control
loop against a peer that answers SYNC with random process data and sprays garbage.

Properties: nothing raises, only well-formed frames from the configured nodes are acted on,
and every command on the wire is the experiment's command as shaped by the supervisor or the
safe command — never anything else.
"""
from __future__ import annotations

import math
import os
import random
import struct
import threading
import time
import uuid

import can
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dbc import profile as P
from gateway.capture import TappedNetwork
from gateway.experiments import Experiment
from gateway.loop import ControlLoop
from gateway.master import StandMaster
from gateway.supervisor import SafetyLimits, Supervisor
from standbus import wire
from standbus.faults import canopen_protected, garbage_frame
from standbus.loopback import LoopbackBus, _open_socket

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# -- the wire format ------------------------------------------------------------------------------
@FUZZ
@given(st.binary(max_size=120))
def test_wire_unpack_takes_any_bytes(data):
    try:
        msg, sender = wire.unpack(data)
    except wire.WireFormatError:
        return
    assert len(msg.data) <= 64 and 0 <= msg.arbitration_id < 2**32


@FUZZ
@given(flags=st.integers(0, 0x3F), arb=st.integers(0, 2**32 - 1), dlc=st.integers(0, 255),
       payload=st.binary(max_size=64), sender=st.integers(0, 2**64 - 1),
       ts=st.floats(allow_nan=False, allow_infinity=False))
def test_wire_round_trips_every_header_it_accepts(flags, arb, dlc, payload, sender, ts):
    datagram = wire.HEADER.pack(wire.MAGIC, wire.VERSION, flags, sender, ts, arb, dlc, len(payload)) + payload
    msg, got_sender = wire.unpack(datagram)
    assert got_sender == sender
    if flags & wire.FLAG_REMOTE and payload:
        assert len(msg.data) == 0, "a remote frame carries no data, whatever the datagram says"
        return
    assert wire.pack(msg, sender, ts) == datagram


def test_the_bus_survives_random_datagrams_at_a_high_rate(channel):
    """30,000 datagrams of junk and mutated frames into a bus socket: each is counted as
    malformed or delivered as a frame; the bus keeps working."""
    rx = LoopbackBus(channel)
    raw = _open_socket(rx.group, rx.port)
    rng = random.Random(1)
    good = wire.pack(can.Message(arbitration_id=0x182, data=bytes(5), is_extended_id=False), 7, time.time())
    received = malformed_sent = 0
    try:
        for i in range(30000):
            if i % 2:
                d = bytearray(good)
                for _ in range(rng.randrange(1, 4)):
                    d[rng.randrange(len(d))] = rng.randrange(256)
                d = bytes(d[:rng.randrange(len(d) + 1)]) if rng.random() < 0.3 else bytes(d)
            else:
                d = rng.randbytes(rng.randrange(0, 100))
            try:
                wire.unpack(d)
                if len(wire.unpack(d)[0].data) > 8 and not wire.unpack(d)[0].is_fd:
                    malformed_sent += 1
            except wire.WireFormatError:
                malformed_sent += 1
            raw.sendto(d, (rx.group, rx.port))
            if i % 500 == 0:                       # drain so the socket buffer never overflows
                while rx.recv(0) is not None:
                    received += 1
        deadline = time.monotonic() + 3
        while time.monotonic() < deadline:
            m = rx.recv(0.2)
            if m is None:
                break
            received += 1
        raw.sendto(good, (rx.group, rx.port))
        last = rx.recv(2.0)
    finally:
        raw.close()
        rx.shutdown()
    assert rx.malformed_datagrams == malformed_sent
    assert received + malformed_sent == 30000
    assert last is not None and last.arbitration_id == 0x182


# -- the gateway's frame handling ----------------------------------------------------------------------
def _stand():
    net = TappedNetwork(None)
    master = StandMaster(net, 1, 2)
    master.configure_from_eds()
    sup = Supervisor(master, SafetyLimits(), 0.002)
    loop = ControlLoop(net, master, sup, 0.002, lockstep=True)
    loop._subscribe()
    return net, master, sup, loop


_STAND = _stand()
STAND_IDS = [0x000, 0x080, 0x081, 0x082, 0x181, 0x182, 0x201, 0x281, 0x282, 0x581, 0x582, 0x601,
             0x602, 0x701, 0x702, 0x083, 0x183, 0x703, 0x7E4]

frames = st.builds(
    lambda cid, ext, data, dlc_off, remote, err, fd: can.Message(
        arbitration_id=cid, is_extended_id=ext, data=data, dlc=len(data) + dlc_off,
        is_remote_frame=remote, is_error_frame=err, is_fd=fd, check=False),
    st.one_of(st.sampled_from(STAND_IDS), st.integers(0, 0x7FF), st.integers(0, 2**29 - 1)),
    st.booleans(), st.binary(max_size=8), st.sampled_from([0, 0, 0, 0, 1, -1]),
    st.booleans(), st.booleans(), st.booleans())


@settings(max_examples=400, deadline=None)
@given(st.lists(frames, max_size=40))
def test_only_well_formed_frames_of_the_two_nodes_are_acted_on(batch):
    net, master, sup, loop = _STAND
    flt = net.frame_filter
    before = flt.counts()
    emcy_before = len(sup.emcy_log)
    while not loop._arrivals.empty():
        loop._arrivals.get()
    for link in master.links:
        link.nmt_state = link.last_heartbeat = None
    valid = []
    for m in batch:
        flt.on_message_received(m)
        classic = not (m.is_extended_id or m.is_remote_frame or m.is_error_frame or m.is_fd)
        if classic and m.dlc == len(m.data):
            valid.append(m)
    after = flt.counts()
    assert after["errors"] == before["errors"], "a consumer raised"
    # PDOs: exactly the frames on the TPDO ids with the mapped size reach the loop
    sizes = {0x181: master.valve_tpdo.size, 0x182: master.force_tpdo.size}
    pdos = [m for m in valid if sizes.get(m.arbitration_id) == len(m.data)]
    got = []
    while not loop._arrivals.empty():
        got.append(loop._arrivals.get())
    assert [cob for cob, _, _ in got] == [m.arbitration_id for m in pdos]
    for (cob, values, _), m in zip(got, pdos):
        layout = master.force_tpdo if cob == 0x182 else master.valve_tpdo
        assert values == layout.decode(m.data)
    # EMCYs: only 8-byte frames from nodes 1 and 2
    emcys = [m for m in valid if m.arbitration_id in (0x81, 0x82) and len(m.data) == 8]
    assert len(sup.emcy_log) - emcy_before == len(emcys)
    # heartbeats: the last 1-byte frame of each node decides its state
    for link in master.links:
        beats = [m for m in valid if m.arbitration_id == 0x700 + link.id and len(m.data) == 1]
        assert link.nmt_state == (beats[-1].data[0] & 0x7F if beats else None)
    dropped = sum(after[k] - before[k] for k in ("not_classic", "unexpected_id", "wrong_dlc"))
    rules = net.frame_filter.rules
    acted = [m for m in valid if m.arbitration_id in rules and
             (rules[m.arbitration_id] is None or len(m.data) in rules[m.arbitration_id])]
    assert dropped == len(batch) - len(acted)
    sup.reset()


# -- the whole loop against a fuzzing peer ----------------------------------------------------------------
class Scripted(Experiment):
    """Returns a given command sequence (may hold NaN, inf, huge values) and remembers it."""

    name = "scripted"

    def __init__(self, commands):
        self.commands = list(commands)
        self.returned = []

    @property
    def duration_s(self):
        return len(self.commands) * 0.002

    def params(self):
        return {}

    def finished(self, t, y):
        return len(self.returned) >= len(self.commands)

    def step(self, t, y):
        u = self.commands[len(self.returned)]
        self.returned.append(u)
        return u, math.nan


class FuzzPeer(threading.Thread):
    """Answers each SYNC like the stand (valve and force TPDOs with random content) and sprays
    garbage frames around them; records every valve command it hears."""

    def __init__(self, bus, master, forces, statuses, garbage_per_sync, seed):
        super().__init__(daemon=True)
        self.bus, self.master = bus, master
        self.forces, self.statuses = forces, statuses
        self.garbage_per_sync = garbage_per_sync
        self.rng = random.Random(seed)
        self.protected = canopen_protected((1, 2), {0x181: master.valve_tpdo.size,
                                                    0x182: master.force_tpdo.size})
        self.commands: list[tuple[int, int]] = []
        self.stop = threading.Event()

    def send(self, cid, data):
        self.bus.send(can.Message(arbitration_id=cid, data=data, is_extended_id=False))

    def run(self):
        k = 0
        vt, ft = self.master.valve_tpdo, self.master.force_tpdo
        self.send(0x701, b"\x05"); self.send(0x702, b"\x05")
        while not self.stop.is_set():
            m = self.bus.recv(0.05)
            if m is None:
                continue
            if m.arbitration_id == 0x201 and len(m.data) == 4:
                self.commands.append(struct.unpack("<Hh", bytes(m.data)))
            if m.arbitration_id != 0x080:
                continue
            for _ in range(self.garbage_per_sync):
                self.bus.send(garbage_frame(self.rng, self.protected))
            if k % 20 == 0:
                self.send(0x701, b"\x05"); self.send(0x702, b"\x05")
            status = self.statuses[k % len(self.statuses)]
            self.send(0x181, vt.encode(*(status if key == (P.STATUS_WORD, 0) else 0 for key in vt.keys)))
            force = self.forces[k % len(self.forces)]
            self.send(0x182, ft.encode(*(force if key == P.PV_INT32 else 0 for key in ft.keys)))
            if self.rng.random() < 0.2:                      # a duplicate with a wrong length
                self.send(0x182, self.rng.randbytes(self.rng.choice([0, 1, 4, 8])))
            k += 1


def expected_shape(u: float, limit: float) -> int:
    if not math.isfinite(u):
        return 0
    return P.percent_to_counts(max(-limit, min(limit, u)))


commands = st.lists(st.one_of(st.floats(-1000, 1000), st.sampled_from([math.nan, math.inf, -math.inf, 1e300])),
                    min_size=1, max_size=150)
forces = st.lists(st.one_of(st.integers(-90_000, 90_000), st.integers(-2**31, 2**31 - 1)), min_size=1, max_size=20)
statuses = st.lists(st.one_of(st.just(P.ValveState.ACTIVE.value), st.integers(0, 0xFFFF)), min_size=1, max_size=5)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(commands=commands, forces=forces, statuses=statuses, garbage=st.integers(0, 6),
       action=st.sampled_from(["hold", "zero", "indicate"]), seed=st.integers(0, 1000))
def test_every_command_on_the_wire_is_the_shaped_one_or_the_safe_one(commands, forces, statuses,
                                                                     garbage, action, seed):
    channel = f"fuzz-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    gw_bus = can.Bus(interface="virtual", channel=channel)
    peer_bus = can.Bus(interface="virtual", channel=channel)
    net = TappedNetwork(gw_bus)
    net.connect()
    master = StandMaster(net, 1, 2)
    master.configure_from_eds()
    limits = SafetyLimits(force_limit_kgf=1000.0, force_action=action, command_limit_pct=50.0)
    loop = ControlLoop(net, master, Supervisor(master, limits, 0.002), 0.002, lockstep=True,
                       lockstep_timeout_s=1.0)
    peer = FuzzPeer(peer_bus, master, forces, statuses, garbage, seed)
    peer.start()
    try:
        deadline = time.monotonic() + 2
        while any(l.nmt_state != 5 for l in master.links) and time.monotonic() < deadline:
            time.sleep(0.002)
        exp = Scripted(commands)
        outcome = loop.run(exp, None)
        time.sleep(0.02)
    finally:
        peer.stop.set()
        peer.join()
        loop.close()
        net.disconnect()
        peer_bus.shutdown()
    sent = peer.commands
    assert sent[0] == (P.CW_ACTIVE, 0), "the valve is enabled with a zero command"
    active = [c for c in sent[1:] if c[0] == P.CW_ACTIVE]
    n = len(active)
    assert n <= len(exp.returned)
    assert [c[1] for c in active] == [expected_shape(u, 50.0) for u in exp.returned[:n]]
    assert all(c[0] == P.CW_ACTIVE for c in sent[:n + 1]), "no safe command between shaped ones"
    tail = sent[n + 1:]
    assert tail and all(c[1] == 0 and c[0] in (P.CW_HOLD, P.CW_DISABLED) for c in tail)
    if outcome.status == "complete":
        assert n == len(commands)
    else:
        assert outcome.reason in {"force_limit", "valve_fault", "valve_not_active", "no_answer_to_sync",
                                  "heartbeat_lost", "nmt_state", "emcy"}, outcome
        if outcome.reason == "force_limit":
            assert action in ("hold", "zero")
            assert tail[0][0] == (P.CW_DISABLED if action == "zero" else P.CW_HOLD)
