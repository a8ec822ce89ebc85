"""Real-time scheduling of the loop threads (standbus.realtime)."""
from __future__ import annotations

import os
import sys
import threading

import pytest

from standbus.realtime import (GIL_SLICE_S, make_realtime, process_threads, realtime_allowed,
                               realtime_threads, short_gil_slices)

pytestmark = pytest.mark.serial   # on the wall clock: runs alone (scripts/test)


def _policy(tid: int = 0) -> int:
    return os.sched_getscheduler(tid)


def test_off_changes_nothing():
    before = _policy() if hasattr(os, "sched_getscheduler") else None
    with realtime_threads(0) as sched:
        assert sched == {"policy": "normal", "note": "real-time priority off"}
        if before is not None:
            assert _policy() == before


@pytest.mark.skipif(not realtime_allowed(), reason="SCHED_FIFO is not permitted here (needs Linux and root "
                                           "or CAP_SYS_NICE)")
def test_fifo_for_the_block_then_back_for_this_and_another_thread():
    stop = threading.Event()
    worker = threading.Thread(target=stop.wait, daemon=True)
    worker.start()
    before = (_policy(), _policy(worker.native_id))
    try:
        with realtime_threads(50, [0, worker.native_id]) as sched:
            assert sched == {"policy": "SCHED_FIFO", "priority": 50}
            assert _policy() == os.SCHED_FIFO and _policy(worker.native_id) == os.SCHED_FIFO
            assert os.sched_getparam(0).sched_priority == 50
        assert (_policy(), _policy(worker.native_id)) == before
    finally:
        stop.set()


def test_all_or_nothing_when_one_thread_cannot_be_raised(monkeypatch):
    import standbus.realtime as rt
    calls = []

    def fake(priority, tid=0):
        calls.append(("raise", tid))
        return (0, 0) if tid == 1 else "not permitted (needs root or CAP_SYS_NICE)"

    monkeypatch.setattr(rt, "make_realtime", fake)
    monkeypatch.setattr(rt, "restore", lambda previous, tid=0: calls.append(("restore", tid)))
    with rt.realtime_threads(50, [1, 2, 3]) as sched:
        assert sched == {"policy": "normal", "note": "not permitted (needs root or CAP_SYS_NICE)"}
        assert calls == [("raise", 1), ("raise", 2), ("restore", 1)], "thread 1 was put back at once"
    assert calls[-1] == ("restore", 1) and len(calls) == 3, "and not restored twice"


@pytest.mark.skipif(not realtime_allowed(), reason="SCHED_FIFO is not permitted here")
def test_a_thread_that_ended_meanwhile_is_skipped_and_every_thread_is_listed():
    stop = threading.Event()
    worker = threading.Thread(target=stop.wait, daemon=True)
    worker.start()
    ended = threading.Thread(target=lambda: None)
    ended.start(); ended.join()
    tids = process_threads()
    assert threading.get_native_id() in tids and worker.native_id in tids
    try:
        with realtime_threads(50, tids + [ended.native_id]) as sched:
            assert sched == {"policy": "SCHED_FIFO", "priority": 50}
            assert _policy(worker.native_id) == os.SCHED_FIFO
    finally:
        stop.set()


def test_a_priority_out_of_range_is_refused_with_the_reason():
    assert make_realtime(0) == "priority 0 is not 1-99" or not sys.platform.startswith("linux")
    assert isinstance(make_realtime(100), str)


def test_short_gil_slices_for_the_block_then_the_interval_before_even_after_an_error():
    before = sys.getswitchinterval()
    with short_gil_slices():
        assert sys.getswitchinterval() == pytest.approx(GIL_SLICE_S)
        assert GIL_SLICE_S < before
    assert sys.getswitchinterval() == before
    with pytest.raises(RuntimeError):
        with short_gil_slices(0.001):
            assert sys.getswitchinterval() == pytest.approx(0.001)
            raise RuntimeError("the run failed")
    assert sys.getswitchinterval() == before
