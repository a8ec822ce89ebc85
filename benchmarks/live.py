"""Live page: the control loop's per-cycle time with the page served and three viewers attached against none (the example's test on the emulated example rig, lockstep).

Sessions of one test (``stand test start``, then ``stand test resume``, each a few flights)
alternate between two conditions: no page (``--serve`` not given; the session's feed is
published all the same) and the page served by the session (``--serve 127.0.0.1:0``) with three
viewers reading its stream (``GET /live``, server-sent events) from this process. The loop's
per-cycle time is each cycle's SYNC time minus the one before (the rolling window's
``sync_time``, read right after each session; steps over 50 ms, where the loop waited for a
flight's piece or a session began, left out): in lockstep a cycle is the loop's work plus the
emulator's answer, so anything that takes the loop's thread (the GIL, the cores) lengthens it.
Noise: the same condition's sessions against each other (the full run has three of each).
The ratio is from this one run; a shared 2-core host's load is in the note.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .table import Row

ORDER = 62
ROOT = Path(__file__).resolve().parents[1]
GATEWAY = ["--lockstep", "--no-progress", "--heartbeat-timeout", "3000"]
VIEWERS = 3
#: a step of the SYNC times longer than this is a wait, not a cycle, s
GAP_S = 0.05


def _the_test(directory: Path, rig_text: str) -> Path:
    """The example's test file, its flights and controller, with ``rig_text`` as its rig."""
    shutil.copytree(ROOT / "examples" / "test-flights", directory / "test-flights")
    (directory / "endurance").mkdir()
    shutil.copy(ROOT / "examples" / "endurance" / "controller.toml", directory / "endurance")
    (directory / "rig.toml").write_text(rig_text)
    shutil.copy(ROOT / "examples" / "test.toml", directory / "test.toml")
    return directory / "test.toml"


def _cycle_times(testdir: Path, record: dict) -> np.ndarray:
    """The session's per-cycle times (s) from the rolling window (module docstring)."""
    import pyarrow.parquet as pq
    t = np.concatenate([pq.read_table(p, columns=["sync_time"]).column(0).to_numpy()
                        for p in sorted((testdir / "rolling").glob("chunk-*.parquet"))] or [np.array([])])
    t = np.sort(t[(t >= record["started_at"]) & (t <= record["ended_at"])])
    d = np.diff(t)
    return d[(d > 0) & (d < GAP_S)]


def _session(args: list[str], testdir: Path, viewers: int) -> tuple[np.ndarray, list[float]]:
    """One session (``stand test ARGS``); its per-cycle times and each viewer's updates/s."""
    serve = ["--serve", "127.0.0.1:0"] if viewers else []
    proc = subprocess.Popen([sys.executable, "-m", "stand", "test", *args, *GATEWAY, *serve],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    from endurance.live.viewer import StreamViewer
    attached: list[StreamViewer] = []
    try:
        if viewers:
            line = proc.stdout.readline()
            if not line.startswith("live page: "):
                raise RuntimeError(f"no page served: {line}{proc.stderr.read()[-2000:]}")
            attached = [StreamViewer(line.split()[2]) for _ in range(viewers)]
        out, err = proc.communicate(timeout=600)
    finally:
        for v in attached:
            v.close()
    if proc.returncode != 0:
        raise RuntimeError(f"stand test {' '.join(args[:1])} failed: {err[-2000:]}")
    record = json.loads(sorted((testdir / "sessions").glob("*.json"))[-1].read_text())
    return _cycle_times(testdir, record), [v.updates_per_s() for v in attached]


def run(quick: bool) -> list[Row]:
    from plant_emulator.process import RigEmulatorProcess
    load_before = os.getloadavg()[0]
    flights, pairs = (1, 1) if quick else (5, 3)
    tag = f"bench-live-{os.getpid()}-{time.monotonic_ns() % 10**6}"
    rig_text = (ROOT / "examples" / "rig.toml").read_text().replace("udp_loopback:rig-", f"udp_loopback:{tag}-")
    times: dict[int, list[np.ndarray]] = {0: [], VIEWERS: []}
    rates: list[float] = []
    with tempfile.TemporaryDirectory(prefix="bench-live-") as tmp:
        directory = Path(tmp)
        test_file = _the_test(directory / "t", rig_text)
        testdir = directory / "T"
        emulator = RigEmulatorProcess(directory / "t" / "rig.toml", lockstep=True, seed=3).start()
        try:
            done = 0
            for k in range(2 * pairs):
                viewers = VIEWERS if k % 2 else 0
                done += flights
                args = (["start", str(test_file), "--out", str(testdir)] if k == 0
                        else ["resume", str(testdir)]) + ["--flights", str(done)]
                cycles, rate = _session(args, testdir, viewers)
                times[viewers].append(cycles)
                rates += rate
        finally:
            emulator.stop()
    load_after = os.getloadavg()[0]
    medians = {v: [float(np.median(c)) * 1e3 for c in cs] for v, cs in times.items()}
    alls = {v: np.concatenate(cs) * 1e3 for v, cs in times.items()}
    note = (f"lockstep, {flights} flights a session, {pairs} session(s) each, alternating; "
            f"load {load_before:.1f} -> {load_after:.1f}")
    rows = []
    for v, label in ((0, "no page"), (VIEWERS, f"page served, {VIEWERS} viewers")):
        a = alls[v]
        rows.append(Row(f"live page: loop cycle, {label}",
                        f"median {np.median(a):.3f} ms, p99 {np.percentile(a, 99):.3f} ms ({len(a):,} cycles)",
                        "sessions' medians " + ", ".join(f"{m:.3f}" for m in medians[v]) + " ms", "", note))
    ratio = float(np.median(alls[VIEWERS]) / np.median(alls[0]))
    spread = (max(medians[0]) / min(medians[0])) if len(medians[0]) > 1 else float("nan")
    rows.append(Row(f"live page: {VIEWERS} viewers against none, per-cycle time",
                    f"{ratio:.3f}x (p99 {np.percentile(alls[VIEWERS], 99) / np.percentile(alls[0], 99):.3f}x)",
                    "noise: no-page sessions against each other "
                    + (f"{spread:.3f}x" if np.isfinite(spread) else "(one session: --quick)"),
                    f"{ratio:.3f}", "ratio of the medians over every cycle of each condition"))
    rows.append(Row("live page: stream updates a viewer got",
                    f"{min(rates):.1f}-{max(rates):.1f} per s" if rates else "none",
                    "at least 10 per s", "", f"{len(rates)} viewers, samples at 50 per s pushed every 50 ms"))
    return rows
