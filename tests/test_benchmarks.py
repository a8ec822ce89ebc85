"""The benchmark command still works (``scripts/bench --quick``): a smoke run of seconds per
benchmark that catches a broken benchmark. It judges nothing about speed (these machines are
shared and noisy), but it does read the table: every row there, every figure a number, and the
figures that do not depend on the host's speed (accuracies, lockstep runs, identified models)
plausible."""
from __future__ import annotations

import os
import re
import signal
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
    "confusion": ("confusion matrix of stepwise", "spurious effects in single-effect cells",
                  "overdamped resonances reported"),
    "bus": ("frames/s", "round trips/s"),
    "bus_budget": ("% bus load",),
    "live": ("live page: loop cycle, no page", "viewers against none", "stream updates a viewer got"),
    "rig_one_run": ("one run", "per column", "simultaneous", "multisine", "inside their 95 % intervals",
                    "the plan"),
    "endurance": ("flights counted through a kill -9", "turning-point log", "integrity_check"),
    "crack": ("crack: intact", "runs with an alarm", "false alarms, thresholds for 1 in",
              "3 % at inner from flight 120", "name inner first"),
}


#: the rows of each benchmark's quick table
ROWS = {"control_loop": 6, "wakeup": 1, "rig": 9, "campaign": 1, "decode": 6, "loading": 8,
        "faster": 9, "diagnosis": 2, "stepwise": 2, "confusion": 4, "rig_identify": 4,
        "rig_load": 11, "bus": 2, "bus_budget": 2, "crack": 6, "live": 4, "rig_one_run": 11,
        "endurance": 2}

_NUMBER = r"[-+]?(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?:e[-+]?\d+)?"


def rows_of(table: str) -> list[list[str]]:
    """The table's rows (without its head), each as its five cells."""
    lines = [line for line in table.splitlines() if line.startswith("| ")][1:]
    return [[cell.strip() for cell in line.strip()[1:-1].split(" | ")] for line in lines]


def figures(text: str, pattern: str) -> list[float]:
    """The numbers ``pattern`` finds in ``text``: each ``{n}`` in it is a number; all of a
    match's numbers, of every match, in order (``{n}`` lists such as ``0.16 / 0.11`` too)."""
    found = []
    for m in re.finditer(pattern.replace("{n}", f"({_NUMBER})"), text):
        found += [float(g.replace(",", "")) for g in m.groups()]
    assert found, f"{pattern!r} not in {text!r}"
    return found


def row(rows: list[list[str]], label: str) -> list[str]:
    """The one row whose benchmark cell starts with ``label``."""
    match = [r for r in rows if r[0].startswith(label)]
    assert len(match) == 1, (label, [r[0] for r in rows])
    return match[0]


def ordered(*values: float) -> bool:
    return all(a <= b for a, b in zip(values, values[1:]))


def _control_loop(rows):
    for label in ("lockstep HIL loop", "lockstep rig loop"):
        assert figures(row(rows, label)[1], r"{n} cycles/s")[0] > 0
    legs = figures(row(rows, "lockstep cycle: where")[1], r"(?:TPDO|RPDO|SYNC) {n}")
    # the emulator's two answers leave in one datagram, stamped alike: that leg may be 0
    assert len(legs) == 4 and all(v >= 0 for v in legs) and sum(legs) > 0, legs
    assert ordered(*figures(row(rows, "lockstep cycle times")[1], r"p50 {n} / p90 {n} / p99 {n}"))
    assert figures(row(rows, "floor: bare UDP")[1], r"{n} round trips/s")[0] > 0
    assert ordered(0, *figures(row(rows, "real-time loop")[1], r"p50 {n} / p99 {n} / max {n} ms"))


def _wakeup(rows):
    assert ordered(0, *figures(rows[0][1], r"p99 {n} / max {n} ms"))


def _rig(rows):
    assert figures(row(rows, "rig lockstep, 1 channel")[1], r"{n} cycles/s")[0] > 0
    rt = "rig real time, 4 channels on 2 buses at 2 ms, 1 busy process beside"
    for what in ("SYNC jitter", "skew"):
        assert ordered(0, *figures(row(rows, f"{rt}: {what}")[1], r"p50 {n} / p99 {n} / max {n} ms"))
    r = row(rows, f"{rt}: missed")
    missed, stale = figures(r[1], r"{n} missed, {n} % stale")
    assert missed >= 0 and 0 <= stale <= 100
    gaps, at_host = figures(r[4], r"the missed slots in {n} gap\(s\), {n} of them at one of the host's stalls")
    assert at_host <= gaps <= missed, r
    assert figures(row(rows, "stand demo --rig, 4 channel(s)")[1], r"{n}x real time")[0] > 0
    for case in ("all valves alive", "one valve dead"):     # lockstep: as in the full run
        r = row(rows, f"rig unload keeping the ratios, 6000/4000/5000/3000 kgf, {case}")
        assert 0 <= figures(r[1], r"largest deviation {n} %")[0] <= 2.0, r   # the goal
        assert "unloaded" in r[4], r


def _campaign(rows):
    stand_s, wall_s = figures(rows[0][1], r"{n} s stand time in {n} s wall")
    assert stand_s > 10 and wall_s > 0
    assert rows[0][4].endswith("complete"), rows[0]


def _decode(rows):
    for kind in ("log", "blf"):
        r = row(rows, f"decode .{kind}, every signal")
        assert figures(r[3], r"{n}x")[0] > 1, r            # vectorized beats frame by frame
        assert figures(row(rows, f"capture .{kind} -> run")[1], r"{n} frames/s")[0] > 0
    figures(row(rows, "stand decode")[3], r"{n}x whole, {n}x past start-up")
    small, big = figures(row(rows, "peak memory")[1], r"{n} MB \(")
    assert 0 < small < 500 and 0 < big < 500


def _designed_rows(rows, prefix):
    for label in ("designed, no compensation", "designed + compensation, pass 3"):
        r = row(rows, f"{prefix}{label}")
        p95, mx, rms = figures(r[1], r"p95 {n} %, max {n} %, RMS {n} %")
        assert 0 <= p95 <= mx < 5 and rms < 5, r


def _loading(rows):
    assert "reversal" in row(rows, "load, default stand: identified")[1]
    for label in ("P k = 0.005 (paper)", "designed from base alone"):
        figures(row(rows, f"load, default stand: {label}")[1], r"p95 {n} %, max {n} %")
    _designed_rows(rows, "load, default stand: ")
    ours, best_p = figures(row(rows, "load, default stand: RMS designed")[1], r"{n} % / {n} %")
    assert ours < best_p, (ours, best_p)                  # the designed controller beats P
    assert ordered(0, *figures(row(rows, "load, default stand: real time")[1],
                               r"p50 {n} / p99 {n} / max {n} ms"))


def _faster(rows):
    r = row(rows, "faster, default stand: programme at 2500")
    today, minimum = figures(r[1], r"{n} s vs {n} s")
    assert today >= minimum > 0, r
    figures(row(rows, "faster, default stand: one pass")[1], r"p95 {n} %, max {n} %")
    r = row(rows, "faster, default stand: --fastest schedule")
    assert figures(r[1], r"= {n}x the minimum")[0] >= 0.99, r
    assert figures(row(rows, "faster, default stand: production")[1], r"p95 {n} %")[0] < 5
    for mode in ("off", "static", "dynamic"):
        missed, total = figures(row(rows, f"pacing, flow limit 25 % the model lacks: {mode}")[1],
                                r"{n} of {n} turning points missed")
        assert 0 <= missed <= total and total > 0


def _diagnosis(rows):
    r = row(rows, "stand diagnose")
    assert figures(r[1], r"{n} s")[0] > 0
    assert "best reversal (right)" in r[4], r
    g, tau = figures(row(rows, "base fit alone")[4], r"g = {n}, τ = {n} ms")
    assert 100 < g < 160 and 0 <= tau < 100


def _stepwise(rows):
    assert figures(rows[0][3], r"{n}x faster")[0] > 1, rows[0]     # CPU times: not the host's
    assert figures(rows[0][4], r"within {n} relative")[0] < 1e-3, rows[0]
    r = row(rows, "rig diagnose --rig-model, 4 channels, stepwise")
    right, total = figures(r[4], r"{n} of {n} channels base\+reversal \(right\)")
    assert right == total == 4, r


def _confusion(rows):
    right, cells = figures(row(rows, "confusion matrix of stepwise")[1], r"{n} of {n}")
    assert right == cells == 3, rows[0]                  # the quick cells are named right
    for label in ("confusion matrix: spurious", "confusion matrix: overdamped"):
        assert figures(row(rows, label)[1], r"{n} of {n}")[0] == 0, label


def _rig_identify(rows):
    for label in ("rig G, per-column", "rig G, one simultaneous"):
        assert figures(row(rows, label)[1], r"largest error {n} %")[0] < 5, label
    r = row(rows, "rig diagnose --rig-model, 4 channels, stepwise (2 candidates), 2 workers")
    assert "same models" in r[4], r


def _rig_load(rows):
    r = row(rows, "rig load, G identified")
    assert figures(r[1], r"largest error {n} %")[0] < 5, r
    for name in ("decoupled", "independent"):
        gm, pm = figures(row(rows, f"rig load, design {name}")[1], r"gain margin {n}, phase margin {n}°")
        assert gm > 1 and pm > 0
    r = row(rows, "rig load through the gateway (stand load --rig)")
    p95, mx = figures(r[1], r"p95 {n} %, max {n} %")
    assert 0 <= p95 <= mx < 1, r                         # the goal: p95 0.5 %, max 1 %
    r = row(rows, "rig load through the gateway, 5 load cases timed")
    assert figures(r[1], r"{n}x the valve-limited minimum")[0] >= 0.99, r
    for rate in ("2500", "5000"):
        decoupled = figures(row(rows, f"rig load, 5 load cases at {rate} kgf/s, decoupled")[1], r"p95 {n} %")
        independent = figures(row(rows, f"rig load, 5 load cases at {rate} kgf/s, independent")[1], r"p95 {n} %")
        assert decoupled[0] < independent[0], (rate, decoupled, independent)


def _bus(rows):
    for r in rows:
        assert figures(r[1], r"{n} (?:frames|round trips)/s")[0] > 0, r


def _bus_budget(rows):
    one, many = rows
    assert figures(one[1], r"= {n} % bus load")[0] < 100 and one[4] == "fits"
    assert figures(many[1], r"= {n} % bus load")[0] > 100 and many[4].startswith("does not fit")


def _crack(rows):
    alarmed, runs = figures(row(rows, "crack: intact")[1], r"{n} of {n} runs with an alarm")
    assert alarmed == 0 and runs > 0
    r = row(rows, "crack: 3 % at inner from flight 120")
    named, seeds = figures(r[1], r"{n} of {n} name inner first")
    assert named == seeds > 0, r


def _live(rows):
    low, high = figures(row(rows, "live page: stream updates")[1], r"{n}-{n} per s")
    assert 10 <= low <= high, (low, high)                # the 10 updates a second
    assert figures(row(rows, "live page: 3 viewers against none")[1], r"{n}x")[0] > 0


def _rig_one_run(rows):
    for structure in ("chain", "plate"):
        r = row(rows, f"rig G, 4-channel {structure}, one run")
        assert figures(r[1], r"largest error {n} %")[0] < 1, r
        assert figures(row(rows, f"rig G, 4-channel {structure}, multisine")[1],
                       r"diagonal {n} % on average")[0] > 1          # why not a multisine
    assert "one run of Hadamard meanders" in row(rows, "rig G from one run: the plan")[1]


def _endurance(rows):
    done, target = figures(row(rows, "endurance (quick): flights counted")[1], r"{n} of {n}")
    assert done == target > 0
    r = row(rows, "endurance (quick): flights counted")
    assert r[3] == "met" and figures(r[4], r"kill -9 at \[{n}\]"), r      # the kill happened
    r = row(rows, "endurance (quick): turning-point log")
    assert r[1] == "clean" and r[3] == "met", r


#: what each benchmark's quick table must say, beyond its figures being numbers
PLAUSIBLE = {"control_loop": _control_loop, "wakeup": _wakeup, "rig": _rig, "campaign": _campaign,
             "decode": _decode, "loading": _loading, "faster": _faster, "diagnosis": _diagnosis,
             "stepwise": _stepwise, "confusion": _confusion, "rig_identify": _rig_identify,
             "rig_load": _rig_load, "bus": _bus, "bus_budget": _bus_budget, "crack": _crack, "live": _live,
             "rig_one_run": _rig_one_run, "endurance": _endurance}


def test_every_benchmark_has_its_smoke_run():
    assert set(FIGURES) <= set(discover())
    assert set(ROWS) == set(PLAUSIBLE) == set(discover())


def run_quick(name: str, timeout_s: float) -> subprocess.CompletedProcess:
    """``scripts/bench --quick NAME`` in a session of its own: past ``timeout_s`` the whole
    session is killed (a benchmark's emulator and ``stand`` processes too, which a killed
    runner left running: one stayed 34 minutes in a CI run, taking a core from the suite)."""
    proc = subprocess.Popen([sys.executable, "-m", "benchmarks.runner", "--quick", name], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        pytest.fail(f"scripts/bench --quick {name} still running after {timeout_s:g} s: "
                    f"{out[-2000:]}{err[-2000:]}")
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


# one test per benchmark, so the test processes share them out (together they took 14 min in
# one process of a CI run)
@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(discover()))
def test_the_benchmark_runs_in_quick_mode_and_prints_its_rows(name):
    res = run_quick(name, timeout_s=850)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    table = res.stdout
    assert f"running {name}" in res.stderr
    assert "FAILED" not in table
    assert sum(line.startswith("| ") for line in table.splitlines()) >= 2, table  # head + rows
    for figure in FIGURES.get(name, ()):
        assert figure in table, figure
    rows = rows_of(table)
    assert len(rows) == ROWS[name], [r[0] for r in rows]
    for r in rows:
        assert len(r) == 5, r
        # every figure measured is a number (a nan is a benchmark measuring nothing)
        assert not re.search(r"\b(nan|inf)\b", " ".join(r[1:4])), r
        assert not re.search(r"FAILED|WRONG|DIFFERENT|stopped", r[1]), r
    PLAUSIBLE[name](rows)


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

