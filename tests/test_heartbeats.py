"""The emulator's nodes' heartbeats come from one thread (plant_emulator.heartbeats): each at
its period, a bus's frames due together in one batch, the new state from the next beat on,
none after stop or close."""
from __future__ import annotations

import threading
import time

import can
import pytest

from plant_emulator.heartbeats import PeriodicFrames

pytestmark = pytest.mark.serial      # on the wall clock


def test_frames_due_together_leave_in_one_batch_at_their_period_until_stopped():
    sent, lock = [], threading.Lock()

    def bus(name):
        def send(frames):
            with lock:
                sent.append((time.monotonic(), name, [(f[1], f[3]) for f in frames]))
        return send

    can0, can1 = bus("can0"), bus("can1")
    periodic = PeriodicFrames()
    start = time.monotonic()
    beats = [periodic.task(can0, 0x701, [5], 0.05), periodic.task(can0, 0x702, [5], 0.05),
             periodic.task(can1, 0x701, [5], 0.05)]
    slow = periodic.task(can1, 0x703, [127], 0.2)
    time.sleep(0.27)
    beats[1].update([4])                      # node 2 stopped: its state from the next beat
    slow.stop()
    time.sleep(0.15)
    periodic.close()
    with lock:
        got = list(sent)
    on0 = [frames for _, name, frames in got if name == "can0"]
    assert all(len(f) == 2 for f in on0)                  # both of can0's nodes in one batch
    assert 7 <= len(on0) <= 9                              # 0.42 s at 50 ms
    assert on0[0] == [(0x701, b"\x05"), (0x702, b"\x05")]
    assert on0[-1] == [(0x701, b"\x05"), (0x702, b"\x04")]
    firsts = [t for t, name, _ in got if name == "can0"]
    assert firsts[0] - start == pytest.approx(0.05, abs=0.02)
    gaps = [b - a for a, b in zip(firsts, firsts[1:])]
    assert all(0.03 < g < 0.08 for g in gaps), gaps
    slow_sent = [f for _, name, frames in got if name == "can1" for f in frames if f[0] == 0x703]
    assert len(slow_sent) == 1                             # at 0.2 s, stopped before 0.4 s
    count = len(got)
    time.sleep(0.12)
    assert len(sent) == count                              # none after close
    with pytest.raises(can.CanOperationError):
        periodic.task(can0, 0x704, [5], 0.05)


def test_a_state_change_while_a_batch_is_sent_never_lets_the_old_state_follow_the_new():
    """A node's NMT state changes (its heartbeat's ``update``, then a heartbeat at once) while
    the thread sends the batch that carries its old state: the old one goes first, never
    after the new one (a master took a late PRE-OPERATIONAL for a node that had just been
    started, and tripped the run at its first cycle)."""
    log = []
    sending = threading.Event()

    def slow_bus(frames):              # another bus's frames, sent before this node's
        if not sending.is_set():
            sending.set()
            time.sleep(0.1)

    def node_bus(frames):
        log.append(("beat", frames[0][3]))

    periodic = PeriodicFrames()
    try:
        periodic.task(slow_bus, 0x701, [5], 0.05)
        beat = periodic.task(node_bus, 0x702, [0x7F], 0.05)
        assert sending.wait(2.0)
        beat.update([5])                       # the node started ...
        log.append(("at the change", b"\x05"))  # ... and sent its new state at once
        time.sleep(0.15)
    finally:
        periodic.close()
    after = log[log.index(("at the change", b"\x05")) + 1:]
    assert after and all(data == b"\x05" for kind, data in after if kind == "beat"), log
