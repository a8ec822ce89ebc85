"""Raw bus: frames/s one way and request/response round trips/s, our loopback bus between two
processes beside python-can's in-process ``virtual`` bus, measured in the same run."""
from __future__ import annotations

import multiprocessing as mp
import os
import threading
import time

import can

from .table import Row

ORDER = 50
PING, PONG, STOP = 0x601, 0x581, 0x7FF


def _frame(arb: int, i: int = 0) -> can.Message:
    return can.Message(arbitration_id=arb, data=i.to_bytes(4, "little") + b"\0\0\0\0", is_extended_id=False)


def _echo(interface: str, channel: str, ready) -> None:
    bus = can.Bus(interface=interface, channel=channel)
    ready.set()
    while True:
        m = bus.recv(5.0)
        if m is None or m.arbitration_id == STOP:
            break
        if m.arbitration_id == PING:
            bus.send(_frame(PONG))
    bus.shutdown()


def _sink(interface: str, channel: str, n: int, ready, result) -> None:
    bus = can.Bus(interface=interface, channel=channel)
    ready.set()
    got, first = 0, None
    while got < n:
        m = bus.recv(5.0)
        if m is None:
            break
        if first is None:
            first = time.perf_counter()
        got += 1
    result.put((got, time.perf_counter() - (first or time.perf_counter())))
    bus.shutdown()


def one_way(interface: str, channel: str, n: int, use_process: bool) -> tuple[float, int]:
    """Frames per second from one sender to one receiver (thread for ``virtual``)."""
    if use_process:
        ready, result = mp.Event(), mp.Queue()
        peer = mp.Process(target=_sink, args=(interface, channel, n, ready, result))
    else:
        import queue
        ready, result = threading.Event(), queue.Queue()
        peer = threading.Thread(target=_sink, args=(interface, channel, n, ready, result))
    peer.start()
    ready.wait(10)
    time.sleep(0.2)
    bus = can.Bus(interface=interface, channel=channel)
    for i in range(n):
        bus.send(_frame(0x182, i))
    got, elapsed = result.get(timeout=60)
    peer.join(10)
    bus.shutdown()
    return (got - 1) / elapsed if elapsed > 0 else float("nan"), n - got


def round_trips(interface: str, channel: str, n: int, use_process: bool) -> float:
    ready = mp.Event() if use_process else threading.Event()
    peer = (mp.Process if use_process else threading.Thread)(target=_echo, args=(interface, channel, ready))
    peer.start()
    ready.wait(10)
    time.sleep(0.2)
    bus = can.Bus(interface=interface, channel=channel)
    t0 = time.perf_counter()
    done = 0
    for i in range(n):
        bus.send(_frame(PING, i))
        while True:
            m = bus.recv(2.0)
            if m is None or m.arbitration_id == PONG:
                break
        if m is None:
            break
        done += 1
    elapsed = time.perf_counter() - t0
    bus.send(_frame(STOP))
    peer.join(10)
    bus.shutdown()
    return done / elapsed


def run(quick: bool) -> list[Row]:
    n_frames = 5_000 if quick else 200_000
    n_rt = 500 if quick else 20_000
    tag = f"bench-bus-{os.getpid()}"
    ours_fps, ours_lost = one_way("udp_loopback", tag + "-a", n_frames, use_process=True)
    virt_fps, _ = one_way("virtual", tag + "-b", n_frames, use_process=False)
    ours_rt = round_trips("udp_loopback", tag + "-c", n_rt, use_process=True)
    virt_rt = round_trips("virtual", tag + "-d", n_rt, use_process=False)
    return [
        Row("raw bus: one way", f"{ours_fps:,.0f} frames/s (udp_loopback, 2 processes)",
            f"virtual (1 process, threads): {virt_fps:,.0f} frames/s", f"{ours_fps / virt_fps:.2f}x",
            f"{n_frames:,} frames" + (f", {ours_lost} not received" if ours_lost else ", none lost")),
        Row("raw bus: request/response", f"{ours_rt:,.0f} round trips/s (udp_loopback, 2 processes)",
            f"virtual (1 process, threads): {virt_rt:,.0f} /s", f"{ours_rt / virt_rt:.2f}x",
            f"{n_rt:,} round trips"),
    ]
