"""Measurements in, whatever their source: a CSV ``t,u,y[,r]`` (s, %, kgf), a recorded run
directory, or a bus capture (decoded with the stand's DBC).

Everything downstream works on :class:`Record`: uniformly sampled arrays plus where they came
from. Several files given together form one data set (a list of records, never concatenated
across gaps: each keeps its own time base).
"""
from __future__ import annotations

import csv
import gzip
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from gateway.errors import DataError
from gateway.runs import is_run_dir, load_run

from .glitches import remove_glitches

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
                      None if self.bridged is None else self.bridged[start:stop])


def make_record(t, u, y, r=None, source: str = "<arrays>", experiment: str | None = None,
                meta: dict | None = None, min_samples: int = 20) -> Record:
    """Validate and tidy arrays into a :class:`Record`.

    Rejects (with :class:`DataError`) too few samples, non-finite time, time that does not
    increase; drops rows with non-finite u or y (counted in ``notes``); resamples to a uniform
    grid if the sampling jitters by more than 5 %; replaces glitches in the force (1-3 samples
    far off the trend, :mod:`analysis.glitches`), noted too."""
    t = np.asarray(t, float)
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    r = np.full_like(t, np.nan) if r is None else np.asarray(r, float)
    notes: list[str] = []
    if not (len(t) == len(u) == len(y) == len(r)):
        raise DataError(f"{source}: columns have different lengths")
    good = np.isfinite(t) & np.isfinite(u) & np.isfinite(y)
    if not good.all():
        notes.append(f"dropped {int((~good).sum())} rows with missing or non-finite t, u or y")
        t, u, y, r = t[good], u[good], y[good], r[good]
    if len(t) < min_samples:
        raise DataError(f"{source}: only {len(t)} usable samples; need at least {min_samples}")
    dts = np.diff(t)
    if (dts <= 0).any():
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


def read_csv(path: str | Path) -> Record:
    """CSV with a header naming at least ``t``, ``u``, ``y`` (optionally ``r``); s, %, kgf.

    Read with pyarrow's multi-threaded CSV reader (an hour at 500 Hz in well under a second);
    a file it refuses is read again line by line, so the error names the line and the value."""
    path = Path(path)
    header = _csv_header(path)
    names = [h.strip().lower() for h in header]
    missing = [c for c in ("t", "u", "y") if c not in names]
    if missing:
        raise DataError(f"{path}: the header must name columns t,u,y[,r] (s, %, kgf); "
                        f"missing {', '.join(missing)} (header: {','.join(header)})")
    wanted = {c: header[names.index(c)] for c in ("t", "u", "y", "r") if c in names}
    try:
        import pyarrow as pa
        import pyarrow.csv as pacsv
        table = pacsv.read_csv(
            path, read_options=pacsv.ReadOptions(column_names=[h for h in header], skip_rows=1),
            convert_options=pacsv.ConvertOptions(
                include_columns=list(wanted.values()),
                column_types={name: pa.float64() for name in wanted.values()},
                null_values=["", "nan", "NaN", "NAN", "na", "NA", "null", "NULL"],
                strings_can_be_null=True))
    except Exception:   # pyarrow refused it: the line reader says exactly where and why
        return _read_csv_lines(path, header)
    if table.num_rows == 0:
        raise DataError(f"{path}: no data rows after the header")
    cols = {c: table.column(name).to_numpy(zero_copy_only=False).astype(float)
            for c, name in wanted.items()}
    return make_record(cols["t"], cols["u"], cols["y"], cols.get("r"), source=str(path))


def _csv_header(path: Path) -> list[str]:
    try:
        with (gzip.open(path, "rt", newline="") if path.suffix.lower() == ".gz"
              else path.open(newline="")) as fh:
            header = next(csv.reader(fh), None)
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"cannot read {path}: {exc}") from None
    if header is None:
        raise DataError(f"{path}: empty file")
    return header


def _read_csv_lines(path: Path, header: list[str]) -> Record:
    names = [h.strip().lower() for h in header]
    cols = {c: names.index(c) for c in ("t", "u", "y", "r") if c in names}
    rows = []
    try:
        with (gzip.open(path, "rt", newline="") if path.suffix.lower() == ".gz"
              else path.open(newline="")) as fh:
            reader = csv.reader(fh)
            next(reader, None)
            for lineno, row in enumerate(reader, start=2):
                if not row or all(not c.strip() for c in row):
                    continue
                try:
                    rows.append([_num(row[cols[c]]) if cols[c] < len(row) else math.nan
                                 for c in ("t", "u", "y")] +
                                [(_num(row[cols["r"]]) if cols["r"] < len(row) else math.nan)
                                 if "r" in cols else math.nan])
                except ValueError as exc:
                    raise DataError(f"{path}:{lineno}: {exc}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"cannot read {path}: {exc}") from None
    if not rows:
        raise DataError(f"{path}: no data rows after the header")
    a = np.array(rows, float)
    return make_record(a[:, 0], a[:, 1], a[:, 2], a[:, 3], source=str(path))


def _num(text: str) -> float:
    text = text.strip()
    if text == "" or text.lower() in ("nan", "na", "null"):
        return math.nan
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"{text!r} is not a number") from None


def write_csv(record: Record, path: str | Path) -> None:
    with Path(path).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t", "u", "y", "r"])
        for row in zip(record.t, record.u, record.y, record.r):
            w.writerow([repr(float(v)) for v in row])


def read_run(path: str | Path) -> Record:
    run = load_run(path)
    if len(run) == 0:
        raise DataError(f"{path}: the run has no samples")
    rec = make_record(run.t, run.u, run.y, run.r, source=str(path), experiment=run.experiment,
                      meta=run.meta)
    rec.notes = run.notes + rec.notes
    return rec


def _is_capture(path: Path) -> bool:
    """A bus capture by its suffixes (``.log``, ``.blf``, ``.asc.gz``, ...); a ``.csv`` is a
    capture only if its header is python-can's (``timestamp,arbitration_id,...``)."""
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    if not suffixes:
        return False
    if suffixes[-1] == ".csv":
        try:
            with (gzip.open(path, "rt") if path.suffix.lower() == ".gz" else path.open()) as fh:
                header = fh.readline().lower()
        except OSError:
            return False
        return "arbitration_id" in header
    try:
        from captures import SUFFIXES
    except ImportError:  # pragma: no cover - captures ships with the project
        return False
    return suffixes[-1] in SUFFIXES


def load(path: str | Path) -> Record:
    """Load one input: run directory, CSV ``t,u,y[,r]``, or a bus capture (decoded with the DBC)."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path} does not exist")
    if path.is_dir():
        if is_run_dir(path):
            return read_run(path)
        raise DataError(f"{path} is a directory but not a run (no run.json)")
    if _is_capture(path):
        from captures import load_capture
        return load_capture(path)
    if path.suffix.lower() == ".csv":
        return read_csv(path)
    raise DataError(f"{path}: unknown input type; give a CSV (t,u,y[,r]), a run directory or a "
                    "bus capture (.log, .asc, .blf, .trc, .mf4, optionally .gz)")


def load_all(paths: Iterable[str | Path]) -> list[Record]:
    """Load every input as :func:`load` does, each split at its gaps (:func:`split_at_gaps`)."""
    records = [part for p in paths for part in split_at_gaps(load(p))]
    if not records:
        raise DataError("no input given")
    return records
