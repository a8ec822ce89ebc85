"""A multi-process CAN bus pinned to the loopback interface (python-can interface ``udp_loopback``).

Every bus instance opens one UDP socket that joins an IPv4 multicast group **on 127.0.0.1
only** and sends with ``IP_MULTICAST_IF = 127.0.0.1`` and TTL 0, so no datagram ever leaves the
host and nobody on the LAN can join the bus. Any number of processes on the same host that open
the same *channel* share one bus; different channels are independent buses (several benches side
by side).

It behaves like SocketCAN where it matters to CANopen stacks:

* a sender does not receive its own frames unless ``receive_own_messages=True``;
* frame flags (extended id, remote, error, FD, BRS, ESI), the DLC and the data are carried intact;
* the timestamp is the sender's wall-clock time at transmission (the same clock for every
  process on the host), so captures taken by different processes agree.

Several frames sent at one instant (a node's answers to a SYNC, a master's commands of a cycle)
can travel as one datagram (:meth:`LoopbackBus.send_frames`): a receiver's ``recv`` still
returns them one by one, so every python-can tool sees every frame, while the project's own
cyclic paths take a datagram's frames raw (:meth:`LoopbackBus.recv_frames`), without a
:class:`can.Message` each. A rig's bus of 8 channels then costs one system call per cycle and
side instead of 17 (docs/decisions.md).

Like any datagram transport it does not arbitrate by id. Frames from one sender arrive in order.

Usage from any python-can tool::

    python -m can.logger -i udp_loopback -c stand0
    python -m can.viewer -i udp_loopback -c stand0

The channel is a name (``stand0``, ``bench-B``), which is hashed to a group and a port, or an
explicit ``239.x.y.z:port``.

Namespaces: with the environment variable ``HYDROSTAND_LOOPBACK_NAMESPACE=NAME`` every channel
*name* a process opens (and its child processes, which inherit it) is a bus of that namespace
only: ``stand0`` in namespace ``ci-7`` is another bus than ``stand0`` without one or in ``ci-8``.
The commands, their options and what they print stay the same, so a test can run the
documented ``stand emulate &`` / ``stand run`` on the default bus without meeting anyone else's
(the documentation tests do: docs/testing.md). An explicit ``GROUP:PORT`` is never namespaced.

Fault injection (tests, drills; see :mod:`standbus.faults`): the options ``drop`` (probability
that a received frame is lost), ``delay_ms`` (every received frame arrives that much later),
``fault_ids`` (id range they apply to, e.g. ``0x080-0x4FF``; default all) and ``seed`` make
this endpoint a lossy or slow receiver::

    stand run meander --bus udp_loopback:stand0,drop=0.1,fault_ids=0x080-0x4FF,seed=1 ...

Busy polling (option ``busy_poll_us``, like Linux's ``SO_BUSY_POLL``): a receive that finds no
frame keeps polling the socket for up to that long before it sleeps in ``select``. Waking a
sleeping process costs ~15 µs here, most of a lockstep round trip (38 µs sleeping, 8 µs
polling, Python to Python); the lockstep gateway and emulator poll, everything else sleeps.
The poller yields its core between polls (``sched_yield``): with more busy processes than cores,
one that kept its core would starve its own peer (two lockstep stands on two cores: 520
cycles/s each without the yield, 4,800 with it; one stand alone: 10,000).
"""
from __future__ import annotations

import collections
import ctypes
import errno
import logging
import os
import select
import socket
import struct
import sys
import time
import zlib
from typing import Any

import can
from can import BusABC, CanProtocol, Message

from . import wire
from .faults import FaultInjector, FaultSpec

log = logging.getLogger(__name__)

LOOPBACK = "127.0.0.1"
DEFAULT_CHANNEL = "stand0"
#: environment variable: the namespace of every channel name this process opens (module doc)
NAMESPACE_VARIABLE = "HYDROSTAND_LOOPBACK_NAMESPACE"
#: Organization-local multicast scope (RFC 2365); combined with the loopback pinning
#: this never reaches a network.
_GROUP_PREFIX = "239.255"
_PORT_BASE = 47000
_PORT_SPAN = 2000


def resolve_channel(channel: str) -> tuple[str, int]:
    """Map a channel name to its ``(multicast group, UDP port)``.

    ``"239.255.1.2:47001"`` is taken literally; any other name is hashed (CRC-32) so the same
    name gives the same bus in every process.
    """
    if ":" in channel:
        group, _, port_text = channel.rpartition(":")
        try:
            port = int(port_text)
            packed = socket.inet_aton(group)
        except (ValueError, OSError):
            raise can.CanInitializationError(
                f"channel {channel!r} looks like GROUP:PORT but is not a valid IPv4 "
                "multicast address and port (e.g. 239.255.0.1:47001)") from None
        if not (224 <= packed[0] <= 239) or not (1 <= port <= 65535):
            raise can.CanInitializationError(
                f"channel {channel!r}: the group must be an IPv4 multicast address "
                "(224.0.0.0-239.255.255.255) and the port 1-65535")
        return group, port
    if not channel or not channel.isprintable():
        raise can.CanInitializationError(
            f"channel {channel!r} is not a usable bus name; use e.g. 'stand0'")
    h = zlib.crc32(channel.encode("utf-8"))
    return f"{_GROUP_PREFIX}.{(h >> 8) & 0xFF}.{h & 0xFF or 1}", _PORT_BASE + (h >> 16) % _PORT_SPAN


def namespaced(channel: str) -> str:
    """The channel as it is hashed: ``NAMESPACE/channel`` when ``HYDROSTAND_LOOPBACK_NAMESPACE``
    is set and the channel is a name (an explicit ``GROUP:PORT`` is taken as it is)."""
    namespace = os.environ.get(NAMESPACE_VARIABLE, "").strip()
    if not namespace or ":" in channel:
        return channel
    return f"{namespace}/{channel}"


def _open_socket(group: str, port: int) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if hasattr(socket, "SO_REUSEPORT"):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        # Bigger buffers: a burst (can.player at full speed) must not be dropped.
        for opt in (socket.SO_RCVBUF, socket.SO_SNDBUF):
            try:
                sock.setsockopt(socket.SOL_SOCKET, opt, 4 * 1024 * 1024)
            except OSError:
                pass
        # Receive only datagrams addressed to our group (binding to the group address
        # filters by destination on Linux; elsewhere fall back to the wildcard).
        try:
            sock.bind((group, port))
        except OSError:
            sock.bind(("", port))
        loopback = socket.inet_aton(LOOPBACK)
        # Join the group on the loopback interface only.
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                        socket.inet_aton(group) + loopback)
        # Send through loopback only, with TTL 0 (never forwarded), and loop back to us.
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, loopback)
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, struct.pack("B", 0))
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, struct.pack("B", 1))
        sock.setblocking(False)
        return sock
    except OSError as exc:
        sock.close()
        raise can.CanInitializationError(
            f"could not open the loopback bus on {group}:{port}: {exc}") from exc


#: what the lockstep gateway and emulator poll for: longer than a cycle's answer usually takes
#: (~0.1 ms), short enough that an idle process sleeps
LOCKSTEP_BUSY_POLL_S = 0.001


def prefer_busy_poll(bus: can.BusABC, seconds: float) -> bool:
    """Let ``bus`` poll for ``seconds`` before sleeping in a receive, unless it does not
    support it or its user chose (``busy_poll_us``, 0 turns it off). True if it now polls."""
    if not hasattr(bus, "busy_poll_s"):
        return False
    if bus.busy_poll_s is None:
        bus.busy_poll_s = float(seconds)
    return bool(bus.busy_poll_s)


_yield_cpu = getattr(os, "sched_yield", lambda: None)
_SO_ATTACH_FILTER = getattr(socket, "SO_ATTACH_FILTER", 26)


def _drop_own_frames_in_kernel(sock: socket.socket, sender_id: int) -> bool:
    """Linux: attach a classic BPF socket filter that drops datagrams carrying ``sender_id``
    (our own frames, looped back by IP_MULTICAST_LOOP for the other processes), so they never
    wake this socket's reader. The Python check in :meth:`LoopbackBus._recv_frame` stays as
    the rule; this only saves the work. False if the platform refused it."""
    if not sys.platform.startswith("linux"):
        return False
    # For a UDP socket the filter sees the UDP header (8 bytes), then our datagram; the sender
    # id is at datagram offset 4 (wire.py), big-endian: two 32-bit words.
    # A load beyond the end of the packet would drop it: shorter datagrams are accepted
    # first, so Python still sees (and counts) every malformed one.
    ld_len, ld_w_abs, jge_k, jeq_k, ret_k = 0x80, 0x20, 0x35, 0x15, 0x06
    program = [
        (ld_len, 0, 0, 0),
        (jge_k, 0, 5, 8 + 12),               # too short to carry a sender id: accept
        (ld_w_abs, 0, 0, 8 + 4),
        (jeq_k, 0, 3, sender_id >> 32),      # high word differs: accept
        (ld_w_abs, 0, 0, 8 + 8),
        (jeq_k, 0, 1, sender_id & 0xFFFFFFFF),
        (ret_k, 0, 0, 0),                    # ours: drop
        (ret_k, 0, 0, 0xFFFFFFFF),           # anyone else's: accept whole
    ]
    code = ctypes.create_string_buffer(b"".join(struct.pack("HBBI", *ins) for ins in program))
    fprog = struct.pack("HL", len(program), ctypes.addressof(code))   # struct sock_fprog
    try:
        sock.setsockopt(socket.SOL_SOCKET, _SO_ATTACH_FILTER, fprog)   # the kernel copies it
    except OSError:
        return False
    return True


class LoopbackBus(BusABC):
    """python-can bus over UDP multicast pinned to 127.0.0.1 (see the module docstring).

    :param channel: bus name (``"stand0"`` by default) or ``"GROUP:PORT"``.
    :param receive_own_messages: also deliver the frames this instance sends.
    :param fd: accept CAN FD frames (default True); if False, FD frames are refused on send
        and ignored on receive.
    :param drop, delay_ms, fault_ids, seed: fault injection on reception (see the module doc).
    :param busy_poll_us: poll this long before sleeping in a receive (see the module doc).
    """

    def __init__(
        self,
        channel: Any = DEFAULT_CHANNEL,
        receive_own_messages: bool = False,
        fd: bool = True,
        drop: float = 0.0,
        delay_ms: float = 0.0,
        fault_ids: str | int | None = None,
        seed: int | None = None,
        busy_poll_us: float | None = None,
        **kwargs: Any,
    ) -> None:
        channel = str(channel if channel is not None else DEFAULT_CHANNEL)
        #: how long a receive polls before it sleeps, s; None: not chosen (no polling, and
        #: :func:`prefer_busy_poll` may choose)
        self.busy_poll_s: float | None = None
        if busy_poll_us is not None:
            try:
                busy_poll_us = float(busy_poll_us)
            except (TypeError, ValueError):
                busy_poll_us = -1.0
            if not 0.0 <= busy_poll_us <= 1e6:
                raise can.CanInitializationError(
                    f"udp_loopback busy_poll_us must be 0-1000000 microseconds, got {busy_poll_us!r}")
            self.busy_poll_s = busy_poll_us * 1e-6
        try:
            spec = FaultSpec.from_options(drop=drop, delay_ms=delay_ms, fault_ids=fault_ids, seed=seed)
        except ValueError as exc:
            raise can.CanInitializationError(f"udp_loopback fault injection: {exc}") from None
        #: fault injection on reception (None: a perfect bus)
        self.faults: FaultInjector | None = FaultInjector(spec) if spec is not None else None
        self.group, self.port = resolve_channel(namespaced(channel))
        self._socket = _open_socket(self.group, self.port)
        self._destination = (self.group, self.port)
        self._sender_id = int.from_bytes(os.urandom(8), "big")
        self._receive_own = bool(receive_own_messages)
        #: own frames are dropped by a kernel socket filter (Linux), not only by the Python check
        self.kernel_self_filter = not self._receive_own and _drop_own_frames_in_kernel(
            self._socket, self._sender_id)
        self._can_protocol = CanProtocol.CAN_FD if fd else CanProtocol.CAN_20
        where = namespaced(channel)
        self.channel_info = (f"udp_loopback {channel}" + (f" in namespace {where.partition('/')[0]}"
                                                           if where != channel else "")
                             + f" ({self.group}:{self.port} on {LOOPBACK})")
        self.channel = channel
        #: Datagrams on the group that were not frames of this bus (counted, then dropped).
        self.malformed_datagrams = 0
        #: frames of a batch datagram not yet returned by ``recv``
        self._pending: collections.deque[Message] = collections.deque()
        super().__init__(channel=channel, **kwargs)

    # -- python-can API -------------------------------------------------------------------
    def send(self, msg: Message, timeout: float | None = None) -> None:
        if msg.is_fd and self._can_protocol is not CanProtocol.CAN_FD:
            raise can.CanOperationError("this bus was opened with fd=False; cannot send a CAN FD frame")
        self._send_datagram(wire.pack(msg, self._sender_id, time.time()), timeout)

    def _send_datagram(self, datagram: bytes, timeout: float | None) -> None:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            try:
                self._socket.sendto(datagram, self._destination)
                return
            except BlockingIOError:
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    raise can.CanOperationError("send buffer full: frame not sent") from None
                select.select([], [self._socket], [], remaining)
            except OSError as exc:
                raise can.CanOperationError(f"loopback bus send failed: {exc}") from exc

    def _recv_internal(self, timeout: float | None) -> tuple[Message | None, bool]:
        if self.faults is not None:
            return self._recv_with_faults(timeout)
        return self._recv_frame(timeout)

    def _recv_with_faults(self, timeout: float | None) -> tuple[Message | None, bool]:
        """Reception through the fault injector: lost frames never appear, delayed ones appear
        when due (frames of the affected ids keep their order)."""
        faults = self.faults
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            now = time.monotonic()
            held = faults.pop_due(now)
            if held is not None:
                return held, False
            wait = None if deadline is None else max(0.0, deadline - now)
            due = faults.next_due()
            if due is not None:
                wait = max(0.0, due - now) if wait is None else min(wait, max(0.0, due - now))
            msg, _ = self._recv_frame(wait)
            if msg is None:
                if deadline is not None and time.monotonic() >= deadline:
                    return faults.pop_due(time.monotonic()), False
                continue
            if not faults.affects(msg.arbitration_id):
                return msg, False
            if faults.lose(msg.arbitration_id):
                continue
            if faults.spec.delay_s:
                faults.hold(msg, time.monotonic())
                continue
            return msg, False

    def _recv_frame(self, timeout: float | None) -> tuple[Message | None, bool]:
        pending = self._pending
        while not pending:
            got = self._recv_datagram(timeout)
            if got is None:
                return None, False
            stamp, frames, own = got
            message, channel = wire.message, self.channel
            pending.extend(message(stamp, f, channel, not own) for f in frames)
        return pending.popleft(), False

    def _recv_datagram(self, timeout: float | None):
        """One datagram's frames as they pass this bus's rules: ``(timestamp, raw frames,
        sent by this bus)``; None on timeout."""
        deadline = None if timeout is None else time.monotonic() + timeout
        poll_until = None
        while True:
            try:
                datagram = self._socket.recv(wire.MAX_DATAGRAM + 1)
            except BlockingIOError:
                now = time.monotonic()
                remaining = None if deadline is None else deadline - now
                if remaining is not None and remaining <= 0:
                    return None
                if self.busy_poll_s:
                    if poll_until is None:
                        poll_until = now + self.busy_poll_s
                    if now < poll_until:
                        _yield_cpu()   # a peer waiting for this core runs first
                        continue
                try:
                    ready, _, _ = select.select([self._socket], [], [], remaining)
                except (OSError, ValueError) as exc:  # closed under us
                    raise can.CanOperationError(f"loopback bus receive failed: {exc}") from exc
                if not ready:
                    return None
                continue
            except OSError as exc:
                if exc.errno == errno.EBADF:
                    raise can.CanOperationError("loopback bus is shut down") from exc
                raise can.CanOperationError(f"loopback bus receive failed: {exc}") from exc
            try:   # the frames, the FD ones only on an FD bus, no classic one over 8 bytes
                sender, stamp, kept, oversized = wire.unpack_for_bus(
                    datagram, self._can_protocol is CanProtocol.CAN_FD)
            except wire.WireFormatError:
                self.malformed_datagrams += 1
                continue
            own = sender == self._sender_id
            if own and not self._receive_own:
                continue
            if oversized:
                self.malformed_datagrams += oversized
            if kept:
                return stamp, kept, own

    # -- batches: several frames in one datagram, without python-can Messages --------------------
    @property
    def raw_frames(self) -> bool:
        """Whether :meth:`recv_frames` may stand for ``recv``: not while frames are injected
        with faults (they act per frame) or this bus hears its own frames."""
        return self.faults is None and not self._receive_own

    @property
    def frames_only_when_readable(self) -> bool:
        """Whether a receive can find a frame only when the socket is readable: none left
        queued by ``recv``, none held back by fault injection (a poller may then skip this bus
        while its descriptor is not ready)."""
        return self.faults is None and not self._pending

    def recv_frames(self, timeout: float | None):
        """The next datagram's frames, raw (``(flags, arbitration_id, dlc, data)``, see
        :mod:`standbus.wire`), with their send time: ``(timestamp, frames)``, or None on
        timeout. Frames a ``recv`` left queued come first, one each. Only where
        :attr:`raw_frames` (else ``recv``)."""
        if self._pending:
            msg = self._pending.popleft()
            return msg.timestamp, [wire.raw_of(msg)]
        got = self._recv_datagram(timeout)
        return None if got is None else got[:2]

    def send_frames(self, frames, timestamp: float | None = None) -> float:
        """Send raw frames ``(flags, arbitration_id, dlc, data)`` as one datagram (several if
        more than :data:`wire.MAX_BATCH`), in order, stamped ``timestamp`` (default now); a
        receiver hands them to its listeners one by one. Returns the stamp."""
        if not frames:
            return 0.0
        if self._can_protocol is not CanProtocol.CAN_FD and any(f[0] & wire.FLAG_FD for f in frames):
            raise can.CanOperationError("this bus was opened with fd=False; cannot send a CAN FD frame")
        stamp = time.time() if timestamp is None else timestamp
        for at in range(0, len(frames), wire.MAX_BATCH):
            chunk = frames[at:at + wire.MAX_BATCH]
            if len(chunk) == 1:
                flags, arb_id, dlc, data = chunk[0]
                datagram = wire.HEADER.pack(wire.MAGIC, wire.VERSION, flags, self._sender_id, stamp,
                                            arb_id, dlc & 0xFF, len(data)) + data
            else:
                datagram = wire.pack_batch(chunk, self._sender_id, stamp)
            self._send_datagram(datagram, None)
        return stamp

    def send_batch(self, msgs, timeout: float | None = None) -> None:
        """python-can Messages as one datagram (:meth:`send_frames`)."""
        self.send_frames([wire.raw_of(m) for m in msgs])

    def fileno(self) -> int:
        return self._socket.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        try:
            self._socket.close()
        except OSError:  # pragma: no cover - nothing useful to do
            pass

    @staticmethod
    def _detect_available_configs() -> list[dict[str, Any]]:
        return [{"interface": "udp_loopback", "channel": DEFAULT_CHANNEL}]
