"""Streamed Parquet output with bounded memory: one file of row groups, or a partitioned
directory of part files that pyarrow.dataset, DuckDB, Polars and Spark read as one table::

    signals.parquet                      # single file (row groups of ``group_rows``)
    signals.parquet/part-00000.parquet   # partitioned: a new part every ``partition_rows`` rows
    signals.parquet/part-00001.parquet

``pq.read_table`` (and so :func:`gateway.load_run`) reads either form.

Columns are handed to pyarrow as buffers (:func:`arrow_column`), not through ``pa.array``: for
a numpy array ``pa.array`` asks pandas whether it is a pandas object, and imports pandas to ask
when it is installed (0.3 s; it is, with ``hydrostand[mf4]``: asammdf needs it).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

GROUP_ROWS = 1 << 16

#: arrow types whose values are the bytes of a numpy array of this dtype
_FIXED_WIDTH = {pa.float64(): np.dtype(np.float64), pa.float32(): np.dtype(np.float32),
                pa.int64(): np.dtype(np.int64), pa.int32(): np.dtype(np.int32),
                pa.int16(): np.dtype(np.int16), pa.int8(): np.dtype(np.int8),
                pa.uint64(): np.dtype(np.uint64), pa.uint32(): np.dtype(np.uint32),
                pa.uint16(): np.dtype(np.uint16), pa.uint8(): np.dtype(np.uint8)}


def arrow_column(values: np.ndarray, type: pa.DataType) -> pa.Array:
    """``values`` as an arrow array of ``type``, without nulls: the same array as
    ``pa.array(values, type=type)``, built from the numpy buffer (no pandas check, no copy) when
    the dtype is already the type's; other dtypes and types go through ``pa.array`` (which casts
    safely)."""
    values = np.asarray(values)
    if values.ndim == 1 and type == pa.bool_() and values.dtype == np.bool_:
        bits = np.packbits(values, bitorder="little")
        return pa.Array.from_buffers(type, len(values), [None, pa.py_buffer(bits)])
    if values.ndim == 1 and _FIXED_WIDTH.get(type) == values.dtype:
        return pa.Array.from_buffers(type, len(values), [None, pa.py_buffer(np.ascontiguousarray(values))])
    return pa.array(values, type=type)


class PartWriter:
    """Append column batches; rows are written in groups of ``group_rows``."""

    def __init__(self, path: Path, schema: pa.Schema, partition_rows: int | None = None,
                 group_rows: int = GROUP_ROWS) -> None:
        self.path = Path(path)
        self.schema = schema
        self.partition_rows = partition_rows
        self.group_rows = min(group_rows, partition_rows) if partition_rows else group_rows
        self._buf: list[dict] = []
        self._buffered = 0
        self._writer: pq.ParquetWriter | None = None
        self._in_part = 0
        self.parts = 0
        self.rows = 0
        if partition_rows:
            self.path.mkdir(parents=True, exist_ok=True)

    def write(self, columns: dict[str, np.ndarray]) -> None:
        n = len(next(iter(columns.values())))
        if not n:
            return
        self._buf.append(columns)
        self._buffered += n
        if self._buffered >= self.group_rows:
            self._flush(final=False)

    def _flush(self, final: bool) -> None:
        if not self._buffered:
            return
        names = self.schema.names
        cols = {k: np.concatenate([b[k] for b in self._buf]) for k in names}
        total = self._buffered
        self._buf, self._buffered = [], 0
        start = 0
        while start < total:
            room = self.group_rows
            if self.partition_rows:
                room = min(room, self.partition_rows - self._in_part)
            stop = min(total, start + room)
            if stop - start < room and not final:
                # keep a partial group for later (bounded: < group_rows rows)
                self._buf.append({k: v[start:] for k, v in cols.items()})
                self._buffered = total - start
                return
            table = pa.table({k: arrow_column(cols[k][start:stop], self.schema.field(k).type)
                              for k in names}, schema=self.schema)
            self._writer_for_part().write_table(table)
            self.rows += stop - start
            self._in_part += stop - start
            if self.partition_rows and self._in_part >= self.partition_rows:
                self._writer.close()
                self._writer = None
            start = stop

    def _writer_for_part(self) -> pq.ParquetWriter:
        if self._writer is None:
            if self.partition_rows:
                target = self.path / f"part-{self.parts:05d}.parquet"
            else:
                target = self.path
            self._writer = pq.ParquetWriter(str(target), self.schema)
            self.parts += 1
            self._in_part = 0
        return self._writer

    def close(self) -> int:
        self._flush(final=True)
        if self._writer is None and self.parts == 0:
            self._writer_for_part()       # an empty table still gets its schema on disk
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        return self.rows


def frames_schema(names: list[str], phys: dict[str, np.ndarray]) -> pa.Schema:
    fields = [("ts", pa.float64())]
    for n in names:
        v = phys[n]
        fields.append((n, pa.int64() if v.dtype.kind in "iu" else pa.float64()))
    return pa.schema(fields)
