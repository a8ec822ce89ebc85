"""Fast capture writers (columns in, file out): candump logs and Vector BLF.

They write what python-can's ``CanutilsLogWriter`` and ``BLFWriter`` write (the tests read the
files back with python-can's readers), but a whole :class:`FrameChunk` at a time, so that
benchmarks can make multi-GB captures in seconds. Classic CAN only (no FD, no error frames).
"""
from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np
from can.io.blf import (CAN_MESSAGE, FILE_HEADER_SIZE, FILE_HEADER_STRUCT, LOG_CONTAINER,
                        LOG_CONTAINER_STRUCT, OBJ_HEADER_BASE_STRUCT, TIME_ONE_NANS,
                        timestamp_to_systemtime)

from .frames import ERROR, EXTENDED, FD, REMOTE, TX, FrameChunk

_HEXCHARS = np.frombuffer(b"0123456789ABCDEF", np.uint8)
_BLOCK = 200_000


def _digits(values: np.ndarray, width: int) -> np.ndarray:
    """Decimal digits (ASCII) of non-negative ints, zero-padded to ``width``."""
    powers = 10 ** np.arange(width - 1, -1, -1, dtype=np.int64)
    return ((values[:, None] // powers) % 10 + 48).astype(np.uint8)


def candump_lines(chunk: FrameChunk, direction: bool = True) -> bytes:
    """``(ssssssssss.uuuuuu) chan ID#DATA[ R| T]\\n`` for every frame (µs-rounded timestamps)."""
    n = len(chunk)
    if n == 0:
        return b""
    if (chunk.flags & (FD | ERROR)).any() or (chunk.dlc > 8).any():
        raise ValueError("the fast candump writer handles classic CAN data/remote frames only")
    us = np.round(chunk.ts * 1e6).astype(np.int64)
    sec, usec = np.divmod(us, 1_000_000)
    sec_width = max(10, len(str(int(sec.max()))))
    names = [c.encode() for c in (chunk.channels or ["can0"])]
    cw = max(len(c) for c in names)
    name_mat = np.zeros((len(names), cw), np.uint8)
    for i, c in enumerate(names):
        name_mat[i, :len(c)] = np.frombuffer(c, np.uint8)
    name_len = np.array([len(c) for c in names])[chunk.channel]

    def const(text: bytes):
        return np.tile(np.frombuffer(text, np.uint8), (n, 1)), np.ones((n, len(text)), bool)

    ext = (chunk.flags & EXTENDED) != 0
    ident = chunk.can_id.astype(np.int64)
    id_chars = _HEXCHARS[(ident[:, None] >> (4 * np.arange(7, -1, -1))) & 0xF]
    id_mask = np.where(ext[:, None], True, np.arange(8)[None, :] >= 5)
    remote = (chunk.flags & REMOTE) != 0
    nib = np.empty((n, 16), np.int64)
    nib[:, 0::2] = chunk.data[:, :8] >> 4
    nib[:, 1::2] = chunk.data[:, :8] & 0xF
    data_chars = _HEXCHARS[nib]
    data_mask = np.arange(16)[None, :] < 2 * chunk.dlc[:, None].astype(np.int64)
    data_chars[remote, 0] = ord("R")
    data_mask[remote] = np.arange(16) < 1
    tx = (chunk.flags & TX) != 0
    flag_chars = np.stack([np.full(n, 32, np.uint8), np.where(tx, ord("T"), ord("R")).astype(np.uint8)], 1)
    segments = [const(b"("), (_digits(sec, sec_width), np.ones((n, sec_width), bool)), const(b"."),
                (_digits(usec, 6), np.ones((n, 6), bool)), const(b") "),
                (name_mat[chunk.channel], np.arange(cw)[None, :] < name_len[:, None]), const(b" "),
                (id_chars, id_mask), const(b"#"), (data_chars, data_mask),
                (flag_chars, np.full((n, 2), direction)), const(b"\n")]
    mat = np.hstack([s[0] for s in segments])
    mask = np.hstack([s[1] for s in segments])
    return mat[mask].tobytes()


def write_candump(path: str | Path, chunks, direction: bool = True) -> int:
    """Write chunks to a candump log; returns the number of frames."""
    frames = 0
    with open(path, "wb") as fh:
        for chunk in chunks:
            for i in range(0, len(chunk), _BLOCK):
                part = chunk.take(slice(i, i + _BLOCK))
                fh.write(candump_lines(part, direction))
                frames += len(part)
    return frames


_CAN_OBJ = np.dtype([("sig", "S4"), ("header_size", "<u2"), ("header_version", "<u2"),
                     ("obj_size", "<u4"), ("obj_type", "<u4"), ("flags", "<u4"),
                     ("client", "<u2"), ("version", "<u2"), ("timestamp", "<u8"),
                     ("channel", "<u2"), ("msg_flags", "u1"), ("dlc", "u1"), ("id", "<u4"),
                     ("data", "u1", (8,))])
assert _CAN_OBJ.itemsize == 48


class FastBlfWriter:
    """BLF as python-can's ``BLFWriter`` writes it (CAN_MESSAGE objects, 128 KiB zlib
    containers, nanosecond timestamps from a start rounded down to the millisecond)."""

    max_container_size = 128 * 1024

    def __init__(self, path: str | Path, compression_level: int = -1) -> None:
        self.fh = open(path, "wb")
        self.level = compression_level
        self.buffer = bytearray()
        self.start: float | None = None
        self.stop_ts: float | None = None
        self.objects = 0
        self.uncompressed = FILE_HEADER_SIZE
        self._header(0)

    def _header(self, filesize: int) -> None:
        head = [b"LOGG", FILE_HEADER_SIZE, 5, 0, 0, 0, 2, 6, 8, 1, filesize, self.uncompressed,
                self.objects, 0, *timestamp_to_systemtime(self.start),
                *timestamp_to_systemtime(self.stop_ts)]
        self.fh.write(FILE_HEADER_STRUCT.pack(*head))
        self.fh.write(b"\x00" * (FILE_HEADER_SIZE - FILE_HEADER_STRUCT.size))

    def write(self, chunk: FrameChunk) -> None:
        n = len(chunk)
        if n == 0:
            return
        if (chunk.flags & (FD | ERROR)).any():
            raise ValueError("the fast BLF writer handles classic CAN data/remote frames only")
        if self.start is None:
            self.start = int(float(chunk.ts[0]) * 1000) / 1000
        self.stop_ts = float(chunk.ts[-1])
        obj = np.zeros(n, _CAN_OBJ)
        obj["sig"] = b"LOBJ"
        obj["header_size"] = 32
        obj["header_version"] = 1
        obj["obj_size"] = 48
        obj["obj_type"] = CAN_MESSAGE
        obj["flags"] = TIME_ONE_NANS
        obj["timestamp"] = np.maximum(((chunk.ts - self.start) * 1e9).astype(np.int64), 0)
        obj["channel"] = chunk.channel.astype(np.uint16) + 1
        obj["msg_flags"] = np.where(chunk.flags & REMOTE, 0x80, 0) | np.where(chunk.flags & TX, 0x1, 0)
        obj["dlc"] = chunk.dlc
        obj["id"] = chunk.can_id | np.where(chunk.flags & EXTENDED, 0x80000000, 0).astype(np.uint32)
        obj["data"] = np.where(np.arange(8)[None, :] < chunk.dlc[:, None], chunk.data[:, :8], 0)
        self.buffer += obj.tobytes()
        self.objects += n
        while len(self.buffer) >= self.max_container_size:
            self._container(bytes(self.buffer[:self.max_container_size]))
            del self.buffer[:self.max_container_size]

    def _container(self, raw: bytes) -> None:
        data = zlib.compress(raw, self.level)
        obj_size = OBJ_HEADER_BASE_STRUCT.size + LOG_CONTAINER_STRUCT.size + len(data)
        self.fh.write(OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", OBJ_HEADER_BASE_STRUCT.size, 1, obj_size,
                                                  LOG_CONTAINER))
        self.fh.write(LOG_CONTAINER_STRUCT.pack(2, len(raw)))
        self.fh.write(data)
        self.fh.write(b"\x00" * (obj_size % 4))
        self.uncompressed += OBJ_HEADER_BASE_STRUCT.size + LOG_CONTAINER_STRUCT.size + len(raw)

    def close(self) -> None:
        if self.buffer:
            self._container(bytes(self.buffer))
            self.buffer.clear()
        size = self.fh.tell()
        self.fh.seek(0)
        self._header(size)
        self.fh.close()

    def __enter__(self) -> "FastBlfWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_blf(path: str | Path, chunks) -> int:
    frames = 0
    with FastBlfWriter(path) as w:
        for chunk in chunks:
            w.write(chunk)
            frames += len(chunk)
    return frames


def to_messages(chunk: FrameChunk):
    """python-can messages of a chunk (to write any format with python-can's writers)."""
    import can
    for i in range(len(chunk)):
        fl = int(chunk.flags[i])
        yield can.Message(timestamp=float(chunk.ts[i]), arbitration_id=int(chunk.can_id[i]),
                          is_extended_id=bool(fl & EXTENDED), is_remote_frame=bool(fl & REMOTE),
                          is_error_frame=bool(fl & ERROR), is_fd=bool(fl & FD), is_rx=not fl & TX,
                          dlc=int(chunk.dlc[i]), data=None if fl & REMOTE else chunk.payload(i),
                          channel=chunk.channels[chunk.channel[i]] if chunk.channels else None)
