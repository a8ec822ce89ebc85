"""The benchmark command still works (``scripts/bench --quick``): a smoke run that catches a
broken benchmark. It judges nothing about speed: these machines are shared and noisy."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.runner import discover

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.e2e


#: a figure each benchmark's rows must name (what a reader of docs/benchmarks.md looks for)
FIGURES = {
    "control_loop": ("cycles/s", "round trips/s", "SYNC jitter", "where the time goes",
                     "cycle times", "bare UDP round trip"),
    "wakeup": ("host floor",),
    "rig": ("rig lockstep", "x real time", "SYNC jitter", "skew between the buses' SYNCs",
            "host floor", "rig unload keeping the ratios"),
    "campaign": ("x real time",),
    "decode": ("frames/s", "past start-up"),
    "diagnosis": ("stand diagnose",),
    "stepwise": ("one fit of",),
    "bus": ("frames/s", "round trips/s"),
    "bus_budget": ("% bus load",),
    "rig_one_run": ("one run", "per column", "simultaneous", "multisine", "inside their 95 % intervals",
                    "the plan"),
    "crack": ("crack: intact", "runs with an alarm", "false alarms, thresholds for 1 in",
              "3 % at inner from flight 120", "name inner first"),
}


def test_every_benchmark_has_its_smoke_run():
    assert set(FIGURES) <= set(discover())


# one test per benchmark, so the test processes share them out (together they took 14 min in
# one process of a CI run)
@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(discover()))
def test_the_benchmark_runs_in_quick_mode_and_prints_its_rows(name):
    res = subprocess.run([sys.executable, "-m", "benchmarks.runner", "--quick", name], cwd=ROOT,
                         capture_output=True, text=True, timeout=850)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    table = res.stdout
    assert f"running {name}" in res.stderr
    assert "FAILED" not in table
    assert sum(line.startswith("| ") for line in table.splitlines()) >= 2, table  # head + rows
    for figure in FIGURES.get(name, ()):
        assert figure in table, figure


def test_a_late_cycle_is_put_on_the_host_only_when_a_bare_thread_was_late_then_too():
    from benchmarks.wakeup import at_host_stalls
    host = [(100.000, 0.004), (200.0, 0.001)]          # (scheduled wall time, lateness), s
    loop = [(100.002, 0.006),                          # inside the first host stall
            (99.990, 0.009),                           # ran into it
            (100.0055, 0.001),                         # 1.5 ms after it ended: within 2 ms
            (150.0, 0.010),                            # the host was on time: ours
            (200.0035, 0.001)]                         # 2.5 ms after the second ended
    assert at_host_stalls(loop, host) == 3
    assert at_host_stalls(loop, []) == 0


def test_the_round_trip_floor_gives_up_with_a_reason_when_the_echo_process_does_not_answer(monkeypatch):
    from benchmarks import control_loop
    monkeypatch.setattr(control_loop, "_echo_datagrams", lambda *args: None)   # exits at once
    with pytest.raises(RuntimeError, match="answered only 0 of 110 round trips in 0.5 s"):
        control_loop.bare_round_trips(10, timeout_s=0.5)
    monkeypatch.undo()
    rate, how = control_loop.bare_round_trips(300, timeout_s=60)   # and works with one that does
    assert rate > 0 and how in ("polling", "sleeping")


def test_cycle_spread_reads_the_sync_intervals_of_a_capture_and_their_tail(tmp_path):
    import can
    from benchmarks.control_loop import SYNC_ID, cycle_spread, send_stamps
    path = tmp_path / "capture.log"
    gaps = [50e-6] * 9 + [200e-6]                     # nine cycles of 50 µs, one of 200 µs
    t = 1_700_000_000.0
    with can.Logger(str(path)) as log:
        for gap in [0.0] + gaps:
            t += gap
            log.on_message_received(can.Message(timestamp=t, arbitration_id=SYNC_ID, data=b"",
                                                is_extended_id=False))
            log.on_message_received(can.Message(timestamp=t + 10e-6, arbitration_id=0x181,
                                                data=bytes(4), is_extended_id=False))
    spread = cycle_spread(*send_stamps(str(path)))
    assert abs(spread["p50"] - 50) < 2
    assert abs(spread["mean"] - 65) < 2
    assert abs(spread["tail_share"] - 200 / 650) < 0.01
