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
import json
import os
import platform
import queue
import sys
import threading
import time
from importlib import metadata as _md
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.ipc
import pyarrow.parquet as pq

from .errors import DataError, StandError
from .runs import (CAPTURE_FILE, CHANNEL_COLUMNS, COLUMNS, FORMAT, META_FILE,
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


def write_json(path: Path, data: dict[str, Any]) -> None:
    """Write JSON atomically (temp file + rename), so a crash never leaves half a file."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=_json_default) + "\n")
    os.replace(tmp, path)


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "item"):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


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
        self.columns = COLUMNS if channels is None else tuple(self.schema.names)
        #: a rig: the column names of each channel column kind, in CHANNEL_COLUMNS order
        self._groups = None if channels is None else \
            [[f"{col}.{ch}" for ch in channels] for col in CHANNEL_COLUMNS]
        self.append_cycle = self._append_one if channels is None else self._append_rig
        self._buf: dict[str, list] = {name: [] for name in self.columns}
        #: a rig: per channel column kind, one tuple of the channels' values per cycle
        self._kinds: list[list] = [] if channels is None else [[] for _ in CHANNEL_COLUMNS]
        self._stream_path = self.dir / STREAM_FILE
        self._sink = pa.OSFile(str(self._stream_path), "wb")
        self._writer = pa.ipc.new_stream(self._sink, self.schema)
        self._sink.flush()
        self._flush_s = flush_s
        self._last_flush = time.monotonic()
        self.rows = 0
        #: rows known to be on disk (written and fsync'ed)
        self.rows_on_disk = 0
        self.closed = False
        self._error: BaseException | None = None
        self._batches: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._write_batches, name="run-recorder", daemon=True)
        self._thread.start()

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
        b = self._buf
        b["t"].append(t); b["u"].append(u); b["y"].append(y); b["r"].append(r)
        b["cycle"].append(cycle); b["y_counts"].append(y_counts); b["spool"].append(spool)
        b["valve_status"].append(valve_status); b["stale"].append(stale)
        b["sync_time"].append(sync_time)
        self.rows += 1
        if time.monotonic() - self._last_flush >= self._flush_s:
            self.flush()

    #: one cycle of every channel: ``append_cycle(t, cycle, sync_time, u, y, r, y_counts, spool,
    #: valve_status, stale)``, the channel values as sequences in the channels' order
    append_cycle = None

    def _append_one(self, t: float, cycle: int, sync_time: float, u, y, r, y_counts, spool,
                    valve_status, stale) -> None:
        b = self._buf
        b["t"].append(t); b["u"].append(u[0]); b["y"].append(y[0]); b["r"].append(r[0])
        b["cycle"].append(cycle); b["y_counts"].append(y_counts[0]); b["spool"].append(spool[0])
        b["valve_status"].append(valve_status[0]); b["stale"].append(stale[0])
        b["sync_time"].append(sync_time)
        self.rows += 1
        if time.monotonic() - self._last_flush >= self._flush_s:
            self.flush()

    def _append_rig(self, t: float, cycle: int, sync_time: float, *channel_values) -> None:
        b = self._buf
        b["t"].append(t); b["cycle"].append(cycle); b["sync_time"].append(sync_time)
        # a cycle's values of each kind as one tuple (the loop reuses its lists); the writer
        # thread turns them into the channels' columns (16 channels: 7 appends, not 112)
        for kind, values in zip(self._kinds, channel_values):
            kind.append(tuple(values))
        self.rows += 1
        if time.monotonic() - self._last_flush >= self._flush_s:
            self.flush()

    def poll(self) -> None:
        """Flush if the oldest buffered row is due (the loop calls this while it waits)."""
        if time.monotonic() - self._last_flush >= self._flush_s:
            self.flush()

    def flush(self) -> None:
        """Hand the buffered rows to the writer thread (one record batch, then fsync)."""
        self._last_flush = time.monotonic()
        if self._error is not None:
            raise DataError(f"{self._stream_path}: the recorder cannot write: {self._error}")
        if not self._buf["t"]:
            return
        rows, self._buf = self._buf, {name: [] for name in self.columns}
        if self._groups is not None:
            kinds, self._kinds = self._kinds, [[] for _ in CHANNEL_COLUMNS]
            rows = _RigRows(rows, kinds)
        self._batches.put(rows)

    def _write_batches(self) -> None:
        while True:
            rows = self._batches.get()
            if rows is None:
                return
            if isinstance(rows, _Barrier):
                rows.event.set()
                continue
            if self._error is not None:
                continue
            try:
                if isinstance(rows, _RigRows):
                    rows = rows.columns(self._groups)
                schema = self.schema
                batch = pa.record_batch([pa.array(rows[name], type=schema.field(name).type)
                                         for name in self.columns], schema=schema)
                self._writer.write_batch(batch)
                self._sink.flush()
                try:
                    os.fsync(self._sink.fileno())
                except (OSError, AttributeError, pa.ArrowNotImplementedError):
                    pass
                self.rows_on_disk += batch.num_rows
            except BaseException as exc:   # disk full, ...: the loop hears it at its next flush
                self._error = exc

    def sync(self) -> None:
        """Flush and wait until every row appended so far is on disk."""
        self.flush()
        done = threading.Event()
        self._batches.put(_Barrier(done))
        done.wait()

    def close(self, status: str = "complete", end_reason: str | None = None, **extra: Any) -> Path:
        """Finish the run: Parquet signals, final metadata. Safe to call once."""
        if self.closed:
            return self.dir
        try:
            self.flush()
        except DataError:
            pass
        self._batches.put(None)
        self._thread.join()
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


class _RigRows:
    """A rig's buffered rows: the scalar columns, and per channel column kind one tuple of the
    channels' values per cycle."""

    def __init__(self, scalars: dict[str, list], kinds: list[list]) -> None:
        self.scalars, self.kinds = scalars, kinds

    def columns(self, groups: list[list[str]]) -> dict[str, list]:
        out = dict(self.scalars)
        for names, rows in zip(groups, self.kinds):
            for name, column in zip(names, zip(*rows)):
                out[name] = list(column)
        return out


class _Barrier(dict):
    """A marker in the writer queue: sets its event when everything before it is written."""

    def __init__(self, event: threading.Event) -> None:
        super().__init__()
        self.event = event
