"""One frame on several buses at once: a rig's SYNCs, with nothing of this process between them.

Python lets go of the GIL in every socket call, and python-can's SocketCAN ``send`` makes two
(``select``, then ``send``). While the first bus's frame is in the kernel, another thread of the
process (a capture formatting its batch, the recorder) can take the GIL and keep it for up to a
switch interval, and the second bus's SYNC leaves that much later. Here each frame goes to the
kernel through libc's ``sendto`` called with :class:`ctypes.PyDLL`, which keeps the GIL for the
call, non-blocking: between two buses' frames only this thread runs (stamp, encode, one system
call each). Measured: docs/decisions.md (the skew's tail narrowed in seven pairs of seven).

A bus this module does not know (python-can's virtual bus, a vendor's interface), a full send
buffer or a system-call error sends that frame the ordinary way (``bus.send``), which waits or
raises as that bus does.
"""
from __future__ import annotations

import ctypes
import socket
import struct
import time
from typing import Callable, Sequence

import can

from . import wire
from .loopback import LoopbackBus

MSG_DONTWAIT = getattr(socket, "MSG_DONTWAIT", 0x40)

try:
    _libc = ctypes.PyDLL(None, use_errno=True)      # PyDLL: the GIL is kept during the call
    _sendto = _libc.sendto
    _sendto.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_size_t, ctypes.c_int,
                        ctypes.c_char_p, ctypes.c_uint32)
    _sendto.restype = ctypes.c_ssize_t
except (OSError, AttributeError):                   # no libc sendto (not a POSIX host)
    _sendto = None


class RawPath:
    """How to hand one bus a frame in a single system call: its socket, the destination
    address (None: the socket's own) and the frame's bytes for a message stamped at a time."""

    __slots__ = ("fd", "address", "encode", "encode_raw")

    def __init__(self, fd: int, address: bytes | None,
                 encode: Callable[[can.Message, float], bytes],
                 encode_raw: Callable[[tuple, float], bytes] | None = None) -> None:
        self.fd, self.address, self.encode = fd, address, encode
        #: the bytes of a raw frame ``(flags, arbitration_id, dlc, data)`` stamped at a time
        self.encode_raw = encode_raw or (lambda frame, stamp: encode(wire.message(stamp, frame, None, False), stamp))


def _sockaddr_in(host: str, port: int) -> bytes:
    """A ``struct sockaddr_in`` (Linux layout: family in host order, port and address in
    network order, 8 bytes of padding)."""
    return struct.pack("=H", socket.AF_INET) + struct.pack("!H", port) + socket.inet_aton(host) + bytes(8)


def raw_path(bus: can.BusABC) -> RawPath | None:
    """The single-call send path of ``bus``, or None where this module does not know one."""
    if _sendto is None:
        return None
    if isinstance(bus, LoopbackBus):
        sender = bus._sender_id
        head = wire.HEADER.pack

        def encode_raw(frame, stamp: float) -> bytes:
            flags, arb_id, dlc, data = frame
            return head(wire.MAGIC, wire.VERSION, flags, sender, stamp, arb_id, dlc & 0xFF, len(data)) + data
        return RawPath(bus._socket.fileno(), _sockaddr_in(*bus._destination),
                       lambda msg, stamp: wire.pack(msg, sender, stamp), encode_raw)
    try:
        from can.interfaces.socketcan.socketcan import SocketcanBus, build_can_frame
    except ImportError:                             # pragma: no cover - not on Linux
        return None
    if isinstance(bus, SocketcanBus) and bus.channel:   # bound to its interface: plain send
        return RawPath(bus.socket.fileno(), None, lambda msg, stamp: build_can_frame(msg))
    return None


def send_together(buses: Sequence[can.BusABC], msgs: Sequence[can.Message],
                  paths: Sequence[RawPath | None] | None = None) -> list[float]:
    """Send ``msgs[i]`` on ``buses[i]``, one after the other with the GIL held (module
    docstring); each message's ``timestamp`` is set to the wall-clock time it was handed to its
    bus, and those times are returned (0.0, the timestamp untouched, for a frame not sent). A
    bus that fails does not keep the frame from the others; the first failure is raised after
    all were tried. ``paths`` (from :func:`raw_path`, one per bus) saves looking them up."""
    if paths is None:
        paths = [raw_path(b) for b in buses]
    stamps = [0.0] * len(buses)
    try:
        _send_each(buses, msgs, paths, stamps, raw=False)
    finally:
        for msg, stamp in zip(msgs, stamps):
            if stamp:
                msg.timestamp = stamp
    return stamps


def send_frames_together(buses: Sequence[can.BusABC], frames: Sequence[tuple],
                         paths: Sequence[RawPath | None], stamps: list[float]) -> list[float]:
    """:func:`send_together` of raw frames (``frames[i]``, ``(flags, arbitration_id, dlc,
    data)``, on ``buses[i]``), without a :class:`can.Message` where a bus has a single-call
    path: ``stamps[i]`` is set to the wall-clock time frame i was handed to its bus (left as
    it was for a frame not sent) before the first failure, if any, is raised."""
    _send_each(buses, frames, paths, stamps, raw=True)
    return stamps


def _send_each(buses, items, paths, stamps: list[float], raw: bool) -> None:
    """``items[i]`` (a :class:`can.Message`, or with ``raw`` a raw frame) on ``buses[i]``, by
    its single-call path where it has one, else by ``bus.send``; ``stamps[i]`` set to the time
    each was handed over; the first failure raised after all were tried."""
    fallback: list[int] = []
    for i, (path, item) in enumerate(zip(paths, items)):
        if path is not None:
            stamp = time.time()
            data = path.encode_raw(item, stamp) if raw else path.encode(item, stamp)
            address = path.address
            sent = _sendto(path.fd, data, len(data), MSG_DONTWAIT, address,
                           len(address) if address is not None else 0)
            if sent == len(data):
                stamps[i] = stamp
                continue
        fallback.append(i)     # bus.send waits for a full buffer, or says what went wrong
    failure = None
    for i in fallback:
        try:
            stamp = time.time()
            buses[i].send(wire.message(stamp, items[i], None, False) if raw else items[i])
            stamps[i] = stamp
        except can.CanError as exc:
            failure = failure or exc
    if failure is not None:
        raise failure
