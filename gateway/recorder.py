"""Writes a run directory (format: :mod:`gateway.runs`) while the loop runs.

Crash safety: rows are buffered in memory and written as Arrow IPC record batches to
``signals.arrows`` at least every ``flush_s`` seconds (then flushed and fsync'ed), so after a
``kill -9`` the run keeps every row up to the last flush. On a clean close the stream is
converted to ``signals.parquet`` and removed, and ``run.json`` gets the end status and reason.
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import sys
import time
from importlib import metadata as _md
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.ipc
import pyarrow.parquet as pq

from .errors import StandError
from .runs import (CAPTURE_FILE, COLUMNS, FORMAT, META_FILE, SCHEMA, SIGNALS_FILE, STREAM_FILE,
                   TRUTH_FILE)


def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for dist in ("hydrostand", "python-can", "canopen", "cantools", "numpy", "scipy", "pyarrow"):
        try:
            out[dist] = _md.version(dist)
        except _md.PackageNotFoundError:
            pass
    return out


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
    """Append one row per cycle; :meth:`close` finalises the run."""

    def __init__(self, out: str | Path, meta: dict[str, Any], flush_s: float = 0.5) -> None:
        self.dir = prepare_run_dir(out)
        self.meta = {"format": FORMAT, "status": "running", "started": now_iso(),
                     "versions": versions(), "command": sys.argv, **meta,
                     "files": {"signals": SIGNALS_FILE, "capture": CAPTURE_FILE}}
        write_json(self.dir / META_FILE, self.meta)
        self._buf: dict[str, list] = {name: [] for name in COLUMNS}
        self._stream_path = self.dir / STREAM_FILE
        self._sink = pa.OSFile(str(self._stream_path), "wb")
        self._writer = pa.ipc.new_stream(self._sink, SCHEMA)
        self._flush_s = flush_s
        self._last_flush = time.monotonic()
        self.rows = 0
        self.closed = False

    @property
    def capture_path(self) -> Path:
        return self.dir / CAPTURE_FILE

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

    def flush(self) -> None:
        """Write the buffered rows as one record batch and push them to disk."""
        self._last_flush = time.monotonic()
        if not self._buf["t"]:
            return
        batch = pa.record_batch([pa.array(self._buf[name], type=SCHEMA.field(name).type)
                                 for name in COLUMNS], schema=SCHEMA)
        self._writer.write_batch(batch)
        self._sink.flush()
        try:
            os.fsync(self._sink.fileno())
        except (OSError, AttributeError, pa.ArrowNotImplementedError):
            pass
        for col in self._buf.values():
            col.clear()

    def close(self, status: str = "complete", end_reason: str | None = None, **extra: Any) -> Path:
        """Finish the run: Parquet signals, final metadata. Safe to call once."""
        if self.closed:
            return self.dir
        self.flush()
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
