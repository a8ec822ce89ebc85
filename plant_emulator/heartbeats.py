"""The emulated nodes' periodic frames (their heartbeats, CiA 301 0x1017) sent from one thread.

canopen's local node sends its heartbeat through ``network.send_periodic``, which python-can
serves with a thread per frame: a 16-channel rig's 32 nodes woke 32 threads every heartbeat
period (320 times a second at 100 ms), each taking the emulator's GIL and a core from the
lockstep cycle (a 300 ms heartbeat ran the 16-channel rig ~3 % faster than 100 ms). Here one
thread sends every node's frame that is due, those of one bus as one batch, and sleeps until
the next is due. A frame due within :data:`GATHER_S` of another goes with it: the nodes boot
within milliseconds of each other, so each period's heartbeats of a bus leave together, a few
ms early at most (a consumer's timeout is 2-3.5 periods).
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Callable

import can

log = logging.getLogger(__name__)

#: frames due this soon after the first one due are sent with it, s
GATHER_S = 0.005


class PeriodicTask:
    """One periodic frame (canopen's ``PeriodicMessageTask`` interface: ``update``, ``stop``)."""

    def __init__(self, sender: "PeriodicFrames", send: Callable[[list], None], can_id: int,
                 data: bytes, period_s: float) -> None:
        self._sender = sender
        self.send = send
        self.can_id = can_id
        self.data = bytes(data)
        self.period_s = period_s
        self.due = time.monotonic() + period_s

    def update(self, data) -> None:
        """The frame's data from its next send on (a heartbeat's new NMT state). Waits for a
        batch being sent: one that carries the old data goes out before this returns, so
        before anything the caller sends next (the node's heartbeat at its state change)."""
        with self._sender._lock:
            self.data = bytes(data)

    def stop(self) -> None:
        self._sender.remove(self)


class PeriodicFrames:
    """Every periodic frame of an emulator; :meth:`task` adds one (started at once, first sent
    one period later, as python-can's tasks), :meth:`close` ends the thread."""

    def __init__(self) -> None:
        self._tasks: list[PeriodicTask] = []
        self._lock = threading.Lock()
        self._changed = threading.Event()
        self._closed = False
        self._thread: threading.Thread | None = None

    def task(self, send: Callable[[list], None], can_id: int, data, period_s: float) -> PeriodicTask:
        """A frame ``can_id``/``data`` every ``period_s``, handed to ``send(raw frames)``
        (the frames of one ``send`` go out together)."""
        if not period_s > 0:
            raise ValueError(f"a periodic frame needs a period > 0, not {period_s}")
        task = PeriodicTask(self, send, can_id, data, period_s)
        with self._lock:
            if self._closed:
                raise can.CanOperationError("the emulator's periodic frames are closed")
            self._tasks.append(task)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="emulator-heartbeats",
                                                daemon=True)
                self._thread.start()
        self._changed.set()
        return task

    def remove(self, task: PeriodicTask) -> None:
        with self._lock:
            if task in self._tasks:
                self._tasks.remove(task)

    def close(self) -> None:
        with self._lock:
            self._closed = True
            self._tasks.clear()
            thread = self._thread
        self._changed.set()
        if thread is not None:
            thread.join(1.0)

    def _run(self) -> None:
        while True:
            with self._lock:
                if self._closed:
                    return
                now = time.monotonic()
                first = min((t.due for t in self._tasks), default=None)
                due: dict = {}
                if first is not None and first <= now:
                    for t in self._tasks:
                        if t.due <= first + GATHER_S:
                            due.setdefault(t.send, []).append((0, t.can_id, len(t.data), t.data))
                            # the next one a period on; after a stall, a period from now
                            t.due = t.due + t.period_s if t.due + t.period_s > now else now + t.period_s
                    first = min(t.due for t in self._tasks)
                # sent under the lock: a frame's data cannot change between here and the bus
                for send, frames in due.items():
                    try:
                        send(frames)
                    except (can.CanError, OSError, ValueError) as exc:   # a closed bus at shutdown
                        log.debug("periodic frames not sent: %s", exc)
            wait = 1.0 if first is None else max(0.0, first - time.monotonic())
            if self._changed.wait(wait):
                self._changed.clear()
