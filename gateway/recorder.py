"""Writes a run directory (format: :mod:`gateway.runs`) while the loop runs.

Crash safety: rows are buffered in memory and handed, at least every ``flush_s`` = 0.5 s, to a
writer thread that appends them as one Arrow IPC record batch to ``signals.arrows`` and
``fsync``s it, so after a ``kill -9`` the run keeps every row up to the last flush (the batch
being written when the process died is dropped whole by :func:`gateway.runs.load_run`). The
control loop pays only for list appends and a buffer swap; conversion and disk I/O happen on
the writer thread, so a slow disk never delays a cycle. While the loop waits for the stand it
calls :meth:`RunRecorder.poll`, so rows never sit in memory longer than ``flush_s``.
On a clean close the stream is converted to ``signals.parquet`` and removed, and ``run.json``
gets the end status and reason.
"""
from __future__ import annotations

import datetime as _dt
import functools
import os
import platform
import sys
from importlib import metadata as _md
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.ipc
import pyarrow.parquet as pq

from core.durable import write_json

from .errors import DataError, StandError
from .rowbuffer import RowBuffer
from .runs import (CAPTURE_FILE, FORMAT, META_FILE,
                   SCHEMA, SIGNALS_FILE, STREAM_FILE, TRUTH_FILE, rig_schema)


@functools.lru_cache(maxsize=1)
def _installed_versions() -> tuple[tuple[str, str], ...]:
    out = {"python": platform.python_version()}
    for dist in ("hydrostand", "python-can", "canopen", "cantools", "numpy", "scipy", "pyarrow"):
        try:
            out[dist] = _md.version(dist)
        except _md.PackageNotFoundError:
            pass
    return tuple(out.items())


def versions() -> dict[str, str]:
    """Python's and the stack's versions, for run.json (read once per process: ~7 ms)."""
    return dict(_installed_versions())


@functools.lru_cache(maxsize=1)
def _warm_up_arrow() -> None:
    """Convert one row once per process before any run: pyarrow's first list conversion takes
    ~11 ms and holds the GIL, which stalled a real-time loop by 8 ms at its first flush."""
    pa.record_batch([pa.array([None], type=f.type) for f in SCHEMA], schema=SCHEMA)


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


def prepare_run_dir(out: str | Path) -> Path:
    """Create the run directory; refuse to overwrite an existing run."""
    out = Path(out)
    if (out / META_FILE).exists():
        raise StandError(f"{out} already holds a run; choose another --out (runs are never overwritten)")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StandError(f"cannot create run directory {out}: {exc}") from None
    return out


class RunRecorder:
    """Append one row per cycle; :meth:`close` finalises the run. ``channels``: a rig run's
    channel names (the signals then have each channel's columns, :func:`gateway.runs.rig_schema`);
    ``files``: run.json ``files`` (default: the one-channel signals and capture)."""

    def __init__(self, out: str | Path, meta: dict[str, Any], flush_s: float = 0.5,
                 channels: list[str] | None = None, files: dict[str, Any] | None = None) -> None:
        self.dir = prepare_run_dir(out)
        self.meta = {"format": FORMAT, "status": "running", "started": now_iso(),
                     "versions": versions(), "command": sys.argv, **meta,
                     "files": files or {"signals": SIGNALS_FILE, "capture": CAPTURE_FILE}}
        write_json(self.dir / META_FILE, self.meta)
        _warm_up_arrow()
        self.schema = SCHEMA if channels is None else rig_schema(channels)
        self.columns = tuple(self.schema.names)
        self._stream_path = self.dir / STREAM_FILE
        self._sink = pa.OSFile(str(self._stream_path), "wb")
        self._writer = pa.ipc.new_stream(self._sink, self.schema)
        self._sink.flush()
        #: rows known to be on disk (written and fsync'ed)
        self.rows_on_disk = 0
        self.closed = False
        self._rows = RowBuffer(self.schema, channels, self._write_batch,
                               f"{self._stream_path}: the recorder", "run-recorder", flush_s)
        self.append_cycle = self._rows.append_cycle
        self.poll = self._rows.poll
        self.flush = self._rows.flush

    @property
    def capture_path(self) -> Path:
        return self.dir / CAPTURE_FILE

    def capture_path_of(self, bus: str) -> Path:
        """A rig run's capture of ``bus``."""
        return self.dir / self.meta["files"]["captures"][bus]

    @property
    def truth_path(self) -> Path:
        return self.dir / TRUTH_FILE

    def append(self, t: float, u: float, y: float, r: float, cycle: int, y_counts: int,
               spool: float, valve_status: int, stale: bool, sync_time: float) -> None:
        """One row of a one-channel run (:meth:`append_cycle` with each value alone)."""
        self._rows.append_cycle(t, cycle, sync_time, (u,), (y,), (r,), (y_counts,), (spool,),
                                (valve_status,), (stale,))

    #: one cycle of every channel: ``append_cycle(t, cycle, sync_time, u, y, r, y_counts, spool,
    #: valve_status, stale)``, the channel values as sequences in the channels' order
    #: (:class:`gateway.rowbuffer.RowBuffer`); ``poll()`` and ``flush()`` are the buffer's too
    append_cycle = None

    @property
    def rows(self) -> int:
        """Rows appended so far."""
        return self._rows.rows

    def _write_batch(self, batch: pa.RecordBatch) -> None:
        """The writer thread's: a batch onto the stream, then fsync."""
        self._writer.write_batch(batch)
        self._sink.flush()
        try:
            os.fsync(self._sink.fileno())
        except (OSError, AttributeError, pa.ArrowNotImplementedError):
            pass
        self.rows_on_disk += batch.num_rows

    def sync(self) -> None:
        """Flush and wait until every row appended so far is on disk (raises a write's failure)."""
        self._rows.sync()

    def close(self, status: str = "complete", end_reason: str | None = None, **extra: Any) -> Path:
        """Finish the run: Parquet signals, final metadata. Safe to call once."""
        if self.closed:
            return self.dir
        try:
            self._rows.close()
        except DataError:
            pass                     # what reached the disk is the run (the loop heard it)
        self._writer.close()
        self._sink.close()
        with pa.OSFile(str(self._stream_path), "rb") as fh:
            table = pa.ipc.open_stream(fh).read_all()
        pq.write_table(table, self.dir / SIGNALS_FILE)
        self._stream_path.unlink()
        self.meta.update(status=status, end_reason=end_reason, ended=now_iso(),
                         rows=table.num_rows, **extra)
        write_json(self.dir / META_FILE, self.meta)
        self.closed = True
        return self.dir

    def write_truth(self, truth: dict[str, Any]) -> None:
        write_json(self.truth_path, truth)
