"""Results kept for read-only arrays: a fit simulates the same pieces hundreds of times, and
most of its Jacobian's columns move one parameter that much of the work does not read (the
reversal's power law reads the flow command and its exponent, not g, Δ or the boost).

A :class:`Kept` store keeps what a function of some arrays and some values gave, by the arrays'
identities and the values, as long as every array is read-only (a fit's cached drives are:
:mod:`analysis.identification.windows`): an array that may still change (an emulator's block)
is never a key, its result is computed each time. The arrays are held with the result, so an
id stays its array's while it is a key. Results are returned read-only (one object for every
caller)."""
from __future__ import annotations

from collections import OrderedDict
from typing import Callable, Hashable

import numpy as np


def read_only(a: object) -> bool:
    """True for None and for a numpy array that cannot be written to."""
    return a is None or (isinstance(a, np.ndarray) and not a.flags.writeable)


class Kept:
    """The last ``size`` results of one computation, by read-only arrays and values."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._store: "OrderedDict[tuple, tuple]" = OrderedDict()

    def __len__(self) -> int:
        return len(self._store)

    def clear(self) -> None:
        self._store.clear()

    def get(self, arrays: tuple, values: Hashable, compute: Callable[[], object]) -> object:
        """``compute()``, or what it gave before for the same ``arrays`` (the same objects,
        each read-only or None) and equal ``values``."""
        if not all(read_only(a) for a in arrays):
            return compute()
        key = (tuple(id(a) for a in arrays), values)
        hit = self._store.get(key)
        if hit is not None and all(a is b for a, b in zip(hit[0], arrays)):
            self._store.move_to_end(key)
            return hit[1]
        out = compute()
        if isinstance(out, np.ndarray):
            out.flags.writeable = False
        self._store[key] = (arrays, out)
        if len(self._store) > self.size:
            self._store.popitem(last=False)
        return out
