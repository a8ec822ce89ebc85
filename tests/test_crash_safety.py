"""No data lost, no actuator left driven: the gateway killed (-9), terminated, or dead before
its first command; the recorder and the capture killed mid-write.

The gateway runs as ``stand run`` in its own process; a sniffer in the test process sees the
bus, and the test reads the run directory the way a user would (``load_run``).
"""
from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import can
import numpy as np
import pytest

from dbc import profile as P
from gateway import load_run
from gateway.capture import TappedNetwork, read_capture
from gateway.master import NMT_START, StandMaster
from standbus import open_bus
from tests.support.faults import LOAD_ALLOWANCE_S, Sniffer, log_reaction, valve_state
from tests.support.stand import BASE, plant

pytestmark = pytest.mark.serial   # on the wall clock: runs alone (scripts/test)

#: the valve's RPDO timeout (0x1400:05, as the gateway writes it) + watchdog poll + deferral, s
VALVE_BOUND_S = 0.100 + 0.005 + 0.020


def stand_run(bus_spec: str, out: Path, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "stand", "run", "meander", "--amplitude-pct", "5", "--period-s", "1",
           "--cycles", "100", "--settle-max-s", "0", "--bus", bus_spec, "--out", str(out), "--no-progress",
           *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def active_commands(sniffer: Sniffer) -> list[tuple[float, int]]:
    out = []
    for f in list(sniffer.frames):
        if f.arbitration_id == 0x201 and len(f.data) == 4:
            cw, sp = struct.unpack("<Hh", bytes(f.data))
            if cw == int(P.CW_ACTIVE):
                out.append((f.timestamp, sp))
    return out


def wait_running(sniffer: Sniffer, gateway: subprocess.Popen, seconds: float) -> None:
    first = sniffer.wait_for(lambda m: m.arbitration_id == 0x201 and m.data[:1] == b"\x07", 30)
    assert first is not None, gateway.communicate(timeout=5)[0] if gateway.poll() is not None else "no command"
    time.sleep(seconds)


def sync_answers(bus, n: int = 1, pause: float = 0.0) -> list[dict]:
    """Send SYNCs from the test and collect the two nodes' TPDOs (the valve's status word and
    spool, the force counts)."""
    out = []
    for _ in range(n):
        while bus.recv(0) is not None:
            pass
        got = {}
        deadline = time.monotonic() + 5
        while len(got) < 2 and time.monotonic() < deadline:
            # again while unanswered: a node that got to a SYNC later than its synchronous
            # window (0x1007, set by the run) discards its answer, as it should on a stall
            got = {}
            bus.send(can.Message(arbitration_id=0x80, data=b"\x01", is_extended_id=False))
            until = time.monotonic() + 0.3
            while len(got) < 2 and time.monotonic() < until:
                m = bus.recv(0.05)
                if m is not None and m.arbitration_id in (0x181, 0x182):
                    got[m.arbitration_id] = bytes(m.data)
        assert len(got) == 2, f"no answer to 5 s of SYNCs: {sorted(got)}"
        status, spool = struct.unpack("<Hh", got[0x181])
        force = struct.unpack_from("<i", got[0x182])[0]
        out.append({"status": status, "spool": spool, "force_counts": force})
        time.sleep(pause)
    return out


@pytest.mark.slow
@pytest.mark.e2e
def test_gateway_killed_mid_run_loses_at_most_the_last_half_second_and_the_valve_fails_safe(
        bus_spec, start_emulator, tmp_path):
    start_emulator(plant(BASE, model="base"), lockstep=False, seed=1)
    out = tmp_path / "run"
    with Sniffer(bus_spec) as sniffer:
        gw = stand_run(bus_spec, out)
        try:
            wait_running(sniffer, gw, 1.6)
            t_kill = time.time()
            os.kill(gw.pid, signal.SIGKILL)
            gw.wait(10)
            emcy = sniffer.wait_for(lambda m: m.arbitration_id == 0x81 and m.data[:2] == b"\x50\x82", 3.0)
        finally:
            if gw.poll() is None:
                gw.kill()
        commands = active_commands(sniffer)
    assert emcy is not None, "the valve reported its RPDO timeout (EMCY 0x8250)"
    last_command = max(ts for ts, _ in commands)
    valve_reaction = emcy.timestamp - last_command
    assert 0.1 <= valve_reaction <= VALVE_BOUND_S + LOAD_ALLOWANCE_S
    log_reaction("gateway killed (-9): valve RPDO timeout → FAULT_HOLD + EMCY", valve_reaction, VALVE_BOUND_S,
                 reason="EMCY 0x8250", measured_from="last command on the bus")

    # the run directory opens and holds every cycle up to the last flush
    run = load_run(out)
    assert run.recovered and run.meta["status"] == "running"
    n = len(run)
    assert np.array_equal(run.cycle, np.arange(n))
    # every command on the wire more than the flush interval before the kill has its row (the
    # first active command is the enable, before cycle 0)
    flushed = sum(1 for ts, _ in commands[1:] if ts < t_kill - 0.5 - LOAD_ALLOWANCE_S)
    assert n >= flushed > 0, (n, flushed)
    assert run.sync_time[-1] >= t_kill - 0.5 - LOAD_ALLOWANCE_S
    log_reaction("gateway killed (-9): newest recovered row before the kill", t_kill - run.sync_time[-1], 0.5,
                 reason="recorder flush", rows=n)
    # ... and they are what went on the wire: row k's command is the k-th command after the enable
    wire = np.array([sp for _, sp in commands[1:n + 1]])
    assert np.array_equal(wire, np.round(run.u * P.COUNTS_PER_PERCENT).astype(int))
    # the capture is readable, ends with a whole line, and reaches to within its flush interval
    raw = (out / "capture.log").read_bytes()
    assert raw.endswith(b"\n")
    frames = list(read_capture(out / "capture.log"))
    assert frames[-1].timestamp >= t_kill - 0.25 - LOAD_ALLOWANCE_S
    assert len(list(can.LogReader(str(out / "capture.log")))) == len(frames)

    # the valve no longer drives the actuator: FAULT_HOLD with zero spool, the force stands still
    bus = open_bus(bus_spec)
    try:
        a, b = sync_answers(bus, 2, pause=0.3)
    finally:
        bus.shutdown()
    assert a["status"] & 0xF == P.ValveState.FAULT_HOLD.value and a["spool"] == 0
    scale = run.meta["force_scale_kgf_per_count"]
    # 5 % would move it by 120 · 5 · 0.3 = 180 kgf; zero flow leaves the trend Δ·0.3 s and noise
    assert abs(b["force_counts"] - a["force_counts"]) * scale < 30.0


@pytest.mark.e2e
def test_a_gateway_that_dies_before_its_first_command_is_caught_by_the_valve(bus_spec, start_emulator):
    start_emulator(plant(BASE, model="base"), lockstep=False, seed=2)
    with Sniffer(bus_spec) as sniffer:
        net = TappedNetwork(open_bus(bus_spec))
        net.connect()
        try:
            master = StandMaster(net, 1, 2)
            master.boot()
            master.configure(0.002, 100, 100)
            t_start = time.time()
            for link in master.links:                 # NMT start, and then ... nothing
                link.node.nmt.send_command(NMT_START)
        finally:
            net.disconnect()
        emcy = sniffer.wait_for(lambda m: m.arbitration_id == 0x81 and m.data[:2] == b"\x50\x82", 3.0)
        assert not [f for f in sniffer.frames if f.arbitration_id == 0x201], "no command was ever sent"
    assert emcy is not None
    measured = emcy.timestamp - t_start
    assert 0.1 <= measured <= VALVE_BOUND_S + LOAD_ALLOWANCE_S
    assert valve_state(bus_spec) == P.ValveState.FAULT_HOLD
    log_reaction("gateway dead before its first command: valve RPDO timeout", measured, VALVE_BOUND_S,
                 reason="EMCY 0x8250", measured_from="NMT start")


@pytest.mark.slow
@pytest.mark.e2e
def test_sigterm_ends_the_run_cleanly_in_the_safe_state(bus_spec, start_emulator, tmp_path):
    start_emulator(plant(BASE, model="base"), lockstep=False, seed=3)
    out = tmp_path / "run"
    with Sniffer(bus_spec) as sniffer:
        gw = stand_run(bus_spec, out)
        wait_running(sniffer, gw, 1.0)
        t_term = time.time()
        gw.send_signal(signal.SIGTERM)
        text = gw.communicate(timeout=30)[0]
        safe = sniffer.wait_for(lambda m: m.arbitration_id == 0x201 and m.timestamp >= t_term
                                and bytes(m.data) == struct.pack("<Hh", int(P.CW_HOLD), 0), 2.0)
    assert gw.returncode == 130, text
    assert "interrupted" in text and "Traceback" not in text
    run = load_run(out)
    assert not run.recovered and (out / "signals.parquet").exists() and not (out / "signals.arrows").exists()
    assert run.meta["status"] == "aborted" and run.meta["end_reason"] == "interrupted"
    assert run.sync_time[-1] >= t_term - 0.05
    assert safe is not None
    measured = safe.timestamp - t_term
    assert measured <= 0.002 + LOAD_ALLOWANCE_S
    log_reaction("SIGTERM to `stand run`", measured, 0.002, reason="interrupted")


# -- the recorder and the capture, killed mid-write ---------------------------------------------------
RECORDER_CHILD = textwrap.dedent("""
    import sys, time
    from gateway.recorder import RunRecorder
    rec = RunRecorder(sys.argv[1], {"experiment": {"name": "test", "params": {}}})
    k = 0
    print("recording", flush=True)
    while True:
        rec.append(k * 0.002, 1.0, float(k), float("nan"), k, k, 0.0, 15, False, time.time())
        k += 1
        time.sleep(0.0005)
""")


def test_recorder_killed_mid_run_keeps_every_row_up_to_the_last_flush(tmp_path):
    out = tmp_path / "run"
    child = subprocess.Popen([sys.executable, "-c", RECORDER_CHILD, str(out)], stdout=subprocess.PIPE,
                             text=True, cwd=Path(__file__).resolve().parents[1])
    assert child.stdout.readline().strip() == "recording"
    time.sleep(1.7)
    t_kill = time.time()
    child.kill()
    child.wait(10)
    run = load_run(out)
    assert run.recovered and any("recovered" in note for note in run.notes)
    n = len(run)
    assert n > 0 and np.array_equal(run.cycle, np.arange(n)) and np.array_equal(run.y, np.arange(n, dtype=float))
    # the rows reach to the last flush: their count depends on how often the host ran the child
    assert run.sync_time[-1] >= t_kill - 0.5 - LOAD_ALLOWANCE_S
    assert run.meta["status"] == "running"


CAPTURE_CHILD = textwrap.dedent("""
    import sys, time, can
    from gateway.capture import BusCapture
    blf = can.Logger(sys.argv[1] + ".blf")
    cap = BusCapture(sys.argv[1] + ".log")
    print("capturing", flush=True)
    for i in range(1500):
        m = can.Message(arbitration_id=0x182, data=i.to_bytes(4, "little") + b"\\0",
                        is_extended_id=False, timestamp=time.time())
        blf.on_message_received(m)
        cap.on_message_received(m)
        time.sleep(0.0005)
    print("done", time.time(), flush=True)
    time.sleep(60)
""")


def test_candump_capture_survives_a_kill_where_blf_keeps_nothing(tmp_path):
    """1,500 frames, then kill -9: the candump log has them all (flushed every 0.25 s, whole
    lines); python-can's BLF writer had them in its unwritten 128 KiB container."""
    base = tmp_path / "cap"
    child = subprocess.Popen([sys.executable, "-c", CAPTURE_CHILD, str(base)], stdout=subprocess.PIPE,
                             text=True, cwd=Path(__file__).resolve().parents[1])
    assert child.stdout.readline().strip() == "capturing"
    assert child.stdout.readline().startswith("done")
    time.sleep(0.25 + LOAD_ALLOWANCE_S)
    child.kill()
    child.wait(10)
    frames = list(read_capture(base.with_suffix(".log")))
    assert [int.from_bytes(f.data[:4], "little") for f in frames] == list(range(1500))
    try:
        blf = list(can.LogReader(str(base.with_suffix(".blf"))))
    except Exception:
        blf = []
    assert blf == []


def test_read_capture_drops_a_partial_last_line(tmp_path):
    path = tmp_path / "c.log"
    path.write_text("(1.000000) stand0 182#0102030405 R\n(1.002000) stand0 182#0102030405 R\n(1.004000) stand0 18")
    frames = list(read_capture(path))
    assert len(frames) == 2 and bytes(frames[-1].data) == b"\x01\x02\x03\x04\x05"
    path.write_text("(1.000000) stand0 182#0102030405 R\n(1.004000) stand0 182#01020")
    assert len(list(read_capture(path))) == 1
    plain = list(can.LogReader(str(path)))  # a plain reader makes a wrong frame of the stump
    assert len(plain) == 2 and bytes(plain[-1].data) == b"\x01\x02\x00"
