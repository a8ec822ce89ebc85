"""A record: one uniformly sampled stretch of measurements (time, command, force, reference)
and where it came from, tidied on the way in (rows dropped, jitter resampled, glitches replaced,
holds at a hydraulic limit noted).

Everything downstream works on :class:`Record`. Several files given together form one data set
(a list of records, never concatenated across gaps: each keeps its own time base);
:func:`split_at_gaps` cuts a record whose samples went missing into records of their own.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gateway.errors import DataError

from .glitches import remove_glitches
from .limits import clipped_mask, clipped_note, held_stretches

#: relative spread of sample intervals above which a record is resampled to a uniform grid
JITTER_TOLERANCE = 0.05
#: an interval this many times the usual one is a gap in the data (samples missing), not jitter
GAP_INTERVALS = 5
#: the words of the note ``make_record`` leaves on a record whose gaps it bridged; the note
#: ``split_at_gaps`` takes off the parts it cuts there
BRIDGED_NOTE = "were bridged by resampling"


@dataclass
class Record:
    """One uniformly sampled record: time (s), command (%), force (kgf), reference (kgf or NaN)."""

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    r: np.ndarray
    source: str
    experiment: str | None = None          #: "meander" | "pfeedback" | "relay" | None (unknown)
    meta: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    #: samples that fall inside a gap of the data, filled in by resampling (None: no gap);
    #: :func:`split_at_gaps` cuts them out
    bridged: np.ndarray | None = None
    #: a force rate from outside the channel's own model that is known, kgf/s, one value per
    #: sample (None: none). A channel of a rig carries the other channels' coupling
    #: ``Σ_{j≠i} G_ij·w_j`` here (:mod:`analysis.rig.coupling`); the model's simulation adds it
    #: to the rate, as it adds its own disturbances (:mod:`analysis.identification.windows`)
    known_rate_kgf_s: np.ndarray | None = None

    @property
    def dt(self) -> float:
        return float((self.t[-1] - self.t[0]) / (len(self.t) - 1))

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])

    def __len__(self) -> int:
        return len(self.t)

    def has_reference(self) -> bool:
        return bool(np.isfinite(self.r).any())

    def slice(self, start: int, stop: int) -> "Record":
        return Record(self.t[start:stop], self.u[start:stop], self.y[start:stop],
                      self.r[start:stop], self.source, self.experiment, self.meta, list(self.notes),
                      None if self.bridged is None else self.bridged[start:stop],
                      None if self.known_rate_kgf_s is None else self.known_rate_kgf_s[start:stop])


def make_record(t, u, y, r=None, source: str = "<arrays>", experiment: str | None = None,
                meta: dict | None = None, min_samples: int = 20) -> Record:
    """Validate and tidy arrays into a :class:`Record`.

    Rejects (with :class:`DataError`) too few samples and time that starts again (goes back by
    more than a few samples: two runs in one file); drops rows with non-finite t, u or y
    (counted in ``notes``); sorts rows a few samples out of order and drops repeated times
    (noted); resamples to a uniform grid if the sampling jitters by more than 5 %; replaces
    glitches in the force (1-3 samples far off the trend, :mod:`analysis.records.glitches`);
    notes readings clipped at the dynamometer's range and holds at a hydraulic limit
    (:mod:`analysis.records.limits`)."""
    t = np.asarray(t, float)
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    r = np.full_like(t, np.nan) if r is None else np.asarray(r, float)
    notes: list[str] = []
    if not (len(t) == len(u) == len(y) == len(r)):
        raise DataError(f"{source}: columns have different lengths")
    good = np.isfinite(t) & np.isfinite(u) & np.isfinite(y)
    row = np.flatnonzero(good)          # the sample's place in what was given
    if not good.all():
        notes.append(f"dropped {int((~good).sum())} rows with missing or non-finite t, u or y")
        t, u, y, r = t[good], u[good], y[good], r[good]
    if len(t) < min_samples:
        raise DataError(f"{source}: only {len(t)} usable samples; need at least {min_samples}")
    dts = np.diff(t)
    if (dts <= 0).any():
        step = float(np.median(dts[dts > 0])) if (dts > 0).any() else 0.0
        back = np.flatnonzero(dts < -GAP_INTERVALS * step)
        if len(back):
            # not a few rows out of order: the time starts again (runs written one after the
            # other, a logger's clock reset); sorting would interleave them
            i = int(back[0])
            more = f", and {len(back) - 1} more time(s)" if len(back) > 1 else ""
            raise DataError(
                f"{source}: the time goes back from {t[i]:g} s to {t[i + 1]:g} s at sample "
                f"{row[i + 1] + 1} of {len(good)}{more}: two runs in one file, or a clock that "
                "was reset? Give each run a file of its own (several files are read as one data "
                "set, each on its own time), or cut this one there")
        order = np.argsort(t, kind="stable")
        t, u, y, r = t[order], u[order], y[order], r[order]
        keep = np.concatenate([[True], np.diff(t) > 0])
        notes.append(f"time was not increasing: sorted, dropped {int((~keep).sum())} duplicate times")
        t, u, y, r = t[keep], u[keep], y[keep], r[keep]
        dts = np.diff(t)
        if len(t) < min_samples:
            raise DataError(f"{source}: only {len(t)} samples with distinct times")
    med = float(np.median(dts))
    bridged = None
    if np.max(np.abs(dts - med)) > JITTER_TOLERANCE * med:
        gap = dts > GAP_INTERVALS * med
        n = int(round((t[-1] - t[0]) / med)) + 1
        grid = t[0] + med * np.arange(n)
        # the command is held (zero-order hold), the force interpolated
        idx = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 1)
        if gap.any():
            notes.append(f"{int(gap.sum())} gap(s) longer than {GAP_INTERVALS} sample intervals "
                         f"(samples missing) {BRIDGED_NOTE}")
            bridged = np.concatenate([gap, [False]])[idx] & (grid > t[idx])
        u = u[idx]
        r = r[idx]
        y = np.interp(grid, t, y)
        t = grid
        notes.append(f"sampling was irregular: resampled to a uniform {med * 1e3:.3g} ms grid")
    y, glitches = remove_glitches(y)
    if glitches.count:
        notes.append(glitches.note())
    clipped = clipped_mask(y)
    if clipped.any():
        notes.append(clipped_note(t, y, clipped))
    if len(t) > 1:
        for held in held_stretches(u, y, float(np.median(np.diff(t)))):
            notes.append(f"{held.describe()}: a hydraulic limit (relief valve, stroke end, pressure "
                         "limit), left out of the model's error")
    return Record(t, u, y, r, source, experiment, dict(meta or {}), notes, bridged)


def split_at_gaps(rec: Record, min_samples: int = 20) -> list[Record]:
    """The parts of ``rec`` between its gaps (samples missing, bridged by resampling), each a
    record of its own: a model run across a gap would integrate a command nobody recorded
    against a force that was only interpolated. Parts shorter than ``min_samples`` are dropped
    (said in the notes of the first part kept). A record without gaps comes back alone."""
    if rec.bridged is None or not rec.bridged.any():
        return [rec]
    z = np.concatenate([[1], rec.bridged.astype(int), [1]])
    edges = np.flatnonzero(np.diff(z))
    spans = list(zip(edges[::2].tolist(), edges[1::2].tolist()))
    kept = [(a, b) for a, b in spans if b - a >= min_samples]
    if not kept:
        raise DataError(f"{rec.source}: no stretch between its gaps (samples missing) has "
                        f"{min_samples} samples")
    parts = []
    for k, (a, b) in enumerate(kept):
        part = rec.slice(a, b)
        part.bridged = None
        part.source = f"{rec.source} [part {k + 1} of {len(kept)}, from {rec.t[a] - rec.t[0]:.3f} s]"
        part.notes = [n for n in part.notes if BRIDGED_NOTE not in n]
        if k == 0:
            part.notes.append(f"split at {len(spans) - 1} gap(s) in the data (samples missing) "
                              f"into {len(kept)} part(s), each a record of its own"
                              + (f"; {len(spans) - len(kept)} part(s) under {min_samples} samples dropped"
                                 if len(kept) < len(spans) else ""))
        parts.append(part)
    return parts

