"""The datagram format of the loopback bus: one CAN (FD) frame per UDP datagram, or a batch of
frames sent at one instant (a node's answers to a SYNC, a master's commands of a cycle).

This is the only place that knows the byte layout. Layout (network byte order), version 1, one
frame::

    offset size field
    0      2    magic b"SB"
    2      1    format version (1)
    3      1    flags: bit0 extended id, bit1 remote, bit2 error frame,
                       bit3 FD, bit4 bit-rate switch, bit5 error-state indicator
    4      8    sender id (random per bus instance; lets a receiver drop its own frames)
    12     8    timestamp, seconds since the epoch (float64), taken when the frame was sent
    20     4    arbitration id
    24     1    DLC as sent (may exceed the data length for classic CAN DLC 9..15)
    25     1    number of data bytes that follow (0..64)
    26     n    data

A classic CAN frame with 8 data bytes is 34 bytes on the wire.

Version 2, a batch (the frames one sender handed the bus at one instant, in order; a receiver
delivers them one by one, every frame stamped with the batch's time)::

    offset size field
    0      2    magic b"SB"
    2      1    format version (2)
    3      1    number of frames that follow (1..255)
    4      8    sender id (where version 1 has it: the kernel's own-frame filter reads it there)
    12     8    timestamp, seconds since the epoch (float64)
    20          per frame: flags (1), arbitration id (4), DLC as sent (1), data bytes (1), data

A frame in a batch is what python-can would see in a datagram of its own: a receiver that only
knows :func:`unpack` is told it is not a version-1 frame and counts it as malformed, nothing
worse. The raw form of a frame, for the paths that never make a :class:`can.Message` of the
cyclic frames, is the tuple ``(flags, arbitration_id, dlc, data)``.
"""
from __future__ import annotations

import struct

import can

MAGIC = b"SB"
VERSION = 1
BATCH_VERSION = 2
HEADER = struct.Struct("!2sBBQdIBB")
HEADER_SIZE = HEADER.size
BATCH_HEADER = struct.Struct("!2sBBQd")
BATCH_FRAME = struct.Struct("!BIBB")
#: the most frames one batch datagram carries
MAX_BATCH = 255
MAX_DATAGRAM = BATCH_HEADER.size + MAX_BATCH * (BATCH_FRAME.size + 64)

FLAG_EXTENDED = 0x01
FLAG_REMOTE = 0x02
FLAG_ERROR = 0x04
FLAG_FD = 0x08
FLAG_BRS = 0x10
FLAG_ESI = 0x20


class WireFormatError(ValueError):
    """A datagram that is not a frame of this bus (wrong magic, version or length)."""


def pack(msg: can.Message, sender_id: int, timestamp: float) -> bytes:
    """Encode ``msg`` as one datagram, stamped with ``timestamp`` and ``sender_id``."""
    flags = (
        (FLAG_EXTENDED if msg.is_extended_id else 0)
        | (FLAG_REMOTE if msg.is_remote_frame else 0)
        | (FLAG_ERROR if msg.is_error_frame else 0)
        | (FLAG_FD if msg.is_fd else 0)
        | (FLAG_BRS if msg.bitrate_switch else 0)
        | (FLAG_ESI if msg.error_state_indicator else 0)
    )
    data = bytes(msg.data) if msg.data is not None else b""
    if len(data) > 64:
        raise ValueError(f"a CAN frame carries at most 64 data bytes, got {len(data)}")
    return HEADER.pack(
        MAGIC, VERSION, flags, sender_id, timestamp, msg.arbitration_id,
        msg.dlc & 0xFF, len(data),
    ) + data


def flags_of(msg: can.Message) -> int:
    """The wire flags of ``msg``."""
    return ((FLAG_EXTENDED if msg.is_extended_id else 0)
            | (FLAG_REMOTE if msg.is_remote_frame else 0)
            | (FLAG_ERROR if msg.is_error_frame else 0)
            | (FLAG_FD if msg.is_fd else 0)
            | (FLAG_BRS if msg.bitrate_switch else 0)
            | (FLAG_ESI if msg.error_state_indicator else 0))


def raw_of(msg: can.Message) -> tuple[int, int, int, bytes]:
    """``msg`` as a raw frame ``(flags, arbitration_id, dlc, data)``."""
    return (flags_of(msg), msg.arbitration_id, msg.dlc & 0xFF,
            bytes(msg.data) if msg.data is not None else b"")


def message(timestamp: float, frame: tuple[int, int, int, bytes], channel=None,
            is_rx: bool = True) -> can.Message:
    """A raw frame as the :class:`can.Message` a receiver hands its listeners."""
    flags, arb_id, dlc, data = frame
    return can.Message(
        timestamp=timestamp, arbitration_id=arb_id,
        is_extended_id=bool(flags & FLAG_EXTENDED), is_remote_frame=bool(flags & FLAG_REMOTE),
        is_error_frame=bool(flags & FLAG_ERROR), is_fd=bool(flags & FLAG_FD),
        bitrate_switch=bool(flags & FLAG_BRS), error_state_indicator=bool(flags & FLAG_ESI),
        dlc=dlc, data=data, channel=channel, is_rx=is_rx, check=False)


def pack_batch(frames, sender_id: int, timestamp: float) -> bytes:
    """Raw frames ``(flags, arbitration_id, dlc, data)`` (1 to :data:`MAX_BATCH`) as one
    version-2 datagram."""
    n = len(frames)
    if not 1 <= n <= MAX_BATCH:
        raise ValueError(f"a batch carries 1 to {MAX_BATCH} frames, not {n}")
    parts = [BATCH_HEADER.pack(MAGIC, BATCH_VERSION, n, sender_id, timestamp)]
    frame = BATCH_FRAME.pack
    for flags, arb_id, dlc, data in frames:
        if len(data) > 64:
            raise ValueError(f"a CAN frame carries at most 64 data bytes, got {len(data)}")
        parts.append(frame(flags, arb_id, dlc & 0xFF, len(data)))
        parts.append(data)
    return b"".join(parts)


def unpack_frames(datagram: bytes) -> tuple[int, float, list[tuple[int, int, int, bytes]]]:
    """Any datagram of this bus (version 1 or 2) as ``(sender_id, timestamp, raw frames)``.

    Raises :class:`WireFormatError` for anything that is not well formed."""
    size = len(datagram)
    if size < BATCH_HEADER.size:
        raise WireFormatError(f"datagram of {size} bytes is shorter than the header")
    magic, version, third, sender, ts = BATCH_HEADER.unpack_from(datagram)
    if magic != MAGIC:
        raise WireFormatError("not a loopback-bus frame (wrong magic)")
    if version == VERSION:
        if size < HEADER_SIZE:
            raise WireFormatError(f"datagram of {size} bytes is shorter than the header")
        arb_id, dlc, n = struct.unpack_from("!IBB", datagram, BATCH_HEADER.size)
        if n > 64 or size != HEADER_SIZE + n:
            raise WireFormatError(f"datagram length {size} does not match its {n} data bytes")
        return sender, ts, [(third, arb_id, dlc, datagram[HEADER_SIZE:])]
    if version != BATCH_VERSION or third == 0:
        raise WireFormatError("not a loopback-bus frame (wrong version or an empty batch)")
    frames, _ = _batch(datagram, third, None)
    return sender, ts, frames


def _batch(datagram: bytes, count: int, fd: bool | None) -> tuple[list, int]:
    """A batch datagram's ``count`` frames, in one pass: every one (``fd`` None), or those a
    bus keeps (FD frames only if ``fd``; a classic frame of more than 8 bytes dropped and
    counted); ``(frames, dropped oversized)``. Raises :class:`WireFormatError` for a batch
    that is not well formed, whatever its frames."""
    size = len(datagram)
    kept = []
    append = kept.append
    oversized = 0
    at = BATCH_HEADER.size
    head = BATCH_FRAME.unpack_from
    step = BATCH_FRAME.size
    for _ in range(count):
        if at + step > size:
            raise WireFormatError("a batch datagram shorter than its frames")
        flags, arb_id, dlc, n = head(datagram, at)
        at += step
        if n > 64 or at + n > size:
            raise WireFormatError("a batch datagram shorter than its frames")
        if fd is None or (fd if flags & FLAG_FD else n <= 8):
            append((flags, arb_id, dlc, datagram[at:at + n]))
        elif not flags & FLAG_FD:        # no classic frame carries more than 8 bytes
            oversized += 1
        at += n
    if at != size:
        raise WireFormatError(f"batch datagram length {size} does not match its frames")
    return kept, oversized


def unpack_for_bus(datagram: bytes, fd: bool) -> tuple[int, float, list, int]:
    """:func:`unpack_frames` and a bus's rules in one pass (the receive path of every frame):
    ``(sender_id, timestamp, frames kept, classic frames dropped for carrying more than 8
    bytes)``; FD frames are dropped unless ``fd``. Raises :class:`WireFormatError` for a
    datagram that is not well formed, whatever its frames."""
    size = len(datagram)
    if size < BATCH_HEADER.size:
        raise WireFormatError(f"datagram of {size} bytes is shorter than the header")
    magic, version, count, sender, ts = BATCH_HEADER.unpack_from(datagram)
    if version == BATCH_VERSION and magic == MAGIC and count:
        kept, oversized = _batch(datagram, count, fd)
    else:                       # a single frame, or the error it is
        sender, ts, frames = unpack_frames(datagram)
        kept, oversized = [], 0
        for frame in frames:
            if frame[0] & FLAG_FD:
                if fd:
                    kept.append(frame)
            elif len(frame[3]) > 8:
                oversized += 1
            else:
                kept.append(frame)
    return sender, ts, kept, oversized


def unpack(datagram: bytes, channel: str | None = None) -> tuple[can.Message, int]:
    """Decode one datagram into ``(message, sender_id)``.

    Raises :class:`WireFormatError` for anything that is not a well-formed frame.
    """
    if len(datagram) < HEADER_SIZE:
        raise WireFormatError(f"datagram of {len(datagram)} bytes is shorter than the header")
    magic, version, flags, sender, ts, arb_id, dlc, n = HEADER.unpack_from(datagram)
    if magic != MAGIC or version != VERSION:
        raise WireFormatError("not a loopback-bus frame (wrong magic or version)")
    if n > 64 or len(datagram) != HEADER_SIZE + n:
        raise WireFormatError(
            f"datagram length {len(datagram)} does not match its {n} data bytes")
    msg = can.Message(
        timestamp=ts,
        arbitration_id=arb_id,
        is_extended_id=bool(flags & FLAG_EXTENDED),
        is_remote_frame=bool(flags & FLAG_REMOTE),
        is_error_frame=bool(flags & FLAG_ERROR),
        is_fd=bool(flags & FLAG_FD),
        bitrate_switch=bool(flags & FLAG_BRS),
        error_state_indicator=bool(flags & FLAG_ESI),
        dlc=dlc,
        data=datagram[HEADER_SIZE:],
        channel=channel,
        check=False,
    )
    return msg, sender
