r"""An endurance test's data of years, bounded.

::

    TESTDIR/turning_points/block=000001/part-000000001-000004529.parquet   every end point, for ever
    TESTDIR/rolling/chunk-<first ms>-<last ms>.parquet                      the last rolling_window_s
    TESTDIR/events/<time>-<kind>[-<channel>]-f<flight>/run.json, signals.parquet   ±event_window_s

**(a) The turning-point log** (:class:`TurningPointLog`): every channel's end point of every load
case of every flight, in Parquet partitioned by block (hive-style: ``pyarrow.dataset.dataset(
TESTDIR/turning_points, partitioning="hive")`` reads it whole). Columns: flight, block,
flight_type, attempt, load_case, channel, level_kgf (commanded), reached_kgf, error_kgf
(reached − level), flow_pct (the valve's command that reached it), time (s since the epoch),
rerun (the flight's attempt > 1: it ran again from its first load case after an interruption).
The journal is the log's source (:meth:`TurningPointLog.export`): the flights it counted and the
log lacks go into one small file per export, named by its flights; a block whose flights are
all in is compacted into one file of the same naming, and the journal's copy of its end points
pruned. Every file is written atomically (a hidden temp file, fsync, rename, fsync of the
directory), so a kill never leaves a torn file; a kill between a compaction's rename and its
removal of the small files leaves files whose flights another holds, which the next open removes
(and :func:`read_turning_points` never reads twice).

**(b) Full-rate signals** (:class:`SignalWindow`): the rows the recorder writes
(``append_cycle`` as :class:`gateway.recorder.RunRecorder`'s), kept only for the last
``rolling_window_s`` in chunks of ``chunk_s`` (the oldest deleted), plus windows of
±``event_window_s`` around each event (:meth:`SignalWindow.mark_event`), each a **run
directory** (``run.json`` + ``signals.parquet``, :mod:`gateway.runs`; a rig's columns
``u.NAME``, ``y.NAME``, ... ) that ``stand compare``, ``diagnose`` and ``report`` read like any
run (each built in a hidden directory and renamed into place whole, so a kill never leaves a
window without its ``run.json``; :func:`event_windows` lists them). The windows are the
**stand's time**, counted in rows of the control period: the rolling window keeps the last
``rolling_window_s / period_s`` rows (a chunk more while one fills), an event window the rows
within ``event_window_s`` of its event on the continuous stand time (:func:`continuous_time`:
``t`` made to increase across passes and resumes, a gap between them
counted at its wall-clock length). In real time that is the wall clock's seconds; in lockstep,
where the stand's second passes in a fraction of the wall's, it is what the plan counted (a
window by the wall clock would hold the run's speed-up times as many rows). Files are named and
events placed by ``sync_time`` (the wall clock). In an event window ``t`` is the continuous
time, so the analysis splits at a gap. Conversion and disk I/O happen on a writer thread.

**(c) The estimate** (:func:`storage_estimate`): bytes per 1,000 flights and for the whole target,
from the sizes measured by writing real data through these classes (:func:`calibrate`;
:data:`CALIBRATION` holds the figures, checked by ``tests/test_endurance_storage.py``).
"""
from __future__ import annotations

import math
import os
import re
import shutil
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from core.durable import fsync_dir, fsync_file, write_json
from core.errors import DataError, ParameterError
from gateway.rowbuffer import RowBuffer
from gateway.runs import FORMAT, META_FILE, SCHEMA, SIGNALS_FILE, rig_schema

from .journal import Journal

TURNING_POINTS_DIR = "turning_points"
#: a session brings the turning-point log up to date every this many flights (and at its end)
EXPORT_EVERY = 50
ROLLING_DIR = "rolling"
EVENTS_DIR = "events"
COMPRESSION = "zstd"

TURNING_POINT_SCHEMA = pa.schema([
    ("flight", pa.int32()), ("block", pa.int32()), ("flight_type", pa.string()),
    ("attempt", pa.int16()), ("load_case", pa.int16()), ("channel", pa.string()),
    ("level_kgf", pa.float64()), ("reached_kgf", pa.float32()), ("error_kgf", pa.float32()),
    ("flow_pct", pa.float32()), ("time", pa.float64()), ("rerun", pa.bool_()),
])
_PART = re.compile(r"^part-(\d{9})-(\d{9})\.parquet$")
_CHUNK = re.compile(r"^chunk-(\d+)-(\d+)\.parquet$")


# -- atomic files -----------------------------------------------------------------------------------
def write_parquet_atomic(table: pa.Table, path: Path) -> Path:
    """``table`` to ``path`` whole or not at all: a hidden temp file beside it (readers and
    ``pyarrow.dataset`` skip names starting with '.'), fsync, rename over, fsync the directory.
    A failure (the disk full) removes the temp file and raises :class:`DataError`."""
    tmp = path.parent / f".{path.name}.{os.getpid()}.tmp"
    floats = [f.name for f in table.schema if pa.types.is_floating(f.type)]
    others = [f.name for f in table.schema if f.name not in floats]
    try:
        # noisy floats: byte stream split (each byte of the numbers together) compresses them
        # by a third more than dictionaries would; everything else by dictionary
        pq.write_table(table, tmp, compression=COMPRESSION, use_byte_stream_split=floats or False,
                       use_dictionary=others or False)
        fsync_file(tmp)
        os.replace(tmp, path)
        fsync_dir(path.parent)
    except (OSError, pa.ArrowException) as exc:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise DataError(f"cannot write {path}: {exc}; nothing of it was written") from None
    return path


def event_windows(testdir: str | Path) -> list[Path]:
    """The test's event windows, oldest first: only whole ones (one being written, or left by a
    kill while it was, is a hidden directory)."""
    root = Path(testdir) / EVENTS_DIR
    return sorted(p for p in root.iterdir() if not p.name.startswith(".")) if root.is_dir() else []


# -- (a) the turning-point log ---------------------------------------------------------------------
def block_dir(root: Path, block: int) -> Path:
    return root / f"block={block:06d}"


def _part_name(first: int, last: int) -> str:
    return f"part-{first:09d}-{last:09d}.parquet"


def _parts(directory: Path) -> list[tuple[int, int, Path]]:
    """(first, last, path) of a block directory's files, without those another file holds."""
    found = []
    for p in directory.iterdir() if directory.is_dir() else ():
        m = _PART.match(p.name)
        if m:
            found.append((int(m.group(1)), int(m.group(2)), p))
    found.sort()
    return [(a, b, p) for a, b, p in found
            if not any(a2 <= a and b <= b2 and (a2, b2) != (a, b) for a2, b2, _ in found)]


def turning_point_files(testdir: str | Path) -> list[Path]:
    """The log's files, each flight in exactly one (a compacted block's leftovers skipped)."""
    root = Path(testdir) / TURNING_POINTS_DIR
    if not root.is_dir():
        return []
    return [p for d in sorted(root.glob("block=*")) for _, _, p in _parts(d)]


def read_turning_points(testdir: str | Path, columns: Sequence[str] | None = None,
                        filter: Any = None) -> pa.Table:
    """The whole log (or ``columns``, rows matching a ``pyarrow.dataset`` ``filter``)."""
    files = turning_point_files(testdir)
    if not files:
        return TURNING_POINT_SCHEMA.empty_table().select(list(columns) if columns else
                                                        TURNING_POINT_SCHEMA.names)
    dataset = ds.dataset([str(p) for p in files], schema=TURNING_POINT_SCHEMA, format="parquet")
    return dataset.to_table(columns=list(columns) if columns else None, filter=filter)


class TurningPointLog:
    """The turning-point log of ``testdir`` (module docstring); ``flights_per_block`` is the
    test's block size (which flights a block holds)."""

    def __init__(self, testdir: str | Path, flights_per_block: int) -> None:
        if flights_per_block < 1:
            raise ParameterError(f"flights_per_block = {flights_per_block}: give a whole number >= 1")
        self.root = Path(testdir) / TURNING_POINTS_DIR
        self.flights_per_block = int(flights_per_block)
        self.root.mkdir(parents=True, exist_ok=True)
        self.exported_through = self._repair()
        for d in sorted(self.root.glob("block=*")):      # a kill before a compaction
            b = int(d.name.split("=")[1])
            if len(_parts(d)) > 1 and b * self.flights_per_block <= self.exported_through:
                self.compact(b)
        #: the journal's end points are pruned through here (this object's knowledge: a kill
        #: between a compaction and its pruning is caught up at the next export)
        self._pruned_through = 0

    def _repair(self) -> int:
        """Remove what a kill left (temp files, small files a compacted file holds); the last
        flight in the log."""
        last = 0
        for d in sorted(self.root.glob("block=*")):
            for p in d.iterdir():
                if p.name.startswith(".") and p.name.endswith(".tmp"):
                    p.unlink(missing_ok=True)
            kept = {p for _, _, p in _parts(d)}
            for p in d.iterdir():
                if _PART.match(p.name) and p not in kept:
                    p.unlink(missing_ok=True)
            for _, b, _ in _parts(d):
                last = max(last, b)
        return last

    def block_of(self, flight: int) -> int:
        return (flight - 1) // self.flights_per_block + 1

    def write(self, table: pa.Table) -> Path:
        """Rows of consecutive flights of one block (:data:`TURNING_POINT_SCHEMA`) as one
        file named by its first and last flight."""
        flights = table.column("flight").to_numpy()
        first, last = int(flights.min()), int(flights.max())
        blocks = set(table.column("block").to_pylist())
        if len(blocks) != 1:
            raise DataError(f"flights {first}-{last}: a file of the log holds one block, got {sorted(blocks)}")
        d = block_dir(self.root, blocks.pop())
        d.mkdir(exist_ok=True)
        return write_parquet_atomic(_sorted(table.cast(TURNING_POINT_SCHEMA)),
                                    d / _part_name(first, last))

    def export(self, journal: Journal, prune: bool = True) -> int:
        """The flights ``journal`` counted that the log lacks, a file per block they touch;
        each block they complete compacted (and, ``prune``, its end points deleted from the
        journal: they are in the log for ever). Returns how many flights were written."""
        done = journal.flights_done
        first = self.exported_through + 1
        if done >= first:
            table = _turning_point_table(journal.end_points(first, done))
            blocks = np.asarray(table.column("block"))
            for b in np.unique(blocks):
                self.write(table.filter(pa.array(blocks == b)))
            self.exported_through = done
            for b in range(self.block_of(first), self.block_of(done) + 1):
                if b * self.flights_per_block <= done:
                    self.compact(b)
        compacted = (self.exported_through // self.flights_per_block) * self.flights_per_block
        if prune and journal.writer and compacted > self._pruned_through:
            journal.prune_end_points(compacted)
            self._pruned_through = compacted
        return max(done - first + 1, 0)

    def compact(self, block: int) -> Path | None:
        """A block's files as one (written atomically, the small files removed after)."""
        d = block_dir(self.root, block)
        parts = _parts(d)
        if not parts:
            return None
        if len(parts) == 1:
            return parts[0][2]
        table = pa.concat_tables([pq.read_table(p, schema=TURNING_POINT_SCHEMA) for _, _, p in parts])
        path = write_parquet_atomic(_sorted(table), d / _part_name(parts[0][0], parts[-1][1]))
        for _, _, p in parts:
            if p != path:
                p.unlink(missing_ok=True)
        fsync_dir(d)
        return path


def _sorted(table: pa.Table) -> pa.Table:
    """By channel, flight, attempt, load case: a channel's end points together compress best
    (a third less than in load case order) and read fastest."""
    return table.sort_by([("channel", "ascending"), ("flight", "ascending"),
                          ("attempt", "ascending"), ("load_case", "ascending")])


def _turning_point_table(rows: Sequence[tuple]) -> pa.Table:
    """Journal end points (:meth:`Journal.end_points`) as the log's table."""
    if not rows:
        return TURNING_POINT_SCHEMA.empty_table()
    cols = list(zip(*rows))
    level = np.asarray(cols[6], float)
    reached = np.asarray(cols[7], float)
    attempt = np.asarray(cols[3], np.int16)
    flow = pa.array(cols[8], type=pa.float64())
    return pa.table({
        "flight": pa.array(cols[0], pa.int32()), "block": pa.array(cols[1], pa.int32()),
        "flight_type": pa.array(cols[2], pa.string()), "attempt": pa.array(attempt),
        "load_case": pa.array(cols[4], pa.int16()), "channel": pa.array(cols[5], pa.string()),
        "level_kgf": level, "reached_kgf": reached, "error_kgf": reached - level,
        "flow_pct": flow, "time": pa.array(cols[9], pa.float64()),
        "rerun": pa.array(attempt > 1),
    }, schema=TURNING_POINT_SCHEMA)


# -- (b) the rolling window and the event windows ------------------------------------------------------
@dataclass(frozen=True)
class EventWindow:
    """An event whose window is (to be) written: its directory and its time (epoch s)."""

    path: Path
    time_s: float
    kind: str
    message: str
    channel: str | None = None
    flight: int | None = None
    #: when the stand was acted on (epoch s: a trip's safe-state command), if later than
    #: ``time_s`` (a heartbeat's loss is seen a timeout after its onset); None: at ``time_s``
    acted_s: float | None = None


class SignalWindow:
    """Full-rate signals kept for the last ``rolling_window_s`` and ±``event_window_s`` around
    each event (module docstring).

    Parameters
    ----------
    testdir : the test's directory
    channels : a rig's channels (the rig run format's columns); None: a one-channel stand
    period_s : the control period (for the event windows' run.json)
    rolling_window_s, event_window_s, chunk_s : the storage policy (:class:`StoragePolicy`)
    meta : what every event window's run.json carries besides the event (the gateway's run
        metadata: experiment, rig section with buses and channels, limits, ...)
    flush_s : rows are handed to the writer thread at least this often
    """

    def __init__(self, testdir: str | Path, channels: Sequence[str] | None, period_s: float,
                 rolling_window_s: float = 600.0, event_window_s: float = 30.0,
                 chunk_s: float = 60.0, meta: Mapping[str, Any] | None = None,
                 flush_s: float = 1.0) -> None:
        if not (0 < chunk_s <= rolling_window_s and 0 < event_window_s <= rolling_window_s):
            raise ParameterError(f"storage: chunk_s = {chunk_s:g} and event_window_s = "
                                 f"{event_window_s:g} must be positive and at most rolling_window_s "
                                 f"= {rolling_window_s:g}")
        self.testdir = Path(testdir)
        self.rolling = self.testdir / ROLLING_DIR
        self.events_dir = self.testdir / EVENTS_DIR
        self.rolling.mkdir(parents=True, exist_ok=True)
        self.events_dir.mkdir(parents=True, exist_ok=True)
        for p in self.rolling.glob(".*.tmp"):
            p.unlink(missing_ok=True)
        for p in self.events_dir.glob(".*.tmp"):
            shutil.rmtree(p, ignore_errors=True)
        self.channels = list(channels) if channels is not None else None
        self.schema = SCHEMA if channels is None else rig_schema(self.channels)
        self.columns = tuple(self.schema.names)
        self.period_s = float(period_s)
        self.rolling_window_s = float(rolling_window_s)
        self.event_window_s = float(event_window_s)
        self.chunk_s = float(chunk_s)
        self.meta = dict(meta or {})
        self._batches: list[pa.RecordBatch] = []        # the chunk being filled (writer thread)
        self._filling = 0                                # its rows
        self._chunk_rows = max(int(round(self.chunk_s / self.period_s)), 1)
        self._rolling_rows = max(int(round(self.rolling_window_s / self.period_s)), 1)
        self._event_rows = max(int(round(self.event_window_s / self.period_s)), 1)
        self._chunks: list[_Chunk] = self._found_chunks()
        self._rows_of: dict[tuple[Path, bool], int] = {}  # an event's rows (onset, acted), once on disk
        self._pending: list[EventWindow] = []            # events whose window is not written yet
        self._pending_lock = threading.Lock()
        self.written: list[EventWindow] = []
        self.closed = False
        self._rows = RowBuffer(self.schema, self.channels, self._handle,
                               f"{self.rolling}: the signal window", "signal-window", flush_s,
                               on_close=self._finish)
        #: one cycle of every channel, as :meth:`gateway.recorder.RunRecorder.append_cycle`
        #: takes it (the channel values as sequences in the channels' order)
        self.append_cycle = self._rows.append_cycle
        self.poll = self._rows.poll
        self.flush = self._rows.flush
        self.sync = self._rows.sync

    # -- the loop's side: appends only (:class:`gateway.rowbuffer.RowBuffer`) ---------------------
    @property
    def last_time_s(self) -> float | None:
        """The last row's ``sync_time`` (None before any)."""
        return self._rows.last_sync_time

    def append_rows(self, columns: Mapping[str, Any]) -> None:
        """Many rows at once: a mapping of every column (:attr:`columns`) to equal-length
        arrays."""
        missing = [c for c in self.columns if c not in columns]
        if missing:
            raise DataError(f"signal window: rows lack column(s) {', '.join(missing[:5])}")
        batch = pa.record_batch([pa.array(np.asarray(columns[c]), type=self.schema.field(c).type)
                                 for c in self.columns], schema=self.schema)
        if batch.num_rows:
            self._rows.last_sync_time = float(np.asarray(columns["sync_time"])[-1])
            self._rows.put(batch)

    def mark_event(self, kind: str, message: str, time_s: float | None = None,
                   channel: str | None = None, flight: int | None = None,
                   acted_s: float | None = None) -> EventWindow:
        """Keep ±event_window_s around ``time_s`` (epoch s; default the last row's): written as
        a run directory once the rows after it are in (or at :meth:`close`). ``acted_s``: when
        the stand was acted on, if not at ``time_s`` (in run.json's ``event`` as ``acted``)."""
        t = self.last_time_s if time_s is None else float(time_s)
        if t is None:
            raise DataError("signal window: an event before any row has no time; give time_s")
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime(t)) + f"{t % 1:.3f}"[1:]
        name = "-".join([stamp, _safe(kind)] + ([_safe(channel)] if channel else [])
                        + ([f"f{flight}"] if flight is not None else []))
        path = self.events_dir / name
        k = 1
        while path.exists() or any(e.path == path for e in self._pending):
            k += 1
            path = self.events_dir / f"{name}-{k}"
        event = EventWindow(path, t, kind, message, channel, flight, acted_s)
        with self._pending_lock:
            self._pending.append(event)
        self._rows.put(_WAKE)
        return event

    def close(self) -> list[EventWindow]:
        """Write the chunk being filled and every pending event's window (with what there is
        after it); returns the event windows written."""
        if self.closed:
            return self.written
        try:
            self._rows.close()
        finally:
            self.closed = True
        return self.written

    # -- the writer thread ------------------------------------------------------------------------
    def _handle(self, item) -> None:
        if isinstance(item, pa.RecordBatch):
            self._add(item)
        self._write_events(final=False)

    def _finish(self) -> None:
        self._write_chunk()
        self._write_events(final=True)

    def _add(self, batch: pa.RecordBatch) -> None:
        # a batch that crosses a chunk's end is split there (a chunk: chunk_s of the stand's rows)
        while batch.num_rows:
            room = self._chunk_rows - self._filling
            if batch.num_rows < room:
                self._batches.append(batch)
                self._filling += batch.num_rows
                return
            self._batches.append(batch.slice(0, room))
            self._write_chunk()
            batch = batch.slice(room)

    def _write_chunk(self) -> None:
        batches, self._batches, self._filling = self._batches, [], 0
        if not batches:
            return
        table = pa.Table.from_batches(batches, schema=self.schema)
        if not table.num_rows:
            return
        clock = table.column("sync_time")
        first, last = clock[0].as_py(), clock[-1].as_py()
        path = write_parquet_atomic(table, self.rolling / f"chunk-{_ms(first)}-{_ms(last)}.parquet")
        self._chunks.append(_Chunk(_ms(first), _ms(last), path, self._rows_on_disk(), table.num_rows))
        # the oldest go once no row of theirs is in the rolling window or a pending event's
        keep_from = self._rows_on_disk() - self._rolling_rows
        with self._pending_lock:
            pending = list(self._pending)
        for event in pending:
            row = self._event_row(event)
            if row is not None:
                keep_from = min(keep_from, row - self._event_rows)
        while len(self._chunks) > 1 and self._chunks[0].end <= keep_from:
            self._chunks.pop(0).path.unlink(missing_ok=True)

    def chunks(self) -> list[tuple[int, int, Path]]:
        """(first ms, last ms, path) of the rolling window's files, oldest first."""
        out = []
        for p in self.rolling.iterdir():
            m = _CHUNK.match(p.name)
            if m:
                out.append((int(m.group(1)), int(m.group(2)), p))
        return sorted(out)

    def _found_chunks(self) -> list["_Chunk"]:
        """The chunks a session before left, numbered on from the oldest (their rows from the
        files' footers; a file that cannot be read is left out of the window)."""
        found, start = [], 0
        for a, b, path in self.chunks():
            try:
                rows = pq.read_metadata(path).num_rows
            except (OSError, pa.ArrowException):
                continue
            found.append(_Chunk(a, b, path, start, rows))
            start += rows
        return found

    def _rows_on_disk(self) -> int:
        return self._chunks[-1].end if self._chunks else 0

    def _event_row(self, event: EventWindow, acted: bool = False) -> int | None:
        """The row (numbered as the chunks are) at or after the event's time (``acted``: the
        time the stand was acted on); None while that row is not on disk (the first on disk if
        the event is older than every row kept)."""
        key = (event.path, acted)
        if key in self._rows_of:
            return self._rows_of[key]
        at = event.acted_s if acted else event.time_s
        for chunk in self._chunks:
            if chunk.last_ms / 1000.0 + 0.001 < at:
                continue
            clock = pq.read_table(chunk.path, columns=["sync_time"]).column("sync_time").to_numpy()
            k = int(np.searchsorted(clock, at - 1e-6, side="left"))
            if k < len(clock):
                self._rows_of[key] = chunk.start + k
                return chunk.start + k
        return None

    def _write_events(self, final: bool) -> None:
        with self._pending_lock:
            pending = list(self._pending)
        for event in pending:
            row = self._event_row(event)
            # a trip acted on later than its onset (a heartbeat's timeout: in lockstep tens of
            # seconds of the stand's time): the window reaches as far past that moment
            later = event.acted_s is not None and event.acted_s > event.time_s
            end = self._event_row(event, acted=True) if later and row is not None else row
            complete = end is not None and self._rows_on_disk() > end + self._event_rows
            if not (complete or final):
                continue
            last = self._rows_on_disk()
            self._write_event(event, last if row is None else row, last if end is None else end)
            self._rows_of.pop((event.path, False), None)
            self._rows_of.pop((event.path, True), None)
            with self._pending_lock:
                self._pending.remove(event)
            self.written.append(event)

    def _write_event(self, event: EventWindow, row: int, end: int) -> None:
        """The event's window: the rows within event_window_s before its row and after ``end``
        (the row where the stand was acted on; ``row`` if then) on the continuous stand time (a
        superset first: that many rows of the period each side)."""
        lo, hi = row - self._event_rows, end + self._event_rows
        parts = [(c, pq.read_table(c.path)) for c in self._chunks if c.end > lo and c.start <= hi]
        tables = [t.slice(max(lo - c.start, 0), min(hi + 1, c.end) - max(lo, c.start)) for c, t in parts]
        table = pa.concat_tables(tables) if tables else self.schema.empty_table()
        clock = table.column("sync_time").to_numpy() if table.num_rows else np.array([])
        t = continuous_time(table.column("t").to_numpy(), clock, self.period_s) if table.num_rows else np.array([])
        truncated = True
        if table.num_rows:
            first = max(lo, parts[0][0].start)          # the row the table begins with

            def time_of(r: int) -> float:
                """Row ``r``'s continuous time; a row after every row on disk (an event marked at
                the end of a session) a period after the last."""
                if r >= self._rows_on_disk():
                    return float(t[-1] + self.period_s)
                return float(t[int(np.clip(r - first, 0, table.num_rows - 1))])
            t_event = time_of(row)
            t_end = max(time_of(end), t_event)
            half = self.period_s / 2
            inside = (t >= t_event - self.event_window_s - half) & (t <= t_end + self.event_window_s + half)
            truncated = bool(t[-1] < t_end + self.event_window_s - half)
            table, clock, t = table.filter(pa.array(inside)), clock[inside], t[inside]
        table = table.set_column(table.schema.get_field_index("t"), "t", pa.array(t, pa.float64()))
        # built in a hidden directory and renamed into place whole: a kill while it is written
        # leaves no window without its run.json (the hidden one is removed at the next open)
        tmp = event.path.parent / f".{event.path.name}.tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        write_parquet_atomic(table, tmp / SIGNALS_FILE)
        meta = {"format": FORMAT, **self.meta, "status": "complete", "period_s": self.period_s,
                "end_reason": "event window", "rows": table.num_rows,
                "files": {"signals": SIGNALS_FILE},
                "event": {"kind": event.kind, "message": event.message, "channel": event.channel,
                          "flight": event.flight, "time": event.time_s, "acted": event.acted_s,
                          "window_s": [float(clock.min()) if len(clock) else None,
                                       float(clock.max()) if len(clock) else None],
                          "stand_window_s": self.event_window_s, "truncated": truncated,
                          "first_sync_time": float(clock.min()) if len(clock) else None}}
        meta.setdefault("experiment", {"name": "endurance event window", "params": {}})
        write_json(tmp / META_FILE, meta)
        fsync_dir(tmp)
        os.rename(tmp, event.path)
        fsync_dir(event.path.parent)


@dataclass(frozen=True)
class _Chunk:
    """A file of the rolling window: its name's times (ms), its rows numbered on from the oldest."""

    first_ms: int
    last_ms: int
    path: Path
    start: int
    rows: int

    @property
    def end(self) -> int:
        return self.start + self.rows


def continuous_time(t: np.ndarray, sync_time: np.ndarray, period_s: float) -> np.ndarray:
    """``t`` made to increase: where it goes back (a pass that starts again at 0) the rest is
    shifted to continue after the sample before by the wall-clock gap between them (at least a
    period), so a gap between passes stays a gap."""
    t = np.asarray(t, float).copy()
    back = np.flatnonzero(np.diff(t) <= 0)
    for i in back:
        step = max(float(sync_time[i + 1] - sync_time[i]), period_s)
        t[i + 1:] += t[i] + step - t[i + 1]
    return t


def rig_meta(station: Any, name: str | None = None) -> dict[str, Any]:
    """A run.json ``rig`` section for an event window of ``station``
    (:class:`endurance.testfile.Station`) when the gateway's own metadata is not at hand:
    the channels with their bus, node ids, range and force limit. A stand: no section."""
    if station.kind != "rig":
        return {}
    rig = station.rig
    channels = [{"name": c.name, "bus": c.bus,
                 "nodes": {"valve": {"id": c.valve_id}, "dynamometer": {"id": c.dynamometer_id}},
                 "range_kgf": c.range_kgf, "force_limit_kgf": c.limit_kgf, "driven": True}
                for c in rig.channels]
    from gateway.runs import capture_file
    return {"rig": {"name": name or rig.name, "file": str(rig.path) if rig.path else None,
                    "period_s": rig.period_s,
                    "G": rig.G.tolist() if rig.G is not None else None,
                    "buses": [{"name": b.name, "spec": b.spec, "capture": capture_file(b.name)}
                              for b in rig.buses],
                    "channels": channels, "driven": list(rig.names)}}


#: a marker put on the writer's queue: an event was marked (its window may be due)
_WAKE = object()


def _ms(t: float) -> int:
    return int(round(t * 1000.0))


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", str(text))[:40] or "event"


# -- (c) the estimate --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Calibration:
    """Bytes on disk measured by writing real data through this module (:func:`calibrate`).

    Attributes
    ----------
    turning_point_b : per turning point (one channel's end point) in a compacted block
    journal_load_case_b : per load case in the journal, its share of its flight's row
        included (end points pruned)
    journal_end_point_b : per end point while in the journal (a block's, until compacted)
    sample_channel_b : per full-rate sample of one channel (u, y, r, y_counts, spool, status,
        stale) in the rolling window's files; ``sample_row_b`` per row (t, cycle, sync_time)
    """

    turning_point_b: float
    journal_load_case_b: float
    journal_end_point_b: float
    sample_channel_b: float
    sample_row_b: float


#: measured by :func:`calibrate` (4 channels, TWIST-like flights, 2 kgf noise; zstd Parquet,
#: SQLite 3.40, pyarrow 26) and checked by tests/test_endurance_storage.py
CALIBRATION = Calibration(turning_point_b=11.3, journal_load_case_b=24.6,
                          journal_end_point_b=50.8, sample_channel_b=26.1, sample_row_b=3.75)


#: Bytes on disk per record that :func:`calibrate` does not write, measured on a session of
#: ``examples/test.toml`` offline (:mod:`endurance.offline`, 600 flights of 4 channels, 7 load cases
#: a flight on average, with ``[monitor.trend]``, ``[monitor.gain] mode = "watch"`` and
#: ``[time_scaling]``): the journal's tables from SQLite's ``dbstat`` (SUM(pgsize) / SUM(ncell):
#: the rows with their B-tree's keys, index and page fill), the files from their sizes.
#: Per Parquet file of the turning-point log (footer, schema, the 12 columns' headers and
#: dictionaries): the same end points written as files of 1-100 flights, size = 3,894 B +
#: 11.35 B per end point (least squares; the slope is :data:`CALIBRATION`'s).
TURNING_POINT_FILE_B = 3894.0
#: a flight's row in the journal and its index (flights, flights_finished): 45,056 B / 600
JOURNAL_FLIGHT_B = 75.0
#: a load case's row (load_cases): 94,208 B / 4,200
JOURNAL_LOAD_CASE_B = 22.4
#: the trend's row per flight (monitor_history, JSON of 5 numbers per channel): 298 B of
#: payload for 4 channels (≈ 100 + 50 per channel) and 66 B of key and page: 166 + 50 per channel
TREND_ROW_B, TREND_ROW_CHANNEL_B = 166.0, 50.0
#: the gain monitor's row per channel and closed block (``block_s`` of loading): 312 B + 66
GAIN_ROW_B = 378.0
#: an event's row (events: 130-170 B of payload with its key) and a session's record
#: (TESTDIR/sessions/NNNN.json)
EVENT_ROW_B, SESSION_FILE_B = 200.0, 1250.0
#: what a flight type keeps, replaced as the test goes (compensation, schedules, monitor_state):
#: its compensation tables 40 B per channel and load case (30 B of TOML text + key), its schedule
#: 495 + 92 B per load case (time scaling)
COMPENSATION_B, SCHEDULE_B, SCHEDULE_CASE_B = 40.0, 495.0, 92.0
#: the trend's state of a type (JSON, :meth:`endurance.trends.TrendDetector.state`), 19.9 B a
#: number (16 channels, 460 flights offline): while it learns, its learning flights' three
#: numbers per channel and load case; armed, four per channel and load case, three N x N
#: matrices (the noise's scatter, its whitening, the correction) and three per channel;
#: whichever is larger (a test's first blocks are all learning), + 230 B of keys
TREND_NUMBER_B, TREND_STATE_B = 19.9, 230.0
#: a journal's write-ahead log while a session runs: SQLite checkpoints it at 1,000 pages and
#: keeps the file at that size until the session's end truncates it
WAL_B = 1000 * 4096.0
#: the plan's assumption for the total: event windows per 1,000 flights (one stop or trip and
#: the window of the resume after it; each window is also shown on its own)
EVENT_WINDOWS_PER_1000_FLIGHTS = 2.0


@dataclass(frozen=True)
class StorageEstimate:
    """What a test keeps on disk (bytes): what grows with the flights (per 1,000), what is bounded."""

    channels: int
    flights: int
    turning_points_per_1000_flights: float
    turning_point_bytes_per_1000_flights: float   #: end points + a Parquet file per block
    journal_bytes_per_1000_flights: float         #: flights and load cases (pruned end points' pages are given back)
    monitor_bytes_per_1000_flights: float         #: the monitors' rows (monitor_history)
    per_1000_flights: float            #: what grows: turning points + journal + monitors
    per_1000_flights_per_channel: float  #: its share that scales with the channels, per channel
    rolling_window: float              #: the rolling window at its fullest (a chunk more)
    journal_block_end_points: float    #: a block's end points in the journal before compaction
    event_window: float                #: each event's run directory
    event_windows_per_1000_flights: float  #: assumed (:data:`EVENT_WINDOWS_PER_1000_FLIGHTS`)
    per_type: float                    #: compensation, schedules, monitors' states: fixed
    block_files: float                 #: the block in progress as files of EXPORT_EVERY flights
    wal: float                         #: the journal's write-ahead log while a session runs
    total: float                       #: the target: all of it, the assumed event windows too

    def grown(self, flights: float, sessions: int = 1, event_windows: int = 0) -> float:
        """Bytes written by ``flights`` flights in ``sessions`` sessions with ``event_windows``
        windows, start-up files not counted (the bounded parts as far as those flights fill them)."""
        blocks = self.flights_per_block
        partial = flights % blocks
        return (self.per_1000_flights * flights / 1000.0
                + (TURNING_POINT_FILE_B if partial else 0.0)
                + self.per_type + sessions * (SESSION_FILE_B + 3 * EVENT_ROW_B)
                + event_windows * (self.event_window + EVENT_ROW_B))

    flights_per_block: int = 1

    def text(self) -> str:
        mb = 1e6
        return "\n".join([
            f"storage for {self.flights:,} flights on {self.channels} channel(s):",
            f"  turning points  {self.turning_point_bytes_per_1000_flights / mb:9.2f} MB per 1,000 "
            f"flights ({self.turning_points_per_1000_flights:,.0f} end points; "
            f"{self.per_1000_flights_per_channel / mb:.3f} MB per channel)",
            f"  journal         {self.journal_bytes_per_1000_flights / mb:9.2f} MB per 1,000 flights "
            f"(+ {self.journal_block_end_points / mb:.1f} MB of a block's end points until compacted)",
            f"  monitors' rows  {self.monitor_bytes_per_1000_flights / mb:9.2f} MB per 1,000 flights",
            f"  growing         {self.per_1000_flights / mb:9.2f} MB per 1,000 flights",
            f"  per-type state  {self.per_type / mb:9.2f} MB (fixed; + {self.block_files / mb:.2f} MB of the "
            f"block in progress, + {self.wal / mb:.1f} MB of write-ahead log while running)",
            f"  rolling window  {self.rolling_window / mb:9.1f} MB (fixed)",
            f"  each event      {self.event_window / mb:9.1f} MB (assumed {self.event_windows_per_1000_flights:g} "
            "per 1,000 flights in the target)",
            f"  the target      {self.total / 1e9:9.2f} GB" if self.total >= 1e8 else
            f"  the target      {self.total / 1e6:9.1f} MB",
        ])


def storage_estimate(test: Any, calibration: Calibration | None = None,
                     flight_s: float | None = None) -> StorageEstimate:
    """Bytes per 1,000 flights and for the target of ``test`` (:class:`endurance.testfile.EnduranceTest`)
    on its N channels, from the measured :data:`CALIBRATION` (or ``calibration``) and the
    per-record sizes above. ``flight_s``: a flight's stand time (the gain monitor's rows; the
    plan gives it at the chosen rates, an upper bound with time scaling)."""
    c = calibration or CALIBRATION
    n = test.station.n
    block = test.block
    types = test.flight_types
    lc_per_flight = sum(block.counts[t] * types[t].load_cases for t in block.counts) / block.size
    points = 1000.0 * lc_per_flight * n
    tp = points * c.turning_point_b + 1000.0 / block.size * TURNING_POINT_FILE_B
    journal = 1000.0 * (JOURNAL_FLIGHT_B + lc_per_flight * JOURNAL_LOAD_CASE_B)
    trend_on = getattr(test, "trend", None) is not None
    gain = test.gain.options() if getattr(test, "gain", None) is not None else None
    monitors = 1000.0 * (TREND_ROW_B + n * TREND_ROW_CHANNEL_B) if trend_on else 0.0
    if gain is not None and flight_s:
        monitors += 1000.0 * n * flight_s / gain.block_s * GAIN_ROW_B
    per_channel = 1000.0 * lc_per_flight * c.turning_point_b + (
        1000.0 * TREND_ROW_CHANNEL_B if trend_on else 0.0) + (
        1000.0 * flight_s / gain.block_s * GAIN_ROW_B if gain is not None and flight_s else 0.0)
    per_sample = n * c.sample_channel_b + c.sample_row_b
    rate = 1.0 / test.station.period_s
    rolling = (test.storage.rolling_window_s + test.storage.chunk_s) * rate * per_sample
    event = 2 * test.storage.event_window_s * rate * per_sample
    block_points = max(block.size, EXPORT_EVERY) * lc_per_flight * n * c.journal_end_point_b
    cases = sum(ft.load_cases for ft in types.values())
    per_type = n * cases * COMPENSATION_B
    if trend_on:
        learn = test.trend.learn_flights
        per_type += sum(TREND_STATE_B + TREND_NUMBER_B * max(learn * 3 * ft.load_cases * n,
                                                              4 * ft.load_cases * n + 3 * n * n + 3 * n)
                        for ft in types.values())
    if getattr(test, "time_scaling", None) is not None:
        per_type += len(types) * SCHEDULE_B + cases * SCHEDULE_CASE_B
    block_files = max(math.ceil(block.size / EXPORT_EVERY) - 1, 0) * TURNING_POINT_FILE_B
    grows = tp + journal + monitors
    events = EVENT_WINDOWS_PER_1000_FLIGHTS * (event + EVENT_ROW_B)
    total = (grows + events) * test.flights / 1000.0 + rolling + block_points + per_type + block_files + WAL_B
    return StorageEstimate(n, test.flights, points, tp, journal, monitors, grows, per_channel, rolling,
                           block_points, event, EVENT_WINDOWS_PER_1000_FLIGHTS, per_type, block_files,
                           WAL_B, total, block.size)


def calibrate(directory: str | Path, channels: int = 4, flights: int = 300,
              seconds: float = 20.0, period_s: float = 0.002, seed: int = 0) -> Calibration:
    """Measure :class:`Calibration` by writing real data through :class:`Journal`,
    :class:`TurningPointLog` and :class:`SignalWindow` in ``directory``: ``flights`` TWIST-like
    flights (blocks of ``flights``, so one compacted block) of ``channels`` channels, end points
    reached within 2 kgf noise, flows about the level's rate; and ``seconds`` of full-rate
    signals (haversines, 2 kgf noise on the force, 0.1 N counts)."""
    from .spectrum import Block, FlightSequence, twist_like_counts, twist_like_levels
    directory = Path(directory)
    rng = np.random.default_rng(seed)
    names = [f"ch{i + 1}" for i in range(channels)]
    limits = np.linspace(9000.0, 4500.0, channels)
    levels = twist_like_levels(limits)
    counts = twist_like_counts(len(levels))
    seq = FlightSequence(Block(counts, seed), flights)
    testdir = directory / "calibration"
    journal = Journal.create(testdir, "calibration", flights, names, "calibration")
    size0 = _size(testdir, "journal.sqlite")
    journal.start()
    t = 1.8e9
    load_cases = 0
    for n in range(1, flights + 1):
        slot = seq.slot(n)
        lv = levels[slot.flight_type]
        journal.begin_flight(n, slot.flight_type, 1, n, lv.shape[1])
        for k in range(lv.shape[1]):
            t += 0.7 + 0.3 * rng.random()
            reached = lv[:, k] + rng.normal(0.0, 2.0, channels)
            flow = 20.0 * np.tanh((lv[:, k] - lv[:, k - 1]) / 2000.0) + rng.normal(0.0, 0.3, channels)
            journal.commit_load_case(n, k, [_end_point(names[i], lv[i, k], reached[i], flow[i], t)
                                            for i in range(channels)], time_s=t)
            load_cases += 1
        journal.finish_flight(n)
    journal.checkpoint()
    with_points = _size(testdir, "journal.sqlite")
    log = TurningPointLog(testdir, flights)
    log.export(journal, prune=True)
    journal.checkpoint(vacuum=True)
    pruned = _size(testdir, "journal.sqlite")
    journal.close()
    tp_bytes = sum(p.stat().st_size for p in turning_point_files(testdir))
    points = load_cases * channels
    # full-rate signals
    window = SignalWindow(testdir, names, period_s, rolling_window_s=10 * seconds,
                          event_window_s=1.0, chunk_s=seconds)
    rows = int(seconds / period_s)
    tt = np.arange(rows) * period_s
    cols: dict[str, Any] = {"t": tt, "cycle": np.arange(rows), "sync_time": 1.8e9 + tt}
    for i, ch in enumerate(names):
        r = limits[i] * 0.4 * (1 - np.cos(2 * np.pi * 0.2 * tt + i)) / 2
        y = r + rng.normal(0.0, 2.0, rows)
        counts_ = np.round(y * 98.0665).astype(np.int32)          # 0.1 N counts
        cols.update({f"r.{ch}": r, f"y.{ch}": counts_ / 98.0665, f"y_counts.{ch}": counts_,
                     f"u.{ch}": np.gradient(r, period_s) / 120.0 + rng.normal(0, 0.05, rows),
                     f"spool.{ch}": np.gradient(r, period_s) / 120.0 + rng.normal(0, 0.05, rows),
                     f"valve_status.{ch}": np.full(rows, 0x0027, np.uint16),
                     f"stale.{ch}": np.zeros(rows, bool)})
    window.append_rows(cols)
    window.close()
    full = sum(p.stat().st_size for _, _, p in window.chunks())
    # the per-row columns: the same rows of no channel
    only = SignalWindow(directory / "calibration-rows", [], period_s, 10 * seconds, 1.0, seconds)
    only.append_rows({"t": tt, "cycle": np.arange(rows), "sync_time": 1.8e9 + tt})
    only.close()
    row_b = sum(p.stat().st_size for _, _, p in only.chunks()) / rows
    return Calibration(turning_point_b=tp_bytes / points,
                       journal_load_case_b=(pruned - size0) / load_cases,
                       journal_end_point_b=(with_points - pruned) / points,
                       sample_channel_b=(full / rows - row_b) / channels, sample_row_b=row_b)


def _end_point(channel: str, level: float, reached: float, flow: float, t: float):
    from .journal import EndPoint
    return EndPoint(channel, float(level), float(reached), float(flow), t)


def _size(directory: Path, name: str) -> int:
    return sum((directory / f).stat().st_size for f in (name, name + "-wal")
               if (directory / f).exists())
