"""Pick the reader for a capture file by its suffix.

=================  =====================================================================
``.log``           candump / python-can canutils log: vectorized (:mod:`captures.candump`)
``.blf``           Vector BLF: vectorized (:mod:`captures.blf`)
``.asc`` ``.trc``  via python-can's readers, batched into chunks (a Python call per frame)
``.csv`` ``.db``
``.mf4``           via python-can's ``MF4Reader`` (needs the optional ``asammdf`` package)
``*.gz``           any of the text formats, gzip-compressed
=================  =====================================================================

Every reader is an iterable of :class:`FrameChunk` with a ``stats`` (:class:`ReadStats`)
attribute that says what was skipped and where the capture is damaged.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import can
import numpy as np

from .blf import BlfReader
from .candump import CandumpReader
from .frames import ERROR, EXTENDED, FD, REMOTE, TX, CaptureError, Damage, FrameChunk, ReadStats

from .formats import SUFFIXES, VECTORIZED, VIA_PYTHON_CAN  # noqa: F401 (re-exported)


def capture_format(path: str | Path) -> str:
    """``"candump"``, ``"blf"``, ``"asc"``, ... from the suffix (``.gz`` looked through)."""
    path = Path(path)
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    suffix = suffixes[-1] if suffixes else ""
    if suffix in VECTORIZED:
        return VECTORIZED[suffix]
    if suffix in VIA_PYTHON_CAN:
        return VIA_PYTHON_CAN[suffix]
    raise CaptureError(f"{path}: unknown capture format {suffix or '(no suffix)'!r}; "
                       f"give one of {', '.join(SUFFIXES)} (optionally .gz)")


def open_capture(path: str | Path, chunk_bytes: int | None = None, on_damage: str = "stop"):
    """The reader for ``path`` (an iterable of :class:`FrameChunk` with ``.stats``)."""
    path = Path(path)
    if not path.exists():
        raise CaptureError(f"{path} does not exist")
    if path.is_dir():
        raise CaptureError(f"{path} is a directory, not a capture file")
    fmt = capture_format(path)
    kwargs = {"on_damage": on_damage}
    if chunk_bytes:
        kwargs["chunk_bytes"] = chunk_bytes
    if fmt == "candump":
        return CandumpReader(path, **kwargs)
    if fmt == "blf":
        if path.suffix.lower() == ".gz":
            raise CaptureError(f"{path}: BLF is compressed already; give the .blf file")
        return BlfReader(path, **kwargs)
    return PythonCanReader(path, fmt, on_damage=on_damage)


class PythonCanReader:
    """Any format python-can reads, one message at a time, batched into chunks."""

    batch = 50_000

    def __init__(self, path: Path, fmt: str, on_damage: str = "stop", **_) -> None:
        self.path = path
        self.format = fmt
        self.on_damage = on_damage
        self.stats = ReadStats()

    def _open(self):
        try:
            return can.LogReader(str(self.path))
        except ImportError as exc:
            raise CaptureError(f"{self.path}: reading {self.format} files needs an optional package "
                               f"python-can could not import ({exc}); e.g. pip install 'hydrostand[mf4]' (asammdf)") from None
        except (OSError, ValueError) as exc:
            raise CaptureError(f"{self.path}: cannot open as {self.format}: {exc}") from None

    def __iter__(self) -> Iterator[FrameChunk]:
        reader = self._open()
        rows: list[can.Message] = []
        count = 0
        try:
            it = iter(reader)
            while True:
                try:
                    msg = next(it)
                except StopIteration:
                    break
                except Exception as exc:   # python-can readers raise many kinds on bad input
                    self.stats.damage = Damage(str(self.path), None, f"python-can's {self.format} "
                                               f"reader failed: {type(exc).__name__}: {exc}",
                                               frame=count)
                    break
                rows.append(msg)
                count += 1
                if len(rows) >= self.batch:
                    chunk = messages_to_chunk(rows)
                    self.stats.frames += len(chunk)
                    yield chunk
                    rows = []
        finally:
            try:
                reader.stop()
            except Exception:
                pass
        if rows:
            chunk = messages_to_chunk(rows)
            self.stats.frames += len(chunk)
            yield chunk


def messages_to_chunk(messages: list[can.Message]) -> FrameChunk:
    n = len(messages)
    width = 64 if any(len(m.data) > 8 for m in messages) else 8
    data = np.zeros((n, width), np.uint8)
    names: list[str] = []
    chan = np.zeros(n, np.int16)
    flags = np.zeros(n, np.uint8)
    for i, m in enumerate(messages):
        if m.data:
            data[i, :len(m.data)] = np.frombuffer(bytes(m.data), np.uint8)
        name = "" if m.channel is None else str(m.channel)
        if name not in names:
            names.append(name)
        chan[i] = names.index(name)
        flags[i] = (EXTENDED * m.is_extended_id | REMOTE * m.is_remote_frame | ERROR * m.is_error_frame
                    | FD * m.is_fd | TX * (not m.is_rx))
    return FrameChunk(np.array([m.timestamp for m in messages], np.float64),
                      np.array([m.arbitration_id for m in messages], np.uint32), flags,
                      np.array([m.dlc if m.is_remote_frame else len(m.data) for m in messages], np.uint8),
                      data, chan, names)
