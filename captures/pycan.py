"""Captures in any format python-can reads (``.asc``, ``.trc``, ``.csv``, ``.db``, ``.mf4``),
one message at a time through ``can.LogReader``, batched into :class:`FrameChunk` s.

python-can is imported when such a file is opened, not before: ``import can`` loads every
python-can log format, ``.mf4``'s asammdf (and pandas) among them, which a candump or BLF
capture does not need.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Iterator

import numpy as np

from .frames import BRS, ERROR, ESI, EXTENDED, FD, REMOTE, TX, CaptureError, Damage, FrameChunk, ReadStats

if TYPE_CHECKING:
    import can


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
            import can
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
                    | FD * m.is_fd | TX * (not m.is_rx)
                    | BRS * (m.is_fd and m.bitrate_switch) | ESI * (m.is_fd and m.error_state_indicator))
    return FrameChunk(np.array([m.timestamp for m in messages], np.float64),
                      np.array([m.arbitration_id for m in messages], np.uint32), flags,
                      np.array([m.dlc if m.is_remote_frame else len(m.data) for m in messages], np.uint8),
                      data, chan, names)
