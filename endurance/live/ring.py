r"""The live rows of a running session in a file that both processes map: the session writes, the
page's server reads, and nothing else passes between them (docs/decisions.md, the live page in a
process of its own).

One file per session (mode 600; where: :mod:`endurance.live.feed`), made under a temporary
name and renamed into place::

    header  whole pages: magic, row width, capacity, the hello's length; at 64 the count of
            rows put, at 72 the closed flag; at 128 the session's hello (JSON: channels,
            period, sample rate, pid)
    seqs    capacity × uint64: 1 + the sequence number of the row in each slot (0: being written)
    rows    capacity × width float64

The writer (the control loop's thread, 50 rows a second) stores a row in slot ``count %
capacity`` between two stores of that slot's sequence (0, then ``count + 1``) and then raises the
count: a few stores into memory, never a wait, never a system call, and nothing a reader does can
change that. A reader copies the slots it wants and keeps the rows whose sequence was the
expected one both before and after the copy (a slot the writer reused meanwhile is left out).
That relies on stores and loads each staying in program order, as x86-64 (TSO) keeps them; a
reader that fell further behind than the ring holds gets the newest ``capacity - MARGIN`` rows.
"""
from __future__ import annotations

import json
import mmap
import os
import stat
import struct
from pathlib import Path
from typing import Sequence

import numpy as np

MAGIC = b"HSRING01"
PAGE_BYTES = 4096
_HELLO_AT = 128
_COUNT_AT = 64
_CLOSED_AT = 72
#: rows a reader leaves to the writer while it copies (at 50 rows/s, seconds of a copy)
MARGIN = 64


def _layout(width: int, capacity: int, hello_bytes: int) -> tuple[int, int, int]:
    """Where the sequence numbers and the rows begin, and the file's size."""
    seqs_at = -(-(_HELLO_AT + hello_bytes) // PAGE_BYTES) * PAGE_BYTES
    rows_at = seqs_at + 8 * capacity
    return seqs_at, rows_at, rows_at + 8 * capacity * width


class RingFile:
    """One session's ring (module docstring): :meth:`create` to write, :meth:`open` to read."""

    def __init__(self, path: Path, mm: mmap.mmap, width: int, capacity: int, hello: dict, hello_bytes: int,
                 writable: bool, inode: int) -> None:
        self.path = path
        #: the file's inode: a reader sees a new session's ring by another one at ``path``
        self.inode = inode
        self.width = width
        self.capacity = capacity
        self.hello = hello
        self._mm = mm
        seqs_at, rows_at, _ = _layout(width, capacity, hello_bytes)
        self._count = np.frombuffer(mm, np.uint64, 1, _COUNT_AT)
        self._closed = np.frombuffer(mm, np.uint64, 1, _CLOSED_AT)
        self._seqs = np.frombuffer(mm, np.uint64, capacity, seqs_at)
        self._rows = np.frombuffer(mm, np.float64, capacity * width, rows_at).reshape(capacity, width)
        self._writable = writable
        self._n = int(self._count[0])

    @classmethod
    def create(cls, path: str | Path, width: int, capacity: int, hello: dict) -> "RingFile":
        """A new ring at ``path`` (written beside it and renamed into place), mode 600."""
        path = Path(path)
        if capacity <= MARGIN:
            raise ValueError(f"capacity {capacity}: give more than {MARGIN} rows")
        text = json.dumps(hello, separators=(",", ":")).encode()
        size = _layout(width, capacity, len(text))[2]
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o600)
        try:
            os.pwrite(fd, bytes(size), 0)             # every page there now: no fault in the loop
            os.pwrite(fd, struct.pack("<8sIII", MAGIC, width, capacity, len(text)), 0)
            os.pwrite(fd, text, _HELLO_AT)
            mm = mmap.mmap(fd, size)
            inode = os.fstat(fd).st_ino
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        finally:
            os.close(fd)
        os.replace(tmp, path)
        return cls(path, mm, width, capacity, hello, len(text), writable=True, inode=inode)

    @classmethod
    def open(cls, path: str | Path) -> "RingFile":
        """The ring at ``path``, mapped read-only; OSError if it is not there, ValueError if it
        is not a ring."""
        path = Path(path)
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        try:
            info = os.fstat(fd)
            size = info.st_size
            if not stat.S_ISREG(info.st_mode) or size < PAGE_BYTES:
                raise ValueError(f"{path}: not a ring ({size} bytes)")
            mm = mmap.mmap(fd, size, access=mmap.ACCESS_READ)
        finally:
            os.close(fd)
        magic, width, capacity, n = struct.unpack_from("<8sIII", mm, 0)
        if magic != MAGIC or _layout(width, capacity, n)[2] != size:
            mm.close()
            raise ValueError(f"{path}: not a ring of this version")
        try:
            hello = json.loads(mm[_HELLO_AT:_HELLO_AT + n])
        except ValueError:
            mm.close()
            raise
        return cls(path, mm, width, capacity, hello, n, writable=False, inode=info.st_ino)

    # -- the writer's -------------------------------------------------------------------------------------
    def put(self, time_s: float, *parts: Sequence[float]) -> None:
        """One row: ``time_s`` and then ``parts`` one after the other (module docstring)."""
        n = self._n
        k = n % self.capacity
        self._seqs[k] = 0
        row = self._rows[k]
        row[0] = time_s
        at = 1
        for part in parts:
            row[at:at + len(part)] = part
            at += len(part)
        self._seqs[k] = n + 1
        self._n = n + 1
        self._count[0] = n + 1

    def close(self) -> None:
        """The writer: mark the ring closed and remove the file (if it is still this one); a
        reader: let go of the mapping."""
        if self._writable:
            self._closed[0] = 1
            try:
                if os.stat(self.path).st_ino == self.inode:
                    self.path.unlink()
            except OSError:
                pass
        self._release()

    def _release(self) -> None:
        for name in ("_count", "_closed", "_seqs", "_rows"):
            setattr(self, name, None)
        try:
            self._mm.close()
        except BufferError:                 # a caller still holds a view: the GC frees it
            pass

    # -- a reader's -----------------------------------------------------------------------------------
    @property
    def count(self) -> int:
        """Rows put so far (the next row's sequence number)."""
        return int(self._count[0])

    @property
    def closed(self) -> bool:
        return bool(self._closed[0])

    def since(self, seq: int) -> tuple[int, np.ndarray]:
        """``(count, rows)``: the rows from sequence number ``seq`` on (the newest ``capacity -
        MARGIN`` at most; any the writer reused while they were copied left out), as an array
        of ``width`` columns, and the count to ask from next time."""
        end = int(self._count[0])
        start = max(int(seq), end - (self.capacity - MARGIN), 0)
        if start >= end:
            return end, np.empty((0, self.width))
        want = np.arange(start, end, dtype=np.uint64)
        slots = (want % np.uint64(self.capacity)).astype(np.intp)
        before = self._seqs[slots]
        rows = self._rows[slots]
        after = self._seqs[slots]
        good = (before == want + 1) & (after == want + 1)
        return end, rows[good]
