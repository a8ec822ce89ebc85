"""The host's own real-time floor: how late a bare SCHED_FIFO thread wakes on a 2 ms grid.

Like rt-tests' ``cyclictest``: a fresh process (one thread, real-time priority where allowed)
sleeps to each point of a 2 ms grid and records how late it woke. Nothing of ours runs in it:
this is the best any control loop can do on this machine, the reference for the real-time loop's
jitter and missed cycles.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

from .table import Row

ORDER = 11
PERIOD_S = 0.002


#: a wake-up at least this late is a stall worth its time stamp (``stalls``), s
STALL_S = 0.0005
#: what a measuring process prints once it is on its CPU at its priority, about to measure
READY = "ready"


#: the probes' priority beside a run: one above the loop's, so a probe is late only when the
#: host did not run it, never because the loop (SCHED_FIFO at the same priority, which a FIFO
#: thread does not preempt) held its CPU; a wake-up costs the loop a few µs
BESIDE_PRIORITY_STEP = 1


def _measure_here(duration_s: float, cpu: int | None = None, priority: int | None = None) -> dict:
    from standbus.realtime import DEFAULT_PRIORITY, make_realtime
    if cpu is not None:
        os.sched_setaffinity(0, {cpu})
    sched = make_realtime(priority or DEFAULT_PRIORITY)
    print(READY, flush=True)       # the caller may start what it measures beside this now
    n = max(1, int(duration_s / PERIOD_S))
    late = []
    stalls = []
    target = time.perf_counter()
    for _ in range(n):
        target += PERIOD_S
        remaining = target - time.perf_counter()
        if remaining > 0:
            time.sleep(remaining)
        lateness = time.perf_counter() - target
        late.append(lateness)
        if lateness >= STALL_S:
            stalls.append((time.time() - lateness, lateness))
    late.sort()
    return {"wakeups": n, "max_ms": late[-1] * 1e3, "p99_ms": late[int(0.99 * (n - 1))] * 1e3,
            "over_period": sum(1 for x in late if x > PERIOD_S),
            "policy": "SCHED_FIFO" if not isinstance(sched, str) else f"normal ({sched})",
            "stalls": stalls}


def start(duration_s: float, cpu: int | None = None, priority: int | None = None) -> subprocess.Popen:
    """The measurement in a fresh process (no other thread, no GIL to share), on one ``cpu``
    if given (-1: any), at ``priority`` (default: the loop's), running beside whatever the
    caller does meanwhile; :func:`result` collects it."""
    return subprocess.Popen([sys.executable, "-m", "benchmarks.wakeup", str(duration_s),
                             str(-1 if cpu is None else cpu)]
                            + ([str(priority)] if priority is not None else []),
                            stdout=subprocess.PIPE, text=True)


def start_on_every_cpu(duration_s: float) -> list[subprocess.Popen]:
    """One measurement pinned to each CPU this process may use, one priority above the loop's
    (:data:`BESIDE_PRIORITY_STEP`): a host that stops one virtual
    CPU only stalls the thread on it, so one floor thread alone could miss it. Returns once
    every one of them is measuring: a Python process takes ~0.5 s to start, and a run started
    at once had its first half second unwatched (late cycles there looked like the loop's own)."""
    from standbus.realtime import DEFAULT_PRIORITY
    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else [None]
    procs = [start(duration_s, cpu, DEFAULT_PRIORITY + BESIDE_PRIORITY_STEP) for cpu in cpus]
    for proc in procs:
        if proc.stdout.readline().strip() != READY:
            raise RuntimeError(f"the host-floor measurement did not start (exit code {proc.wait()})")
    return procs


def result(proc: subprocess.Popen) -> dict:
    out, _ = proc.communicate()
    if proc.returncode:
        raise RuntimeError(f"the host-floor measurement failed (exit code {proc.returncode})")
    return json.loads(out.strip().splitlines()[-1])


def measure(duration_s: float) -> dict:
    return result(start(duration_s))


def at_host_stalls(stalls: list[tuple[float, float]], host: list[tuple[float, float]],
                   within_s: float = 0.002) -> int:
    """How many of ``stalls`` overlap (to ``within_s``) one of the ``host`` stalls, both as
    ``(scheduled wall-clock time, lateness)``, s: a loop late while a bare thread elsewhere on
    the host was late too."""
    return sum(1 for m, d in stalls
               if any(s - within_s <= m + d and m <= s + late + within_s for s, late in host))


def run(quick: bool) -> list[Row]:
    m = measure(1.0 if quick else 60.0)
    return [Row("host floor: bare thread sleeping on a 2 ms grid",
                f"p99 {m['p99_ms']:.3f} / max {m['max_ms']:.2f} ms",
                "what any loop on this host gets (cyclictest-like)", "",
                f"{m['wakeups']:,} wake-ups, {m['over_period']} more than a period late; {m['policy']}")]


if __name__ == "__main__":
    cpu_arg = int(sys.argv[2]) if len(sys.argv) > 2 else -1
    print(json.dumps(_measure_here(float(sys.argv[1]), None if cpu_arg < 0 else cpu_arg,
                                   int(sys.argv[3]) if len(sys.argv) > 3 else None)))
