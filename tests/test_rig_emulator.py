"""``stand emulate --rig``: one process serving every channel of a rig on every one of its
buses, the coupled plant behind them. End to end: the emulator is a separate process on real
loopback buses, driven frame by frame by a minimal master (tests/support/rig.py)."""
from __future__ import annotations

import re
import subprocess
import sys
import time

import canopen
import numpy as np
import pytest

from dbc import DYNAMOMETER_EDS, VALVE_EDS
from dbc import profile as P
from plant_emulator.lockstep_plant import LockstepRig
from plant_emulator.process import RigEmulatorProcess
from rig.config import load_rig_file
from rig.emulated import emulated_plant
from tests.support.rig import RigMaster, example_rig_text, with_spare_bus, write_rig

pytestmark = pytest.mark.e2e
T = 0.002
ALL = ("root", "inner", "outer", "tip")


def identity_of(eds) -> tuple[int, int]:
    info = canopen.import_od(str(eds)).device_information
    return info.vendor_number, info.product_number


def test_every_node_of_every_channel_boots_and_identifies_over_sdo_on_its_own_bus(start_rig_emulator, channel):
    # the second bus's channels on node ids 11-14: a node answering on the wrong bus would show
    text = example_rig_text(channel)
    for name, (v, d) in {"outer": (11, 12), "tip": (13, 14)}.items():
        text, n = re.subn(rf'(name = "{name}"\nbus = "can1"\n)valve_id = \d+\ndynamometer_id = \d+',
                          rf"\1valve_id = {v}\ndynamometer_id = {d}", text)
        assert n == 1
    path = start_rig_emulator(text)
    with RigMaster(path) as master:
        assert master.reset_and_collect_boot_ups() == {"can0": {1, 2, 3, 4}, "can1": {11, 12, 13, 14}}
        for c in master.rig.channels:
            assert master.identity(c.bus, c.valve_id) == identity_of(VALVE_EDS), c.name
            assert master.identity(c.bus, c.dynamometer_id) == identity_of(DYNAMOMETER_EDS), c.name
        for bus, stranger in (("can0", 11), ("can1", 1)):
            with pytest.raises(canopen.SdoCommunicationError):
                master.sdo_upload(bus, stranger, P.IDENTITY, 1, timeout_s=0.3)


def offline_forces(path, commands: list[dict[str, float]]) -> np.ndarray:
    """The forces the rig's plant gives, cycle by cycle, for the commands sent after each
    cycle's answers (the first answer is the initial force): what lockstep must reproduce."""
    rig = load_rig_file(path)
    plant = emulated_plant(rig)
    lockstep = LockstepRig(plant.model, plant.initial_forces_kgf, 0.0005)
    out = [list(plant.initial_forces_kgf)]
    for cmd in commands:
        spool = [P.counts_to_percent(P.percent_to_counts(cmd[n])) for n in rig.names]
        out.append(list(lockstep.step(T, spool)))
    return np.array(out)


def test_in_lockstep_the_plant_advances_once_every_buses_sync_of_the_cycle_came(start_rig_emulator, channel):
    """Cycles 1-60 back to back; then a cycle whose SYNC comes on can0 only (no answer on
    either bus, and none while it waits), completed by can1's; one the other way round; and
    three SYNCs on can0 before three on can1 (three cycles, one at each of can1's). Every
    answer is the offline plant's force after exactly one more period, on all four channels
    (the dynamometers without noise: readings to 0.1 N). A third bus without channels gets no
    SYNC at all: a cycle does not wait for it."""
    path = start_rig_emulator(with_spare_bus(example_rig_text(channel, quiet=True), channel))
    drive = {"root": 10.0, "inner": 0.0, "outer": -4.0, "tip": 0.0}
    commands = []
    with RigMaster(path) as master:
        master.start()
        got = []
        for _ in range(60):
            got.append(master.cycle(drive))
            commands.append(drive)
        for first, then in (("can0", "can1"), ("can1", "can0")):
            master.sync([first])
            assert master.answers(timeout_s=0.3) == {}, f"answered on {first}'s SYNC alone"
            master.sync([then])
            got.append(master.answers())
            master.command(drive)
            commands.append(drive)
        for _ in range(3):
            master.sync(["can0"])
        assert master.answers(timeout_s=0.3) == {}
        for _ in range(3):
            master.sync(["can1"])
            got.append(master.answers())
            master.command(drive)
            commands.append(drive)
        assert master.answers(timeout_s=0.3) == {}, "can0's surplus SYNCs made an extra cycle"
    readings = np.array([[g[n].force_kgf for n in ALL] for g in got])
    want = offline_forces(path, commands)[:len(readings)]
    assert np.max(np.abs(readings - want)) < 0.011, np.abs(readings - want).max(axis=0)
    assert readings[-1, 0] > 50 and readings[-1, 2] < -10     # root pushed, outer pulled


def test_driving_one_channel_moves_its_neighbours_at_the_rate_G_says_and_two_away_not(start_rig_emulator):
    """The example rig as it is (noise 1.5-2 kgf): inner's valve at +10 %, the others at zero
    command. Over 0.6 s from 0.2 s on, each force's rate is G[:, inner]·u + Δ within five
    standard errors of its slope: root (same bus) and outer (the other bus) at 30 % of inner's
    rate, tip (two away) only its own trend, zero."""
    path = start_rig_emulator()
    drive = {"root": 0.0, "inner": 10.0, "outer": 0.0, "tip": 0.0}
    with RigMaster(path) as master:
        master.start()
        got = [master.cycle(drive) for _ in range(400)]
    y = np.array([[g[n].force_kgf for n in ALL] for g in got[100:]])
    t = np.arange(len(y)) * T
    rig = load_rig_file(path)
    u = P.counts_to_percent(P.percent_to_counts(10.0))
    deltas = np.array([c.plant.model.delta for c in rig.channels])
    want = rig.G[:, 1] * u + deltas
    for i, name in enumerate(ALL):
        slope, intercept = np.polyfit(t, y[:, i], 1)
        resid = y[:, i] - (slope * t + intercept)
        se = resid.std(ddof=2) / (t.std() * np.sqrt(len(t)))
        assert abs(slope - want[i]) < 5 * se + 1e-6, (name, slope, want[i], se)
    # what was checked: neighbours at 30 % of inner's own gain, tip not coupled to it at all
    assert rig.G[0, 1] == rig.G[2, 1] == pytest.approx(0.3 * rig.G[1, 1]) and want[3] == 0.0


def test_a_channel_whose_commands_stop_faults_alone_and_the_others_go_on(start_rig_emulator):
    """Lockstep: tip's commands stop after cycle 20. 100 ms of stand time later (its RPDO
    timeout) tip's valve alone sends EMCY 0x8250 and reports FAULT_HOLD with its spool at
    zero; the three others stay ACTIVE and root's force keeps rising."""
    path = start_rig_emulator()
    drive = {"root": 5.0, "inner": 0.0, "outer": 0.0, "tip": 3.0}
    with RigMaster(path) as master:
        master.start()
        for _ in range(20):
            master.cycle(drive)
        without_tip = {k: v for k, v in drive.items() if k != "tip"}
        states = []
        for _ in range(80):
            a = master.cycle(without_tip)
            states.append((a["tip"].valve_state, a["root"].force_kgf))
        master.drain(0.1)
        last = master.cycle(without_tip)
    faulted = [k for k, (s, _) in enumerate(states) if s is P.ValveState.FAULT_HOLD]
    assert faulted and 49 <= faulted[0] <= 51, faulted[:1]   # 100 ms = 50 periods after the last command
    assert master.emcys == [("can1", 3, P.EMCY_RPDO_TIMEOUT)]
    assert last["tip"].valve_state is P.ValveState.FAULT_HOLD and last["tip"].spool_pct == 0.0
    for name in ("root", "inner", "outer"):
        assert last[name].valve_state is P.ValveState.ACTIVE, name
    rising = [f for _, f in states[faulted[0]:]]
    assert last["root"].force_kgf > rising[0] + 10


@pytest.mark.serial
def test_in_real_time_a_silent_master_leaves_every_valve_of_every_bus_safe(start_rig_emulator):
    """Real time: the master commands every valve, then goes silent. Each valve's own RPDO
    watchdog (100 ms) brings it to FAULT_HOLD with EMCY 0x8250, on both buses; a SYNC on one
    bus is then answered on that bus only, sampled on the wall clock."""
    path = start_rig_emulator(lockstep=False)
    with RigMaster(path) as master:
        master.start()
        master.command({n: 1.0 for n in ALL})
        silent = time.monotonic()
        deadline = silent + 2.0
        while len(master.emcys) < 4 and time.monotonic() < deadline:
            master.drain(0.01)
        took = time.monotonic() - silent
        assert sorted(master.emcys) == [("can0", 1, P.EMCY_RPDO_TIMEOUT), ("can0", 3, P.EMCY_RPDO_TIMEOUT),
                                        ("can1", 1, P.EMCY_RPDO_TIMEOUT), ("can1", 3, P.EMCY_RPDO_TIMEOUT)]
        assert 0.1 <= took <= 0.125 + 0.25, took
        master.sync(["can0"])
        answers = master.answers(timeout_s=0.5)
        assert set(answers) == {"root", "inner"}
        assert all(a.valve_state is P.ValveState.FAULT_HOLD for a in answers.values())


def test_the_rig_truth_is_the_structure_and_each_channels_plant(tmp_path, channel):
    path = write_rig(tmp_path / "rig.toml", example_rig_text(channel))
    truth = RigEmulatorProcess(path).truth()
    assert truth["channels"] == list(ALL) and truth["structure_from"] == "K"
    assert np.allclose(np.diag(truth["G"]), [120, 100, 140, 110])
    assert truth["plants"]["tip"]["params"]["tau"] == 0.055
    assert truth["plants"]["outer"]["sensor"]["range_kgf"] == 5000


def test_the_one_channel_options_are_refused_beside_a_rig(tmp_path, channel):
    path = write_rig(tmp_path / "rig.toml", example_rig_text(channel))
    res = subprocess.run([sys.executable, "-m", "stand", "emulate", "--rig", str(path), "--bus",
                          "udp_loopback:x", "--set", "g=3"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and res.stdout == ""
    assert "--rig takes the buses, node ids and plants from the rig file: leave out --bus, --set" in res.stderr


def test_an_emulated_structure_that_is_not_physical_is_refused_at_start(tmp_path, channel):
    # outer and tip pushing each other more than themselves: no positive definite stiffness
    text = (example_rig_text(channel).replace("[ 0.0,  3.0, 10.0,  3.0]", "[ 0.0,  3.0, 10.0, 12.0]")
            .replace("[ 0.0,  0.0,  3.0, 10.0]", "[ 0.0,  0.0, 12.0, 10.0]"))
    path = write_rig(tmp_path / "bad.toml", text)
    res = subprocess.run([sys.executable, "-m", "stand", "emulate", "--rig", str(path), "--lockstep"],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "cannot be emulated" in res.stderr and "not positive definite" in res.stderr
    assert res.stdout == ""                               # refused before any bus was served


@pytest.mark.serial
def test_in_real_time_the_plants_blocks_are_computed_between_cycles_not_at_a_sync(tmp_path, channel):
    """Real time: the coupled plant's blocks (a transport delay's steps computed at once) are
    computed at the quiet moments between a cycle's commands and its next SYNC, so no SYNC's
    answers wait for one; the forces still follow the commands. In process, on the rig's
    loopback buses, a master sending a SYNC and every command each 2 ms for 1.2 s."""
    from plant_emulator.emulated_rig import EmulatedRig, EmulatorOptions
    from standbus import open_bus
    rig = load_rig_file(write_rig(tmp_path / "rig.toml", example_rig_text(channel, quiet=True)))
    buses = {b.name: open_bus(b.spec) for b in rig.buses}
    try:
        emu = EmulatedRig.from_rig(buses, rig, EmulatorOptions(lockstep=False, seed=1))
        with emu, RigMaster(rig) as master:
            master.start(T)
            start = time.perf_counter()
            for k in range(600):
                master.sync()
                master.drain(0.0003)
                master.command({"root": 20.0, "inner": 0.0, "outer": 0.0, "tip": 0.0})
                time.sleep(max(0.0, start + (k + 1) * T - time.perf_counter()))
            master.sync()
            answers = master.answers(timeout_s=0.5)
        plant = emu.realtime_plant
    finally:
        for bus in buses.values():
            bus.shutdown()
    assert plant.prefetched_blocks >= 10
    # most of them (without: none prefetched, 32 on demand; on a host busy with three
    # spinning processes: 27 and 8)
    assert plant.blocks_on_demand < plant.prefetched_blocks
    assert answers["root"].force_kgf > 100.0      # root's valve open: its force rose
