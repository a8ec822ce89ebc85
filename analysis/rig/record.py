"""A rig record: the channels of one rig run on one time base (one SYNC per cycle for all).

Channel i's command ``u_i`` (%), force ``y_i`` (kgf) and reference ``r_i`` (kgf or NaN) are a
one-channel :class:`~analysis.records.record.Record` each, tidied as any record is (glitches
replaced, clipping and hydraulic limits noted), all of the same length and time. The rig's
analysis reads them side by side (:attr:`RigRecord.u` is ``(N, K)``), the one-channel analysis one
at a time (:meth:`RigRecord.channel`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from core.errors import DataError

from ..records.record import Record, make_record


@dataclass
class RigRecord:
    """N channels recorded together: ``names[i]`` is ``channels[i]``'s, all on one time base."""

    names: list[str]
    channels: list[Record]
    source: str
    meta: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def n(self) -> int:
        return len(self.names)

    @property
    def t(self) -> np.ndarray:
        return self.channels[0].t

    @property
    def dt(self) -> float:
        return self.channels[0].dt

    def __len__(self) -> int:
        return len(self.channels[0])

    @property
    def u(self) -> np.ndarray:
        """Commands, (N, K), %."""
        return np.vstack([c.u for c in self.channels])

    @property
    def y(self) -> np.ndarray:
        """Forces, (N, K), kgf."""
        return np.vstack([c.y for c in self.channels])

    @property
    def r(self) -> np.ndarray:
        """References, (N, K), kgf (NaN: open loop)."""
        return np.vstack([c.r for c in self.channels])

    def index(self, name: str) -> int:
        """The row of channel ``name``; :class:`DataError` naming the channels if there is none."""
        if name not in self.names:
            raise DataError(f"{self.source}: no channel {name!r}; its channels: "
                            f"{', '.join(self.names)}")
        return self.names.index(name)

    def channel(self, name: str) -> Record:
        """Channel ``name`` as a one-channel record."""
        return self.channels[self.index(name)]


def make_rig_record(t, u, y, names: Sequence[str], r=None, source: str = "<arrays>",
                    meta: dict | None = None, experiment: str | None = None) -> RigRecord:
    """Validate and tidy arrays into a :class:`RigRecord`: ``t`` (K,), ``u``, ``y`` and
    optionally ``r`` (N, K). A row where any channel's t, u or y is missing is dropped for all
    channels (they share the cycle); each channel is then tidied by
    :func:`~analysis.records.record.make_record`."""
    names = [str(n) for n in names]
    t = np.asarray(t, float)
    u = np.atleast_2d(np.asarray(u, float))
    y = np.atleast_2d(np.asarray(y, float))
    n = len(names)
    if n == 0:
        raise DataError(f"{source}: a rig record needs at least one channel")
    dupes = sorted({x for x in names if names.count(x) > 1})
    if dupes:
        raise DataError(f"{source}: channel name(s) {', '.join(dupes)} given twice")
    r = np.full_like(u, np.nan) if r is None else np.atleast_2d(np.asarray(r, float))
    for what, a in (("commands u", u), ("forces y", y), ("references r", r)):
        if a.shape != (n, len(t)):
            raise DataError(f"{source}: {what} have shape {a.shape}, expected ({n}, {len(t)}): "
                            "one row per channel, one column per sample")
    good = np.isfinite(t) & np.all(np.isfinite(u), axis=0) & np.all(np.isfinite(y), axis=0)
    notes = []
    if not good.all():
        notes.append(f"dropped {int((~good).sum())} rows where a channel's t, u or y was missing")
        t, u, y, r = t[good], u[:, good], y[:, good], r[:, good]
    channels = [make_record(t, u[i], y[i], r[i], source=f"{source} [{names[i]}]",
                            experiment=experiment, meta=meta) for i in range(n)]
    lengths = {len(c) for c in channels}
    if len(lengths) != 1 or not all(np.array_equal(c.t, channels[0].t) for c in channels):
        raise DataError(f"{source}: the channels ended on different time bases after tidying "
                        "(rows sorted or resampled differently): give every channel the same "
                        "time column")
    return RigRecord(names, channels, source, dict(meta or {}), notes)
