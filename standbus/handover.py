"""A python-can Notifier whose reader thread can hand the bus to another thread for a while.

A lockstep control loop waits for the stand's answer to every SYNC. With the stock Notifier each
answer wakes the reader thread, which hands it over through a queue to the loop thread, which
then wakes too: two thread wake-ups and a GIL hand-off per frame, about half of the loop's time.
:meth:`HandoverNotifier.handover` parks the reader thread instead and gives the caller a
``pump(timeout)`` that receives one frame on the caller's thread and hands it to the listeners
exactly as the reader would have (same listeners, same order, same lock). Everything subscribed
to the bus (canopen's heartbeat and EMCY consumers, SDO clients, a capture) keeps working as long
as the caller pumps. When the block ends the reader thread takes the bus back.

::

    notifier = HandoverNotifier(bus, listeners, timeout=0.005)
    with notifier.handover(spin_s=0.001) as pump:
        msg = pump(0.5)        # the frame (already handed to the listeners) or None
"""
from __future__ import annotations

import contextlib
import functools
import logging
import os
import select
import threading
import time
from typing import Callable, Iterator

import can

from . import wire

log = logging.getLogger(__name__)

#: the wire flags of the frames a fast handler may take: a classic data frame, or on a CAN FD bus
#: an FD frame with or without the bit-rate switch
_CLASSIC = 0
_FD_FLAGS = (wire.FLAG_FD, wire.FLAG_FD | wire.FLAG_BRS)


class HandoverNotifier(can.Notifier):
    """:class:`can.Notifier` (one bus, no asyncio loop) with :meth:`handover`.

    The reader thread leaves ``bus.recv`` only when its ``timeout`` expires or a frame arrives,
    so taking the bus over costs up to one ``timeout``: keep it short (5 ms) where hand-overs
    are frequent."""

    def __init__(self, bus: can.BusABC, listeners, timeout: float = 1.0) -> None:
        self._want_bus = threading.Event()     # a caller asked for the bus
        self._parked = threading.Event()       # the reader thread is off the bus
        self._resume = threading.Event()
        self._handover_lock = threading.Lock()
        #: the cyclic frames' own handlers, by arbitration id: ``handler(data, timestamp)``
        #: takes a frame before the listeners and returns True, or False to leave it to them
        #: (a wrong length, a state it does not handle): only classic data frames with 11-bit
        #: ids whose DLC is their length, and FD frames where :attr:`fast_fd`
        self.fast: dict[int, object] = {}
        self.fast_fd = False
        #: ``tap(timestamp, raw frames, received, channel)`` sees every frame first (a capture);
        #: the listeners then see only what no fast handler took
        self.tap = None
        #: where the bus hands over whole datagrams raw (:meth:`LoopbackBus.recv_frames`)
        self._raw = bool(getattr(bus, "raw_frames", False))
        self._channel = getattr(bus, "channel", None)
        super().__init__(bus, listeners, timeout)

    def receive(self, bus: can.BusABC, timeout: float | None):
        """Receive what the bus has (one datagram's frames where it hands them over raw, else
        one frame), waiting at most ``timeout``, and deliver it: the tap, the fast handlers,
        the listeners. Returns the last Message made, a count of frames taken raw, or None."""
        if self._raw and bus.raw_frames:
            got = bus.recv_frames(timeout)
            if got is None:
                return None
            with self._lock:
                return self._deliver_raw(got[0], got[1])
        msg = bus.recv(timeout)
        if msg is None:
            return None
        with self._lock:
            if self.tap is None and not self.fast:
                self._on_message_received(msg)
            else:
                self._deliver_raw(msg.timestamp, [wire.raw_of(msg)], msg)
        return msg

    def _deliver_raw(self, stamp: float, frames, msg: can.Message | None = None):
        if self.tap is not None:
            self.tap(stamp, frames, True, self._channel if msg is None else msg.channel)
        fast = self.fast
        fd_ok = _FD_FLAGS if self.fast_fd else ()
        out = len(frames)
        for frame in frames:
            flags, arb_id, dlc, data = frame
            if fast and (flags == _CLASSIC or flags in fd_ok) and dlc == len(data):
                handler = fast.get(arb_id)
                if handler is not None and handler(data, stamp):
                    continue
            out = msg or wire.message(stamp, frame, self._channel)
            self._on_message_received(out)
        return out

    def _rx_thread(self, bus: can.BusABC) -> None:
        while not self._stopped:
            if self._want_bus.is_set():
                self._resume.clear()
                self._parked.set()
                self._resume.wait()
                continue
            try:
                self.receive(bus, self.timeout)
            except Exception as exc:  # as can.Notifier: listeners' on_error, else re-raise
                self.exception = exc
                if not self._on_error(exc):
                    raise
                log.debug("suppressed exception: %s", exc)

    def stop(self, timeout: float = 5.0) -> None:
        self._stopped = True
        self._resume.set()
        super().stop(timeout)

    @contextlib.contextmanager
    def handover(self, spin_s: float = 0.0, wait_s: float | None = None,
                 idle: Callable[[], bool] | None = None) -> Iterator[Callable[[float], can.Message | None]]:
        """Park the reader thread and yield ``pump(timeout)``: receive one frame, or one
        datagram's frames where the bus hands them over raw (waiting at most ``timeout`` s),
        hand them on (:meth:`receive`), return the last (or a count; None on timeout). ``spin_s``:
        poll the bus (``recv(0)``, yielding the core between polls) up to that long before
        sleeping in ``recv``: a sleeping thread takes ~15 µs to wake, most of a lockstep round
        trip. ``idle()``: a small piece of the caller's own work, done between polls instead of
        yielding the core (True: it did some). The bus is given back when the block ends, even
        on an exception."""
        if self._stopped:
            raise RuntimeError("the notifier is stopped")
        with self._handover_lock:
            self._want_bus.set()
            try:
                if not self._parked.wait(wait_s if wait_s is not None else self.timeout + 1.0):
                    raise RuntimeError("the bus reader thread did not hand the bus over")
                bus = self.bus
                receive = self.receive
                clock = time.perf_counter
                yield_cpu = getattr(os, "sched_yield", lambda: None)

                def pump(timeout: float):
                    msg = None
                    if spin_s > 0:
                        start = clock()
                        stop = start + min(spin_s, timeout)
                        while msg is None and clock() < stop:
                            msg = receive(bus, 0)
                            if msg is None and not (idle is not None and idle()):
                                yield_cpu()     # a peer waiting for this core runs first
                        if msg is None:
                            msg = receive(bus, max(0.0, timeout - (clock() - start)))
                    else:
                        msg = receive(bus, timeout)
                    return msg

                yield pump
            finally:
                self._want_bus.clear()
                self._parked.clear()
                self._resume.set()


@contextlib.contextmanager
def handover_many(notifiers: "list[HandoverNotifier]", spin_s: float = 0.0,
                  idle_poll_s: float = 0.001,
                  idle: Callable[[], bool] | None = None) -> Iterator[Callable[[float], can.Message | None]]:
    """:meth:`HandoverNotifier.handover` over several buses at once (a rig's buses): every
    reader thread parks, and the one ``pump(timeout)`` receives a frame from whichever bus has
    one (round robin, so no bus starves), handing it to that bus's listeners. It polls all buses
    for ``spin_s`` before it sleeps (doing a piece of ``idle()`` work between polls where
    given, as :meth:`HandoverNotifier.handover`), then waits on the buses' file descriptors (at
    most ``idle_poll_s`` at a time, so a bus whose frames do not wake its descriptor, e.g. one
    delaying frames on purpose, is still polled); a bus without a descriptor is polled. Where
    every descriptor can be watched, one epoll tells which buses to ask, in the spin too."""
    with contextlib.ExitStack() as stack:
        pumps = [stack.enter_context(n.handover(0.0)) for n in notifiers]
        if len(pumps) == 1 and spin_s == 0.0:
            yield pumps[0]
            return
        descriptors = []
        for n in notifiers:
            try:
                fd = n.bus.fileno()
            except (AttributeError, NotImplementedError, OSError, ValueError):
                fd = -1
            descriptors.append(fd)
        waitable = all(fd is not None and fd >= 0 for fd in descriptors)
        clock = time.perf_counter
        yield_cpu = getattr(os, "sched_yield", lambda: None)
        count = len(pumps)
        first = [0]
        # where every bus's descriptor can be watched: one epoll says which buses have a datagram
        # (one call, ~0.3 µs, where asking each bus's socket cost ~2 µs a bus). Only a bus taken
        # raw whose frames all show on its descriptor (``frames_only_when_readable``: nothing
        # left queued by a ``recv``, nothing held back by fault injection; taken raw, nothing
        # is queued later) is skipped while it is not ready; any other is asked every time
        poller = None
        if waitable and len(set(descriptors)) == count and hasattr(select, "epoll"):
            try:
                poller = stack.enter_context(select.epoll())
                for fd in descriptors:
                    poller.register(fd, select.EPOLLIN)
            except OSError:
                poller = None
        skippable = [bool(getattr(n, "_raw", False) and getattr(n.bus, "raw_frames", False)
                          and getattr(n.bus, "frames_only_when_readable", False)) for n in notifiers]
        every_skippable = all(skippable)
        index_of = {fd: k for k, fd in enumerate(descriptors)}
        receivers = [functools.partial(n.receive, n.bus) for n in notifiers]
        poll = poller.poll if poller is not None else None

        def pump(timeout: float) -> can.Message | None:
            start = clock()
            end = start + timeout
            spin_end = start + min(spin_s, timeout)
            while True:
                k0 = first[0]
                if poller is not None and every_skippable:
                    events = poll(0)
                    if events:                # the ready bus next in the round, taken at once
                        if len(events) == 1:
                            k = index_of[events[0][0]]
                        else:
                            k = min((index_of[fd] for fd, _ in events), key=lambda k: (k - k0) % count)
                        msg = receivers[k](0.0)
                        if msg is not None:
                            first[0] = (k + 1) % count
                            return msg
                elif poller is not None:
                    ready = {fd for fd, _ in poll(0)}
                    for j in range(count):
                        k = (k0 + j) % count
                        if descriptors[k] in ready or not skippable[k]:
                            msg = pumps[k](0.0)
                            if msg is not None:
                                first[0] = (k + 1) % count
                                return msg
                else:
                    for j in range(count):
                        k = (k0 + j) % count
                        msg = pumps[k](0.0)
                        if msg is not None:
                            first[0] = (k + 1) % count
                            return msg
                now = clock()
                if now >= end:
                    return None
                if now < spin_end:
                    if idle is None or not idle():
                        yield_cpu()
                elif waitable:      # (select: epoll's timeout is rounded up to whole milliseconds)
                    try:
                        select.select(descriptors, [], [], min(end - now, idle_poll_s))
                    except (OSError, ValueError):
                        time.sleep(min(end - now, idle_poll_s))
                else:
                    time.sleep(min(end - now, idle_poll_s / 10))

        yield pump
