"""Real-time scheduling for the threads that keep a bus cycle: SCHED_FIFO where the host allows.

A 2 ms control loop on a shared machine misses a cycle whenever an ordinary process is
scheduled in its place at the wrong moment. Test controllers run their loop at a real-time
priority; so do we, on Linux, when the process may (root or CAP_SYS_NICE): the gateway's loop and
bus reader threads for the length of a real-time run, the real-time emulator for its life. The
kernel's real-time throttling (``/proc/sys/kernel/sched_rt_runtime_us``, 95 % by default) keeps a
runaway thread from freezing the host. Where it is not allowed nothing changes, and the caller
says so (run.json ``realtime``).

Priorities: 1-99; the default 50 leaves room above for kernel interrupt threads and below for
anything the user wants to rank lower.
"""
from __future__ import annotations

import contextlib
import os
import sys
from typing import Iterable, Iterator

DEFAULT_PRIORITY = 50
#: how long a thread holding the GIL may keep it while a real-time thread waits for it, s
#: (CPython's switch interval; its default, 5 ms, is longer than two periods of the loop)
GIL_SLICE_S = 0.0002
#: :func:`make_realtime` of a thread that has ended (listed a moment before): skipped
NO_SUCH_THREAD = "no such thread"


def _supported() -> bool:
    return sys.platform.startswith("linux") and hasattr(os, "sched_setscheduler")


def make_realtime(priority: int, tid: int = 0) -> tuple[int, int] | str:
    """Put thread ``tid`` (0: the calling thread; threads it starts later inherit it) in
    SCHED_FIFO at ``priority``. Returns what to pass to :func:`restore`, or why it could not."""
    if not _supported():
        return "real-time scheduling needs Linux"
    if not 1 <= int(priority) <= 99:
        return f"priority {priority} is not 1-99"
    try:
        before = (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(int(priority)))
    except PermissionError:
        return "not permitted (needs root or CAP_SYS_NICE)"
    except ProcessLookupError:
        return NO_SUCH_THREAD
    except OSError as exc:
        return f"refused by the host: {exc.strerror or exc}"
    return before


def process_threads() -> list[int]:
    """Kernel ids of every thread of this process: Python's and native ones (pyarrow's thread
    pools, jemalloc's background thread), as ``chrt -f -p`` on each would. The loop shares the
    GIL (and library locks) with all of them, and one preempted by an ordinary process while it
    holds what the loop needs stalls the loop: priority inversion. So every thread is raised,
    not only the loop's and the bus reader's (the figures: docs/decisions.md)."""
    try:
        return sorted(int(t) for t in os.listdir("/proc/self/task"))
    except OSError:      # no procfs: the Python threads we know of
        import threading
        return [t.native_id for t in threading.enumerate() if t.native_id]


def realtime_allowed() -> bool:
    """Whether this process may use SCHED_FIFO (tried on the calling thread and undone)."""
    result = make_realtime(1)
    if isinstance(result, str):
        return False
    restore(result)
    return True


def restore(previous: tuple[int, int], tid: int = 0) -> None:
    """Give thread ``tid`` back the policy :func:`make_realtime` returned (the thread may be gone)."""
    try:
        os.sched_setscheduler(tid, previous[0], os.sched_param(previous[1]))
    except OSError:
        pass


@contextlib.contextmanager
def realtime_threads(priority: int | None, tids: Iterable[int] = (0,)) -> Iterator[dict]:
    """SCHED_FIFO for these threads (native ids; 0 is the caller) inside the block. Yields what
    happened, for the run's metadata: ``{"policy": "SCHED_FIFO", "priority": 50}`` or
    ``{"policy": "normal", "note": why}``."""
    if not priority:
        yield {"policy": "normal", "note": "real-time priority off"}
        return
    applied: list[tuple[int, tuple[int, int]]] = []
    note = None
    for tid in tids:
        result = make_realtime(priority, tid)
        if result == NO_SUCH_THREAD and tid != 0:
            continue
        if isinstance(result, str):
            note = result
            break
        applied.append((tid, result))
    if note is not None:      # all or nothing: one thread at FIFO waiting on another is worse
        for tid, previous in applied:
            restore(previous, tid)
        applied = []
    try:
        yield ({"policy": "SCHED_FIFO", "priority": int(priority)} if note is None
               else {"policy": "normal", "note": note})
    finally:
        for tid, previous in applied:
            restore(previous, tid)


@contextlib.contextmanager
def short_gil_slices(seconds: float = GIL_SLICE_S) -> Iterator[None]:
    """Inside the block, a thread that wants the GIL gets it within ``seconds`` (plus the
    C call in progress) from a thread that holds it, instead of CPython's 5 ms.

    Priorities do not reach the GIL: a loop thread at SCHED_FIFO that wakes while the capture
    thread formats a quarter second of frames (~500 lines of Python) waits until that thread
    is asked to let go, after the switch interval. The cost is a GIL hand-off every
    ``seconds`` while two threads both want to run, which a real-time loop that mostly sleeps
    rarely sees. It is kept as a guard that costs nothing measurable; its measured effect
    (none this host can resolve) is in docs/decisions.md."""
    before = sys.getswitchinterval()
    sys.setswitchinterval(seconds)
    try:
        yield
    finally:
        sys.setswitchinterval(before)
