"""Vectorized reader for Vector BLF (binary logging format) captures.

Layout (as python-can's ``BLFReader`` reads it, after Toby Lorenz' vector_blf)::

    file header "LOGG" (144 bytes: sizes, object count, start/stop time as SYSTEMTIME)
    LOBJ LOG_CONTAINER { zlib-compressed (or stored) stream of objects, ~128 KiB each }
    ...
    inner objects: LOBJ header (16) + v1/v2 header (16/24: flags, timestamp) + body
        CAN_MESSAGE / CAN_MESSAGE2: channel u16, flags u8, dlc u8, id u32, data 8
        CAN_FD_MESSAGE, CAN_FD_MESSAGE_64, CAN_ERROR_EXT; anything else is skipped and counted

Objects may straddle containers. How it is fast: containers are inflated into a ~1 MB buffer,
and the buffer is walked in *runs* of equal objects (same type and size, one after the other,
the usual case: thousands of CAN_MESSAGEs in a row) — each run is one numpy structured view, so
a Python step happens per run, not per frame. Timestamps are python-can's: raw/10^9 (or /10^5)
plus the start time, the same correctly rounded float64.

Damage (bad signature, a container that does not inflate, a file cut short) stops the reader
(``on_damage="stop"``, the default) with the byte offset of the damaged container or object;
everything before it is yielded. With ``on_damage="skip"`` the reader goes on after it, as
``candump`` logs do: a container that does not inflate is skipped whole (its outer header still
says where the next one starts); a damaged outer header is passed by scanning for the next
plausible container header; inside the inflated stream a damaged object is passed by scanning
for the next plausible object header. After a skipped container the next one may begin inside
an object that straddled them, so its stream is read from its first plausible object header.
A *plausible* header is the ``LOBJ`` signature with a header size, version, object size and
type a BLF writer produces (a frame's payload spelling ``LOBJ`` is not enough). Each skipped
region counts in :attr:`ReadStats.damaged` (the first in ``first_damage``); frames lost with
it are lost, everything else is read. A file cut short ends the reading either way.
"""
from __future__ import annotations

import zlib
from pathlib import Path
from typing import Iterator

import numpy as np
from can.io.blf import (CAN_ERROR_EXT, CAN_FD_MESSAGE, CAN_FD_MESSAGE_64, CAN_MESSAGE, CAN_MESSAGE2,
                        FILE_HEADER_STRUCT, LOG_CONTAINER, LOG_CONTAINER_STRUCT, NO_COMPRESSION,
                        OBJ_HEADER_BASE_STRUCT, ZLIB_DEFLATE, systemtime_to_timestamp)
from can.util import dlc2len

from .candump import open_binary
from .frames import BRS, ERROR, ESI, EXTENDED, FD, REMOTE, TX, CaptureError, Damage, FrameChunk, ReadStats

DEFAULT_CHUNK_BYTES = 1 << 20
_SIG = np.frombuffer(b"LOBJ", "<u4")[0]
_DLC2LEN = np.array([dlc2len(i) for i in range(16)], np.uint8)
#: the largest outer object (log container) the reader believes, rather than reading a damaged
#: size's gigabytes into memory (python-can writes ~128 KiB containers)
_MAX_CONTAINER = 1 << 26
#: the largest inner object it believes (a CAN FD frame with extended data is < 200 bytes)
_MAX_OBJECT = 1 << 16
_BASE = OBJ_HEADER_BASE_STRUCT.size


def plausible_container(raw, p: int) -> bool:
    """Whether a log container's header (as python-can and Vector write it) starts at ``p``."""
    if p + _BASE > len(raw):
        return False
    sig, hsize, hver, osize, otype = OBJ_HEADER_BASE_STRUCT.unpack_from(raw, p)
    return (sig == b"LOBJ" and hsize == _BASE and hver == 1 and otype == LOG_CONTAINER
            and _BASE + LOG_CONTAINER_STRUCT.size <= osize <= _MAX_CONTAINER)


def plausible_object(raw, p: int) -> bool:
    """Whether an inner object's header (v1: 32 bytes, v2: 40) starts at ``p``."""
    if p + _BASE > len(raw):
        return False
    sig, hsize, hver, osize, otype = OBJ_HEADER_BASE_STRUCT.unpack_from(raw, p)
    return (sig == b"LOBJ" and (hver, hsize) in ((1, 32), (2, 40)) and hsize <= osize <= _MAX_OBJECT
            and 0 < otype < 256 and otype != LOG_CONTAINER)


def next_plausible(raw, start: int, test) -> int:
    """Offset of the first header at or after ``start`` that ``test`` accepts, or -1."""
    p = raw.find(b"LOBJ", start)
    while p >= 0 and not test(raw, p):
        p = raw.find(b"LOBJ", p + 1)
    return p


class _PushbackFile:
    """A binary stream that takes back bytes read ahead (a resync reads past a header)."""

    def __init__(self, fh) -> None:
        self.fh = fh
        self.back = b""

    def read(self, n: int) -> bytes:
        if not self.back:
            return self.fh.read(n)
        head, self.back = self.back[:n], self.back[n:]
        if len(head) < n:
            head += self.fh.read(n - len(head))
        return head

    def unread(self, data: bytes) -> None:
        self.back = data + self.back


class BlfReader:
    """Stream a BLF file as :class:`FrameChunk` s (about ``chunk_bytes`` of inflated objects each)."""

    def __init__(self, path: str | Path, chunk_bytes: int = DEFAULT_CHUNK_BYTES,
                 on_damage: str = "stop") -> None:
        self.path = Path(path)
        if on_damage not in ("stop", "skip"):
            raise CaptureError(f"on_damage must be 'stop' or 'skip', not {on_damage!r}")
        self.chunk_bytes = max(int(chunk_bytes), 4096)
        self.on_damage = on_damage
        self.stats = ReadStats()
        self.start_timestamp = 0.0

    def _damage(self, byte: int, reason: str) -> None:
        self.stats.damage = Damage(str(self.path), byte, reason)

    def _skipped(self, byte: int, reason: str) -> None:
        """``on_damage="skip"``: count a damaged region passed over (the first one named)."""
        self.stats.damaged += 1
        if self.stats.first_damage is None:
            self.stats.first_damage = Damage(str(self.path), byte, reason)

    def _resync(self, fh: _PushbackFile, ahead: bytes, pos: int) -> int | None:
        """Scan from the bytes ``ahead`` (read at file offset ``pos``) for the next plausible
        log container; leave the stream at it and return its offset (None: none before EOF)."""
        buf = ahead
        origin = pos
        while True:
            p = next_plausible(buf, 0, plausible_container)
            if p >= 0:
                fh.unread(buf[p:])
                return origin + p
            more = fh.read(1 << 16)
            if not more:
                return None
            keep = buf[-(_BASE - 1):]       # a header may straddle the reads
            origin += len(buf) - len(keep)
            buf = keep + more

    def __iter__(self) -> Iterator[FrameChunk]:
        stats = self.stats
        skip = self.on_damage == "skip"
        with open_binary(self.path) as raw_fh:
            fh = _PushbackFile(raw_fh)
            head = fh.read(FILE_HEADER_STRUCT.size)
            if len(head) < FILE_HEADER_STRUCT.size or head[:4] != b"LOGG":
                raise CaptureError(f"{self.path}: not a BLF file (no 'LOGG' header)")
            header = FILE_HEADER_STRUCT.unpack(head)
            self.start_timestamp = systemtime_to_timestamp(header[14:22])
            fh.read(max(header[1] - FILE_HEADER_STRUCT.size, 0))
            pos = header[1]
            pending = bytearray()
            pending_origin = pos          # file offset of the container the pending bytes began in
            resync_stream = False         # skip: the next container may begin inside an object
            while True:
                base = fh.read(OBJ_HEADER_BASE_STRUCT.size)
                if not base:
                    break
                if len(base) < OBJ_HEADER_BASE_STRUCT.size:
                    self._damage(pos, "the file ends inside an object header (truncated capture?)")
                    break
                sig, _, _, obj_size, obj_type = OBJ_HEADER_BASE_STRUCT.unpack(base)
                if sig != b"LOBJ" or not OBJ_HEADER_BASE_STRUCT.size <= obj_size <= _MAX_CONTAINER:
                    reason = f"no object here (signature {sig!r}, size {obj_size}): corrupted file"
                    if not skip:
                        self._damage(pos, reason)
                        break
                    yield from self._skip_region(pos, reason, pending, pending_origin)
                    resync_stream = True
                    found = self._resync(fh, base, pos)
                    if found is None:
                        break
                    pos = found
                    continue
                body = fh.read(obj_size - OBJ_HEADER_BASE_STRUCT.size)
                if len(body) < obj_size - OBJ_HEADER_BASE_STRUCT.size:
                    self._damage(pos, f"the file ends inside a {obj_size}-byte object (truncated capture?)")
                    break
                fh.read(obj_size % 4)
                stats.bytes_read += obj_size + obj_size % 4
                here = pos
                pos += obj_size + obj_size % 4
                if obj_type != LOG_CONTAINER:
                    stats.non_can_objects += 1
                    continue
                method, size = LOG_CONTAINER_STRUCT.unpack_from(body)
                payload = body[LOG_CONTAINER_STRUCT.size:]
                if method == ZLIB_DEFLATE:
                    try:
                        data = zlib.decompress(payload)
                    except zlib.error as exc:
                        reason = f"log container does not inflate ({exc}): corrupted file"
                        if not skip:
                            self._damage(here, reason)
                            break
                        yield from self._skip_region(here, reason, pending, pending_origin)
                        resync_stream = True
                        continue
                elif method == NO_COMPRESSION:
                    data = bytes(payload)
                else:
                    stats.non_can_objects += 1
                    continue
                if resync_stream:
                    first = next_plausible(data, 0, plausible_object)
                    if first < 0:
                        continue            # no object starts in this container: wait for one
                    data = data[first:]
                    resync_stream = False
                if not pending:
                    pending_origin = here
                pending += data
                if len(pending) >= self.chunk_bytes:
                    chunk, used, problem = parse_objects(pending, self.start_timestamp, stats,
                                                         on_problem=self._inner(pending_origin))
                    if len(chunk):
                        stats.frames += len(chunk)
                        yield chunk
                    if problem is not None:
                        self._damage(pending_origin, f"{problem} (inside the log container at this byte)")
                        return
                    del pending[:used]
                    pending_origin = here
            chunk, used, problem = parse_objects(pending, self.start_timestamp, stats, final=True,
                                                 on_problem=self._inner(pending_origin))
            if len(chunk):
                stats.frames += len(chunk)
                yield chunk
            if problem is not None and stats.damage is None:
                self._damage(pending_origin, f"{problem} (inside the log container at this byte)")
            elif used < len(pending) and stats.damage is None and any(pending[used:]):
                self._damage(pending_origin, f"the last {len(pending) - used} bytes are an incomplete "
                                             "object (truncated capture?)")

    def _inner(self, origin: int):
        """``on_damage="skip"``: what :func:`parse_objects` calls on a damaged inner object."""
        if self.on_damage != "skip":
            return None
        return lambda problem: self._skipped(origin, f"{problem} (inside the log container at this byte)")

    def _skip_region(self, byte: int, reason: str, pending: bytearray,
                     origin: int) -> Iterator[FrameChunk]:
        """``on_damage="skip"``: count the damaged region at ``byte`` and yield the complete
        objects still pending before it; an object cut off by the damage is part of the damaged
        region. Empties ``pending``."""
        self._skipped(byte, reason)
        chunk, _, _ = parse_objects(pending, self.start_timestamp, self.stats,
                                    on_problem=self._inner(origin))
        pending.clear()
        if len(chunk):
            self.stats.frames += len(chunk)
            yield chunk


def parse_objects(buf: bytearray, start_ts: float, stats: ReadStats, final: bool = False,
                  on_problem=None) -> tuple[FrameChunk, int, str | None]:
    """Frames of the complete objects at the start of ``buf``; returns (frames, bytes used,
    what is wrong if an object is damaged). With ``on_problem`` (skip mode) a damaged object is
    reported to it and passed: reading goes on at the next plausible object header."""
    raw = bytes(buf)
    b = np.frombuffer(raw, np.uint8)
    n = len(raw)
    pieces: list[FrameChunk] = []
    pos = 0
    problem = None
    while pos + OBJ_HEADER_BASE_STRUCT.size <= n:
        # objects are padded: the next signature starts within 8 bytes (python-can: within 4)
        p = raw.find(b"LOBJ", pos, pos + 12)
        if p < 0:
            if not any(raw[pos:pos + 8]) and n - pos <= 8:
                pos = n
                break
            problem = f"no object signature at stream offset {pos}"
        elif p + OBJ_HEADER_BASE_STRUCT.size > n:
            break
        else:
            _, hsize, hver, osize, otype = OBJ_HEADER_BASE_STRUCT.unpack_from(raw, p)
            if osize < 32 or hsize < 16 or hsize > osize:
                problem = f"object at stream offset {p} has an impossible size ({osize}, header {hsize})"
        if problem is not None:
            if on_problem is None:
                break
            on_problem(problem)
            problem = None
            nxt = next_plausible(raw, pos + 1, plausible_object)
            if nxt < 0:                     # keep a tail a header may begin in, unless at the end
                pos = n if final else max(pos, n - (_BASE - 1))
                break
            pos = nxt
            continue
        if p + osize > n:
            break                           # continues in the next container
        # stride to the next object: its size plus padding
        nxt = raw.find(b"LOBJ", p + osize, p + osize + 12)
        stride = osize + (nxt - p - osize if nxt >= 0 else 0)
        m = _run_length(b, p, stride, hsize, hver, osize, otype)
        while m > 1 and p + (m - 1) * stride + osize > n:
            m -= 1
        pieces.append(_decode_run(b, p, stride, m, hsize, osize, otype, start_ts, stats))
        pos = p + (m - 1) * stride + osize
    return FrameChunk.concat(pieces) if pieces else FrameChunk.empty(), pos, problem


def _run_length(b: np.ndarray, p: int, stride: int, hsize: int, hver: int, osize: int, otype: int) -> int:
    """How many objects from ``p`` on are the same kind, one every ``stride`` bytes."""
    m_max = (len(b) - p - 16) // stride + 1
    if m_max <= 1 or stride < 16:
        return 1
    view = np.ndarray((m_max,), dtype=np.dtype([("sig", "<u4"), ("hsize", "<u2"), ("hver", "<u2"),
                                                 ("osize", "<u4"), ("otype", "<u4")]),
                      buffer=b, offset=p, strides=(stride,))
    same = ((view["sig"] == _SIG) & (view["hsize"] == hsize) & (view["hver"] == hver)
            & (view["osize"] == osize) & (view["otype"] == otype))
    if same.all():
        return m_max
    return int(np.argmin(same))


def _field(b: np.ndarray, p: int, stride: int, m: int, offset: int, dtype: str, count: int = 1) -> np.ndarray:
    dt = np.dtype(dtype)
    shape = (m,) if count == 1 else (m, count)
    strides = (stride,) if count == 1 else (stride, dt.itemsize)
    return np.ndarray(shape, dtype=dt, buffer=b, offset=p + offset, strides=strides).copy()


def _decode_run(b, p, stride, m, hsize, osize, otype, start_ts, stats) -> FrameChunk:
    h = hsize   # body offset from the object start
    if otype not in (CAN_MESSAGE, CAN_MESSAGE2, CAN_FD_MESSAGE, CAN_FD_MESSAGE_64, CAN_ERROR_EXT):
        stats.non_can_objects += m
        return FrameChunk.empty()
    tflags = _field(b, p, stride, m, 16, "<u4")
    raw_ts = _field(b, p, stride, m, 24, "<u8")
    ts = np.where(tflags == 1, raw_ts / 1e5, raw_ts / 1e9) + start_ts
    if otype in (CAN_MESSAGE, CAN_MESSAGE2):
        channel = _field(b, p, stride, m, h, "<u2")
        mflags = _field(b, p, stride, m, h + 2, "u1")
        dlc = _field(b, p, stride, m, h + 3, "u1")
        ident = _field(b, p, stride, m, h + 4, "<u4")
        data = _field(b, p, stride, m, h + 8, "u1", 8)
        flags = (np.where(ident & 0x80000000, EXTENDED, 0) | np.where(mflags & 0x80, REMOTE, 0)
                 | np.where(mflags & 0x1, TX, 0)).astype(np.uint8)
        length = np.minimum(dlc, 8)
        data = np.where(np.arange(8)[None, :] < length[:, None], data, 0).astype(np.uint8)
    elif otype == CAN_ERROR_EXT:
        channel = _field(b, p, stride, m, h, "<u2")
        ident = _field(b, p, stride, m, h + 16, "<u4")
        length = np.zeros(m, np.uint8)
        data = np.zeros((m, 8), np.uint8)
        flags = (ERROR | np.where(ident & 0x80000000, EXTENDED, 0)).astype(np.uint8)
    elif otype == CAN_FD_MESSAGE:
        channel = _field(b, p, stride, m, h, "<u2")
        mflags = _field(b, p, stride, m, h + 2, "u1")
        dlc = _field(b, p, stride, m, h + 3, "u1")
        ident = _field(b, p, stride, m, h + 4, "<u4")
        fd_flags = _field(b, p, stride, m, h + 13, "u1")
        valid = _field(b, p, stride, m, h + 14, "u1")
        data = _field(b, p, stride, m, h + 20, "u1", 64)
        length = np.minimum(valid, 64).astype(np.uint8)
        data = np.where(np.arange(64)[None, :] < length[:, None], data, 0).astype(np.uint8)
        flags = (np.where(ident & 0x80000000, EXTENDED, 0) | np.where(mflags & 0x80, REMOTE, 0)
                 | np.where(mflags & 0x1, TX, 0) | np.where(fd_flags & 0x1, FD, 0)
                 | np.where(fd_flags & 0x2, BRS, 0) | np.where(fd_flags & 0x4, ESI, 0)).astype(np.uint8)
    else:  # CAN_FD_MESSAGE_64
        channel = _field(b, p, stride, m, h, "u1").astype(np.uint16)
        valid = _field(b, p, stride, m, h + 2, "u1")
        ident = _field(b, p, stride, m, h + 4, "<u4")
        fd_flags = _field(b, p, stride, m, h + 12, "<u4")
        direction = _field(b, p, stride, m, h + 34, "u1")
        ext_off = _field(b, p, stride, m, h + 36, "<u4")
        avail = np.where(ext_off > 0, ext_off, osize).astype(np.int64) - hsize - 40
        length = np.clip(np.minimum(valid, avail), 0, 64).astype(np.uint8)
        room = max(0, min(64, osize - hsize - 40))
        data = np.zeros((m, 64), np.uint8)
        if room:
            data[:, :room] = _field(b, p, stride, m, h + 40, "u1", room)
        data = np.where(np.arange(64)[None, :] < length[:, None], data, 0).astype(np.uint8)
        length = valid.astype(np.uint8)      # python-can pads missing bytes with zeros
        flags = (np.where(ident & 0x80000000, EXTENDED, 0) | np.where(fd_flags & 0x0010, REMOTE, 0)
                 | np.where(direction, TX, 0) | np.where(fd_flags & 0x1000, FD, 0)
                 | np.where(fd_flags & 0x2000, BRS, 0) | np.where(fd_flags & 0x4000, ESI, 0)).astype(np.uint8)
    chans = np.unique(channel)
    names = [str(int(c) - 1) for c in chans]
    return FrameChunk(ts, ident & 0x1FFFFFFF, flags, length, data,
                      np.searchsorted(chans, channel).astype(np.int16), names)
