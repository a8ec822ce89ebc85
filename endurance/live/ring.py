"""A bounded ring of rows: one thread puts, others read what came since they last looked.

The control loop is the putter: :meth:`SampleRing.put` stores a reference and counts, nothing
else (no lock, no allocation, never a wait); the oldest row is overwritten. A reader asks for
the rows since the count it last saw (:meth:`SampleRing.since`); one that fell further behind
than the ring holds gets the newest ``capacity - MARGIN`` rows (the margin: rows the putter may
overwrite while the reader copies). CPython's GIL makes the list store and the count's update
each atomic; the count is raised after the row is stored, so a reader never sees a row that is
not there yet.
"""
from __future__ import annotations

from typing import Any

#: rows a reader leaves to the putter while it copies (at 50 rows/s, seconds of a copy)
MARGIN = 64


class SampleRing:
    """The newest ``capacity`` rows (module docstring)."""

    def __init__(self, capacity: int) -> None:
        if capacity <= MARGIN:
            raise ValueError(f"capacity {capacity}: give more than {MARGIN} rows")
        self.capacity = int(capacity)
        self._rows: list[Any] = [None] * self.capacity
        #: rows put so far (the next row's sequence number)
        self.count = 0

    def put(self, row: Any) -> None:
        n = self.count
        self._rows[n % self.capacity] = row
        self.count = n + 1

    def since(self, seq: int) -> tuple[int, list[Any]]:
        """``(count, rows)``: the rows from sequence number ``seq`` on (the newest
        ``capacity - MARGIN`` of them at most), and the count to ask from next time."""
        end = self.count
        start = max(int(seq), end - (self.capacity - MARGIN), 0)
        rows = self._rows
        cap = self.capacity
        return end, [rows[i % cap] for i in range(start, end)]
