"""The datagram format of the loopback bus: one CAN (FD) frame per UDP datagram.

This is the only place that knows the byte layout. Layout (network byte order)::

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
"""
from __future__ import annotations

import struct

import can

MAGIC = b"SB"
VERSION = 1
HEADER = struct.Struct("!2sBBQdIBB")
HEADER_SIZE = HEADER.size
MAX_DATAGRAM = HEADER_SIZE + 64

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
