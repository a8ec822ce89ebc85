"""Frames as columns: the unit every capture reader yields and every decoder consumes.

A :class:`FrameChunk` holds a few hundred thousand frames as numpy arrays (one entry per frame,
in file order), so decoding is array arithmetic instead of a Python call per frame. Readers stream
a capture of any length as a sequence of chunks; memory is bounded by the chunk size.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gateway.errors import DataError

#: bits of :attr:`FrameChunk.flags`
EXTENDED = 0x01
REMOTE = 0x02
ERROR = 0x04
FD = 0x08
TX = 0x10          #: the capturing station sent the frame (candump " T", BLF direction Tx)
BRS = 0x20         #: CAN FD: bit rate switch (candump flags digit 1, BLF, python-can)
ESI = 0x40         #: CAN FD: error state indicator of the sender (candump flags digit 2, ...)

CAN_ERR_FLAG = 0x20000000   #: SocketCAN error-frame flag in a candump id


class CaptureError(DataError):
    """A capture cannot be read (unknown format, unreadable file, bad options)."""


@dataclass(frozen=True)
class Damage:
    """Where a capture stops being readable and why.

    ``line`` is 1-based (text formats), ``byte`` the offset in the file (for compressed files: in
    the uncompressed stream)."""

    path: str
    byte: int | None
    reason: str
    line: int | None = None
    frame: int | None = None          #: frames read before the damage (readers without byte offsets)

    @property
    def position(self) -> str:
        if self.line is not None:
            where = f"line {self.line}, byte {self.byte}"
        elif self.byte is not None:
            where = f"byte {self.byte}"
        else:
            where = f"after frame {self.frame}"
        return f"{self.path}: {where}"

    def __str__(self) -> str:
        return f"{self.position}: {self.reason}"


class CaptureDamaged(CaptureError):
    """A truncated or corrupted capture; :attr:`partial` holds what was decoded before the damage."""

    def __init__(self, damage: Damage, partial=None) -> None:
        super().__init__(f"{damage}; everything before it was decoded")
        self.damage = damage
        self.partial = partial


@dataclass
class FrameChunk:
    """Consecutive frames of one capture, as columns.

    Attributes
    ----------
    ts : float64 (n,)      timestamp, s (absolute when the format has it: candump, BLF)
    can_id : uint32 (n,)   arbitration id without flag bits (11 or 29 bits)
    flags : uint8 (n,)     :data:`EXTENDED` | :data:`REMOTE` | :data:`ERROR` | :data:`FD` | :data:`TX`
                           | :data:`BRS` | :data:`ESI` (the last two on CAN FD frames only)
    dlc : uint8 (n,)       number of data bytes
    data : uint8 (n, w)    payload, zero-padded; w = 8 (classic CAN) or 64 (CAN FD)
    channel : int16 (n,)   index into :attr:`channels`
    channels : list[str]   channel names as the capture spells them
    """

    ts: np.ndarray
    can_id: np.ndarray
    flags: np.ndarray
    dlc: np.ndarray
    data: np.ndarray
    channel: np.ndarray
    channels: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.ts)

    @classmethod
    def empty(cls, width: int = 8) -> "FrameChunk":
        return cls(np.empty(0, np.float64), np.empty(0, np.uint32), np.empty(0, np.uint8),
                   np.empty(0, np.uint8), np.empty((0, width), np.uint8), np.empty(0, np.int16), [])

    def take(self, index) -> "FrameChunk":
        """The frames selected by ``index`` (boolean mask, integer array or slice)."""
        return FrameChunk(self.ts[index], self.can_id[index], self.flags[index], self.dlc[index],
                          self.data[index], self.channel[index], self.channels)

    def widened(self, width: int) -> "FrameChunk":
        if self.data.shape[1] >= width:
            return self
        data = np.zeros((len(self), width), np.uint8)
        data[:, :self.data.shape[1]] = self.data
        return FrameChunk(self.ts, self.can_id, self.flags, self.dlc, data, self.channel, self.channels)

    @classmethod
    def concat(cls, chunks: list["FrameChunk"]) -> "FrameChunk":
        """Join chunks (channel indices are re-mapped onto one name list)."""
        chunks = [c for c in chunks if len(c)]
        if not chunks:
            return cls.empty()
        width = max(c.data.shape[1] for c in chunks)
        names: list[str] = []
        channel_parts = []
        for c in chunks:
            mapping = np.array([_index(names, n) for n in c.channels] or [0], np.int16)
            channel_parts.append(mapping[c.channel] if c.channels else c.channel)
        chunks = [c.widened(width) for c in chunks]
        return cls(np.concatenate([c.ts for c in chunks]), np.concatenate([c.can_id for c in chunks]),
                   np.concatenate([c.flags for c in chunks]), np.concatenate([c.dlc for c in chunks]),
                   np.concatenate([c.data for c in chunks]), np.concatenate(channel_parts), names)

    def payload(self, i: int) -> bytes:
        return bytes(self.data[i, :self.dlc[i]])


def _index(names: list[str], name: str) -> int:
    if name not in names:
        names.append(name)
    return names.index(name)


@dataclass
class ReadStats:
    """What a reader saw besides frames: skipped lines/objects, the damage if any."""

    frames: int = 0
    bytes_read: int = 0
    skipped_lines: int = 0           #: empty lines (text formats)
    damaged: int = 0                 #: damaged lines/objects skipped (on_damage="skip")
    first_damage: Damage | None = None
    damage: Damage | None = None     #: the damage that stopped reading (on_damage="stop")
    non_can_objects: int = 0         #: BLF objects that are not CAN frames (markers, other buses)
    slow_path_lines: int = 0         #: candump lines parsed one by one (CAN FD, remote, odd spacing)

    def as_dict(self) -> dict:
        out = {k: v for k, v in self.__dict__.items() if not isinstance(v, Damage)}
        for key in ("first_damage", "damage"):
            d = getattr(self, key)
            out[key] = None if d is None else {"position": d.position, "byte": d.byte,
                                               "line": d.line, "frame": d.frame, "reason": d.reason}
        return out
