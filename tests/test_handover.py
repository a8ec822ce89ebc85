"""HandoverNotifier: the lockstep loop receives on its own thread while the reader thread parks,
and every frame still reaches every listener exactly once, in order."""
from __future__ import annotations

import threading
import time

import can
import pytest

from standbus import HandoverNotifier
from standbus.loopback import LoopbackBus


def frame(i: int) -> can.Message:
    return can.Message(arbitration_id=0x180, data=i.to_bytes(2, "little"), is_extended_id=False)


def test_frames_reach_every_listener_once_in_order_across_handovers(channel):
    sender, bus = LoopbackBus(channel), LoopbackBus(channel)
    got: list[tuple[int, str]] = []
    notifier = HandoverNotifier(bus, [lambda m: got.append((int.from_bytes(m.data, "little"),
                                                             threading.current_thread().name))],
                                timeout=0.005)
    try:
        main = threading.current_thread().name
        i = 0
        for spin in (0.0, 0.001, 0.0):
            for _ in range(100):                     # the reader thread delivers
                sender.send(frame(i)); i += 1
            time.sleep(0.05)
            with notifier.handover(spin_s=spin) as pump:
                first = i
                for _ in range(100):                 # the caller delivers
                    sender.send(frame(i)); i += 1
                    msg = pump(1.0)
                    assert msg is not None
                assert pump(0.02) is None            # times out cleanly
                assert all(t == main for n, t in got if n >= first)
        for _ in range(50):                          # and the reader thread takes over again
            sender.send(frame(i)); i += 1
        deadline = time.monotonic() + 2
        while len(got) < i and time.monotonic() < deadline:
            time.sleep(0.01)
        assert [n for n, _ in got] == list(range(i))
        assert got[-1][1] != main
    finally:
        notifier.stop(); sender.shutdown(); bus.shutdown()


def test_the_bus_goes_back_to_the_reader_after_an_exception(channel):
    sender, bus = LoopbackBus(channel), LoopbackBus(channel)
    got = []
    notifier = HandoverNotifier(bus, [got.append], timeout=0.005)
    try:
        with pytest.raises(KeyError):
            with notifier.handover():
                raise KeyError("boom")
        sender.send(frame(1))
        deadline = time.monotonic() + 2
        while not got and time.monotonic() < deadline:
            time.sleep(0.01)
        assert len(got) == 1
    finally:
        notifier.stop(); sender.shutdown(); bus.shutdown()
    with pytest.raises(RuntimeError, match="stopped"):
        with notifier.handover():
            pass


@pytest.mark.parametrize("spin", [0.0, 0.002])
def test_handover_many_delivers_every_frame_of_every_bus_the_poller_skipping_only_idle_raw_buses(channel, spin):
    """Three buses on one pump: a plain one (taken raw: the poller skips it while its socket is
    idle), one delaying its frames on purpose (fault injection: its frames come due without
    waking its socket) and one hearing its own frames (not raw: a batch's frames queued behind
    its socket). Every frame reaches its bus's listener once, in order, the delayed ones after
    their delay."""
    from standbus import wire
    from standbus.handover import handover_many
    names = [f"{channel}-plain", f"{channel}-slow", f"{channel}-own"]
    senders = [LoopbackBus(n) for n in names]
    buses = [LoopbackBus(names[0]), LoopbackBus(names[1], delay_ms=20.0),
             LoopbackBus(names[2], receive_own_messages=True)]
    got: list[list[int]] = [[], [], []]
    notifiers = [HandoverNotifier(b, [lambda m, k=k: got[k].append(int.from_bytes(m.data, "little"))],
                                  timeout=0.005) for k, b in enumerate(buses)]
    try:
        assert buses[0].frames_only_when_readable and not buses[1].frames_only_when_readable
        with handover_many(notifiers, spin_s=spin) as pump:
            sent = time.monotonic()
            for i in range(0, 30, 3):        # batches: three frames in one datagram
                for s in senders:
                    s.send_frames([wire.raw_of(frame(j)) for j in (i, i + 1, i + 2)])
            deadline = time.monotonic() + 3.0
            while any(len(g) < 30 for g in got) and time.monotonic() < deadline:
                pump(0.05)
                if len(got[1]) == 0:
                    assert time.monotonic() - sent < 0.02 + 0.5   # (the delayed bus not yet due)
            assert all(g == list(range(30)) for g in got), got
            assert pump(0.01) is None
    finally:
        for n in notifiers:
            n.stop()
        for b in senders + buses:
            b.shutdown()


@pytest.mark.serial
def test_handover_many_waits_no_longer_than_asked_below_a_millisecond(channel):
    """The real-time loop waits for its answers and its next SYNC's time in slices of a
    fraction of a millisecond: a pump over several buses with nothing to receive returns after
    about the time asked, not a whole millisecond later (epoll's own timeout rounds up to whole
    milliseconds; the wait is select's)."""
    from standbus.handover import handover_many
    buses = [LoopbackBus(f"{channel}-{k}") for k in range(3)]
    notifiers = [HandoverNotifier(b, [], timeout=0.005) for b in buses]
    try:
        with handover_many(notifiers, spin_s=0.0) as pump:
            took = []
            for _ in range(31):
                t0 = time.perf_counter()
                assert pump(0.0002) is None
                took.append(time.perf_counter() - t0)
        took.sort()
        assert took[15] < 0.0008, took        # the median: an epoll wait would be >= 1 ms each
    finally:
        for n in notifiers:
            n.stop()
        for b in buses:
            b.shutdown()
