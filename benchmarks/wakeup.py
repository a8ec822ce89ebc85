"""The host's own real-time floor: how late a bare SCHED_FIFO thread wakes on a 2 ms grid.

Like rt-tests' ``cyclictest``: a fresh process (one thread, real-time priority where allowed)
sleeps to each point of a 2 ms grid and records how late it woke. Nothing of ours runs in it:
this is the best any control loop can do on this machine, the reference for the real-time loop's
jitter and missed cycles.
"""
from __future__ import annotations

import json
import subprocess
import sys
import time

from .table import Row

ORDER = 11
PERIOD_S = 0.002


def _measure_here(duration_s: float) -> dict:
    from standbus.realtime import DEFAULT_PRIORITY, make_realtime
    sched = make_realtime(DEFAULT_PRIORITY)
    n = max(1, int(duration_s / PERIOD_S))
    late = []
    target = time.perf_counter()
    for _ in range(n):
        target += PERIOD_S
        remaining = target - time.perf_counter()
        if remaining > 0:
            time.sleep(remaining)
        late.append(time.perf_counter() - target)
    late.sort()
    return {"wakeups": n, "max_ms": late[-1] * 1e3, "p99_ms": late[int(0.99 * (n - 1))] * 1e3,
            "over_period": sum(1 for x in late if x > PERIOD_S),
            "policy": "SCHED_FIFO" if not isinstance(sched, str) else f"normal ({sched})"}


def measure(duration_s: float) -> dict:
    """Run the measurement in a fresh process (no other thread, no GIL to share)."""
    out = subprocess.run([sys.executable, "-m", "benchmarks.wakeup", str(duration_s)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def run(quick: bool) -> list[Row]:
    m = measure(4.0 if quick else 60.0)
    return [Row("host floor: bare thread sleeping on a 2 ms grid",
                f"p99 {m['p99_ms']:.3f} / max {m['max_ms']:.2f} ms",
                "what any loop on this host gets (cyclictest-like)", "",
                f"{m['wakeups']:,} wake-ups, {m['over_period']} more than a period late; {m['policy']}")]


if __name__ == "__main__":
    print(json.dumps(_measure_here(float(sys.argv[1]))))
