"""A control loop's rows handed to a writer thread: the one buffering both the run recorder
(:class:`gateway.recorder.RunRecorder`) and an endurance test's rolling window
(:class:`endurance.storage.SignalWindow`) use.

The loop appends one row per cycle (``append_cycle``, never waiting: a list append per column,
or for a rig every channel's values of a column kind onto one typed array) and calls :meth:`RowBuffer.poll`
while it waits for the stand; every ``flush_s`` the rows go to the writer thread, which turns them
into a ``pyarrow.RecordBatch`` and hands it to the owner's ``handle``. Anything else the owner
puts on the queue (:meth:`RowBuffer.put`: a batch of its own, a marker) reaches ``handle`` in
order. A failure of ``handle`` (the disk full) stops the writing and is raised, as a
:class:`core.errors.DataError` naming the owner, at the loop's next flush: the loop hears it
and stops instead of losing rows unseen."""
from __future__ import annotations

import array
import queue
import threading
import time
from typing import Any, Callable, Sequence

import numpy as np
import pyarrow as pa

from core.errors import DataError

from .runs import CHANNEL_COLUMNS


class RowBuffer:
    """Rows of ``schema`` (:data:`gateway.runs.SCHEMA`, or :func:`gateway.runs.rig_schema` of
    ``channels``) buffered on the loop's side, written by ``handle`` on a thread named ``name``;
    ``what`` names the owner in errors ("PATH: the recorder"). ``on_close``: called on the
    writer thread after everything put before :meth:`close` (and not after a failure)."""

    def __init__(self, schema: pa.Schema, channels: Sequence[str] | None, handle: Callable[[Any], None],
                 what: str, name: str, flush_s: float = 1.0,
                 on_close: Callable[[], None] | None = None) -> None:
        self.schema = schema
        self.columns = tuple(schema.names)
        self.what = what
        self._handle, self._on_close = handle, on_close
        #: a rig: the column names of each channel column kind, in CHANNEL_COLUMNS order
        self._groups = None if channels is None else \
            [[f"{col}.{ch}" for ch in channels] for col in CHANNEL_COLUMNS]
        self._scalars = self.columns if channels is None else ("t", "cycle", "sync_time")
        self.append_cycle = self._append_one if channels is None else self._append_rig
        self._buf: dict[str, list] = {c: [] for c in self._scalars}
        #: a rig: per channel column kind, every cycle's values of the channels, one typed
        #: array each (the channels' values of a cycle one after the other)
        self._codes = [] if channels is None else \
            [_array_code(schema.field(names[0]).type) if names else "d" for names in self._groups]
        self._kinds: list[array.array] = self._new_kinds()
        self._flush_s = flush_s
        self._last_flush = time.monotonic()
        self.rows = 0
        self.last_sync_time: float | None = None
        self.error: BaseException | None = None
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._work, name=name, daemon=True)
        self._thread.start()

    # -- the loop's side ------------------------------------------------------------------------
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
        self._appended(sync_time)

    def _append_rig(self, t: float, cycle: int, sync_time: float, *channel_values) -> None:
        b = self._buf
        b["t"].append(t); b["cycle"].append(cycle); b["sync_time"].append(sync_time)
        # a cycle's values of each kind onto that kind's typed array (16 channels: 7 calls,
        # not 112 appends); the writer thread takes the channels' columns from it as a numpy
        # view, without a Python loop over the values (the tuples it transposed before held
        # the loop's GIL ~0.5 ms a flush, and a third of the late cycles at 16 channels fell
        # there)
        for kind, values in zip(self._kinds, channel_values):
            kind.extend(values)
        self._appended(sync_time)

    def _new_kinds(self) -> list[array.array]:
        return [array.array(code) for code in self._codes]

    def _appended(self, sync_time: float) -> None:
        self.rows += 1
        self.last_sync_time = sync_time
        if time.monotonic() - self._last_flush >= self._flush_s:
            self.flush()

    def poll(self) -> None:
        """Flush if the oldest buffered row is due (the loop calls this while it waits)."""
        if time.monotonic() - self._last_flush >= self._flush_s:
            self.flush()

    def flush(self) -> None:
        """Hand the buffered rows to the writer thread; raises the writer's failure."""
        self._last_flush = time.monotonic()
        self.check()
        if not self._buf["t"]:
            return
        rows, self._buf = self._buf, {c: [] for c in self._scalars}
        if self._groups is not None:
            kinds, self._kinds = self._kinds, self._new_kinds()
            rows = _RigRows(rows, kinds)
        self._queue.put(rows)

    def put(self, item: Any) -> None:
        """``item`` to ``handle`` on the writer thread, after the rows buffered so far."""
        self.flush()
        self._queue.put(item)

    def check(self) -> None:
        """Raise the writer's failure, if there was one."""
        if self.error is not None:
            raise DataError(f"{self.what} cannot write: {self.error}")

    def sync(self) -> None:
        """Flush, and wait until the writer thread has handled everything so far."""
        self.flush()
        done = threading.Event()
        self._queue.put(_Barrier(done))
        done.wait()
        self.check()

    def close(self) -> None:
        """Flush (a failure is raised after the thread ends), let the writer thread finish."""
        try:
            self.flush()
        except DataError:
            pass
        self._queue.put(_CLOSE)
        self._thread.join()
        self.check()

    # -- the writer thread ----------------------------------------------------------------------
    def _work(self) -> None:
        while True:
            item = self._queue.get()
            if isinstance(item, _Barrier):
                item.event.set()
                continue
            try:
                if item is _CLOSE:
                    if self.error is None and self._on_close is not None:
                        self._on_close()
                    return
                if self.error is not None:
                    continue
                if isinstance(item, _RigRows):
                    item = item.columns(self._groups)
                if isinstance(item, dict):
                    item = pa.record_batch([pa.array(item[c], type=self.schema.field(c).type)
                                            for c in self.columns], schema=self.schema)
                self._handle(item)
            except BaseException as exc:     # the disk full, ...: heard at the next flush
                self.error = exc


class _RigRows:
    """A rig's buffered rows: the scalar columns, and per channel column kind a typed array
    of every cycle's channel values."""

    def __init__(self, scalars: dict[str, list], kinds: list[array.array]) -> None:
        self.scalars, self.kinds = scalars, kinds

    def columns(self, groups: list[list[str]]) -> dict[str, Any]:
        out: dict[str, Any] = dict(self.scalars)
        for names, values in zip(groups, self.kinds):
            if not names:               # a rig's rows without channels (a calibration's)
                continue
            dtype = np.bool_ if values.typecode == _BOOL_CODE else values.typecode
            by_channel = np.frombuffer(values, dtype=dtype).reshape(-1, len(names)).T.copy()
            for name, column in zip(names, by_channel):
                out[name] = column
        return out


#: the typed array code of a column of booleans (one byte, 0 or 1: numpy's bool)
_BOOL_CODE = "b"


def _array_code(kind: pa.DataType) -> str:
    """The :mod:`array` type code holding a column of ``kind`` exactly."""
    if pa.types.is_boolean(kind):
        return _BOOL_CODE
    code = np.dtype(kind.to_pandas_dtype()).char
    if code not in array.typecodes:
        raise TypeError(f"no typed array holds a column of {kind}")
    return code


class _Barrier:
    """A marker in the writer queue: sets its event when everything before it is handled."""

    def __init__(self, event: threading.Event) -> None:
        self.event = event


_CLOSE = object()
