"""Capture decoding: our vectorized decoder vs python-can LogReader + cantools per frame, and peak memory.

The same synthetic stand capture (SYNC, two TPDOs, RPDO per 2 ms cycle, heartbeats, SDO; written
as a candump log and as a BLF) is decoded in the same run by

* the reference: ``can.LogReader`` + ``cantools`` ``db.decode_message`` for every frame (every
  signal of every known frame, as a user would write it);
* ours: :func:`captures.decode_frames` (every signal of every known frame, vectorized), and the
  whole ``capture → run`` pipeline (:func:`captures.decode_capture`: cycles, t/u/y rows).

Whole process: ``stand decode big.log -o run`` (2.1 M frames, as issue 29 measured) against a
process that does the reference's work on the same file (:data:`REFERENCE_PROCESS`), wall time
from start to exit, best of a few runs each; and "past start-up": each minus its own process on a
capture of a few cycles (interpreter, imports, DBC, output: every fixed cost), so what is left is
the per-frame work. The same ratios in CPU time (user + system) are in the note: on a shared host
they move less than the wall times, which also hold the waits for a core.

Peak memory: ``stand decode`` to partitioned Parquet in a fresh process (peak RSS) for two capture
sizes 4× apart; the peak does not grow with the file, which is the argument for a 10 GB capture
(memory is set by the ~1 MB chunk and the Parquet row groups, not by the file).
"""
from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import can
import cantools

from captures import decode_capture, decode_frames
from captures.synthetic import stand_frames, synthetic_run
from captures.writers import write_blf, write_candump

from .table import Row

ORDER = 30
SMALL_CYCLES = 40   #: the capture whose decode is a process's start-up (fixed costs)
DBC = Path(__file__).resolve().parent.parent / "dbc" / "stand.dbc"


def make_captures(directory: Path, frames: int) -> dict[str, Path]:
    run = synthetic_run(max(10, frames // 4 - 10), seed=1)
    paths = {"log": directory / "bench.log", "blf": directory / "bench.blf"}
    write_candump(paths["log"], stand_frames(run))
    write_blf(paths["blf"], stand_frames(run))
    return paths


def reference(path: Path) -> tuple[float, int]:
    """python-can LogReader + cantools decode_message, one frame at a time."""
    db = cantools.database.load_file(str(DBC))
    t0 = time.perf_counter()
    n = 0
    for msg in can.LogReader(str(path)):
        n += 1
        try:
            db.decode_message(msg.arbitration_id, msg.data)
        except (KeyError, cantools.database.DecodeError):
            pass
    return n / (time.perf_counter() - t0), n


def ours(path: Path, repeats: int = 3) -> tuple[float, float]:
    """Best of ``repeats``: (frames/s all signals, frames/s capture → run rows)."""
    best_frames = best_run = 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        n = 0
        for chunk, _ in decode_frames(path):
            n += len(chunk)
        best_frames = max(best_frames, n / (time.perf_counter() - t0))
        t0 = time.perf_counter()
        result = decode_capture(path, collect=False)
        best_run = max(best_run, result.frames.frames / (time.perf_counter() - t0))
    return best_frames, best_run


#: the reference as a process: python-can's LogReader and cantools' decode_message for every frame
#: (every signal of every known frame), as :func:`reference` does in this process
REFERENCE_PROCESS = """\
import sys
import can
import cantools
db = cantools.database.load_file(sys.argv[2])
n = 0
for msg in can.LogReader(sys.argv[1]):
    n += 1
    try:
        db.decode_message(msg.arbitration_id, msg.data)
    except (KeyError, cantools.database.DecodeError):
        pass
print(n)
"""


@dataclass(frozen=True)
class ProcessTime:
    """A process's wall time from start to exit and its CPU time (user + system), in s; on a
    shared host the wall time also holds the waits for a core, the CPU time does not."""

    wall_s: float
    cpu_s: float


def timed(command: list[str]) -> tuple[ProcessTime, str]:
    """Run ``command``; its times and what it printed."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run(command, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} exited {res.returncode}: {res.stderr[-2000:]}")
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    return ProcessTime(wall, cpu), res.stdout


def best(commands: list[list[str]]) -> tuple[ProcessTime, str]:
    """The least wall time and the least CPU time of the runs (each the least disturbed), and
    what the first run printed."""
    runs = [timed(c) for c in commands]
    return (ProcessTime(min(t.wall_s for t, _ in runs), min(t.cpu_s for t, _ in runs)), runs[0][1])


def stand_decode(capture: Path, out: Path, repeats: int) -> tuple[ProcessTime, str]:
    """``stand decode CAPTURE -o RUN`` (a new run directory each time)."""
    return best([[sys.executable, "-m", "stand", "decode", str(capture), "-o", str(out / f"run-{i}"),
                  "--no-progress"] for i in range(repeats)])


def reference_process(capture: Path, repeats: int) -> tuple[ProcessTime, str]:
    """:data:`REFERENCE_PROCESS` on ``capture``."""
    return best([[sys.executable, "-c", REFERENCE_PROCESS, str(capture), str(DBC)]] * repeats)


def whole_process(directory: Path, frames: int, repeats: int) -> Row:
    """``stand decode`` against the reference, each as a whole process, and past start-up."""
    big, small = directory / "big.log", directory / "small.log"
    write_candump(big, stand_frames(synthetic_run(frames // 4, seed=3)))
    write_candump(small, stand_frames(synthetic_run(SMALL_CYCLES, seed=3)))
    ours, said = stand_decode(big, directory / "ours", repeats)
    ref, counted = reference_process(big, max(1, repeats - 1))
    ours0, _ = stand_decode(small, directory / "ours-small", 2 * repeats)    # short: more runs
    ref0, _ = reference_process(small, 2 * repeats)
    n = int(counted.split()[-1])
    if f"{n:,} frames" not in said:
        raise RuntimeError(f"stand decode read other frames than the reference's {n:,}: {said}")

    def ratios(kind: str) -> tuple[float, float]:
        o, o0, r, r0 = (getattr(t, kind) for t in (ours, ours0, ref, ref0))
        return r / o, (r - r0) / (o - o0)

    whole, past = ratios("wall_s")
    whole_cpu, past_cpu = ratios("cpu_s")
    return Row(f"stand decode {n / 1e6:.1f} M-frame .log -o run, whole process",
               f"{ours.wall_s:.2f} s ({ours0.wall_s:.2f} s of it start-up)",
               f"python-can LogReader + cantools process: {ref.wall_s:.2f} s ({ref0.wall_s:.2f} s start-up)",
               f"{whole:.1f}x whole, {past:.1f}x past start-up",
               f"wall times; in CPU time {whole_cpu:.1f}x and {past_cpu:.1f}x "
               f"(ours {ours.cpu_s:.2f} s, {ours0.cpu_s:.2f} s of it start-up); {os.path.getsize(big) / 1e6:.0f} MB; "
               f"start-up: the same process on a {SMALL_CYCLES}-cycle log; ours also pairs cycles and "
               "writes Parquet; target >= 8x past start-up")


# VmHWM (peak RSS of this address space): unlike ru_maxrss it is not inherited across exec
_PEAK = ("import sys\n"
         "from captures import decode_capture\n"
         "if sys.argv[1] != '-':\n"
         "    decode_capture(sys.argv[1], out=sys.argv[2], collect=False, partition_rows=2_000_000)\n"
         "print([l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM')][0])\n")


def peak_rss_mb(capture: Path | None, out: Path) -> float:
    """Peak resident memory (MB) of a fresh process decoding ``capture`` (None: imports only)."""
    res = subprocess.run([sys.executable, "-c", _PEAK, str(capture) if capture else "-", str(out)],
                         capture_output=True, text=True, check=True)
    return int(res.stdout.split()[-1]) / 1024


def run(quick: bool) -> list[Row]:
    frames = 40_000 if quick else 200_000
    rows: list[Row] = []
    with tempfile.TemporaryDirectory(prefix="bench-decode-") as tmp:
        tmp = Path(tmp)
        paths = make_captures(tmp, frames)
        for kind, path in paths.items():
            ref, n = reference(path)
            fast, to_run = ours(path)
            size = os.path.getsize(path) / 1e6
            rows.append(Row(f"decode .{kind}, every signal (vectorized)", f"{fast:,.0f} frames/s",
                            f"python-can LogReader + cantools: {ref:,.0f} frames/s", f"{fast / ref:.1f}x",
                            f"{n:,} frames, {size:.1f} MB; target >= 10x"))
            rows.append(Row(f"capture .{kind} -> run (cycles t,u,y)", f"{to_run:,.0f} frames/s",
                            f"python-can LogReader + cantools: {ref:,.0f} frames/s", f"{to_run / ref:.1f}x",
                            "decode + pair TPDOs with SYNCs + rows"))
        # quick (a smoke run): each process once (the start-up's twice), a capture large enough
        # that its decoding outlasts the start-up's noise
        rows.append(whole_process(tmp, 100_000 if quick else 2_100_000, 1 if quick else 3))
        # memory: two sizes 4x apart, in fresh processes
        small_frames = 100_000 if quick else 2_500_000
        sizes = []
        for factor in (1, 4):
            run_ = synthetic_run(small_frames * factor // 4, seed=2)
            path = tmp / f"mem{factor}.log"
            write_candump(path, stand_frames(run_))
            peak = peak_rss_mb(path, tmp / f"out{factor}")
            sizes.append((os.path.getsize(path) / 1e6, peak))
            path.unlink()
        base = peak_rss_mb(None, tmp / "none")
        (s1, p1), (s2, p2) = sizes
        rows.append(Row("peak memory: stand decode -> partitioned Parquet",
                        f"{p1:.0f} MB ({s1:.0f} MB log), {p2:.0f} MB ({s2:.0f} MB log)",
                        "target < 500 MB for a 10 GB capture", f"{p2 / p1:.2f}x for 4x the file",
                        f"imports alone {base:.0f} MB; streams ~1 MB chunks, so 10 GB stays at this peak"))
    return rows
