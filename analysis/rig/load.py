"""Rig runs as users bring them: a rig run directory, a campaign directory of them, or a table.

A rig run (written by the gateway for a rig, ``gateway/runs.py``) is a run directory whose
``run.json`` has a ``rig`` section (``channels``: each with its ``name``) and whose
``signals.parquet`` has ``t`` and per channel ``u.<name>``, ``y.<name>``, ``r.<name>``. A table
(``.csv``, comma separated, one header line) with the same column names is read alike. A
campaign directory holds rig runs as its sub-directories (one experiment each: the per-column
meanders, or one simultaneous meander), read in name order.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Iterable

import numpy as np

from core.errors import DataError

from .record import RigRecord, make_rig_record

META_FILE = "run.json"


def rig_section(path: Path) -> dict | None:
    """The ``rig`` section of a run directory's ``run.json`` (None: not a rig run)."""
    meta = path / META_FILE
    if not (path.is_dir() and meta.exists()):
        return None
    try:
        data = json.loads(meta.read_text())
    except (OSError, ValueError):
        return None
    rig = data.get("rig") if isinstance(data, dict) else None
    return rig if isinstance(rig, dict) and rig.get("channels") else None


def _table_channels(path: Path) -> list[str] | None:
    """The channels a table's header names (``u.<name>`` and ``y.<name>``), None if it is not a
    rig table."""
    if path.suffix.lower() != ".csv" or not path.is_file():
        return None
    try:
        with path.open(newline="") as fh:
            header = next(csv.reader(fh), [])
    except (OSError, UnicodeDecodeError):
        return None
    header = [h.strip() for h in header]
    names = [h[2:] for h in header if h.startswith("u.")]
    if not names or "t" not in header or not all(f"y.{n}" in header for n in names):
        return None
    return names


def is_rig_input(path: str | Path) -> bool:
    """A rig run, a rig table, or a directory holding rig runs."""
    path = Path(path)
    if rig_section(path) is not None or _table_channels(path) is not None:
        return True
    return path.is_dir() and not (path / META_FILE).exists() and any(
        rig_section(p) is not None for p in path.iterdir() if p.is_dir())


def read_rig_run(path: str | Path) -> RigRecord:
    """One rig run directory as a :class:`RigRecord`."""
    from gateway.runs import load_run
    path = Path(path)
    rig = rig_section(path)
    if rig is None:
        raise DataError(f"{path} is not a rig run (its run.json has no 'rig' section with "
                        "channels); for one channel use it without the rig options")
    names = [str(c.get("name")) for c in rig["channels"]]
    run = load_run(path)
    sig = run.signals
    missing = [f"{c}.{n}" for n in names for c in ("u", "y") if f"{c}.{n}" not in sig]
    if missing or "t" not in sig:
        raise DataError(f"{path}: the rig run's signals lack {', '.join(missing or ['t'])}")
    u = np.vstack([sig[f"u.{n}"] for n in names])
    y = np.vstack([sig[f"y.{n}"] for n in names])
    r = np.vstack([sig.get(f"r.{n}", np.full(len(sig["t"]), np.nan)) for n in names])
    experiment = (run.meta.get("experiment") or {}).get("name")
    rec = make_rig_record(sig["t"], u, y, names, r, source=str(path), meta=run.meta,
                          experiment=experiment)
    rec.notes = list(run.notes) + rec.notes
    return rec


def read_rig_table(path: str | Path) -> RigRecord:
    """A comma-separated table ``t, u.<name>, y.<name>[, r.<name>], ...`` (s, %, kgf)."""
    path = Path(path)
    names = _table_channels(path)
    if names is None:
        raise DataError(f"{path}: not a rig table: a header with t and u.<name>, y.<name> per "
                        "channel is needed")
    with path.open(newline="") as fh:
        header = [h.strip() for h in next(csv.reader(fh))]
    try:
        data = np.genfromtxt(path, delimiter=",", skip_header=1, dtype=float, ndmin=2)
    except ValueError as exc:
        raise DataError(f"{path}: cannot read the table's numbers: {exc}") from None
    if data.shape[1] != len(header):
        raise DataError(f"{path}: rows have {data.shape[1]} fields, the header {len(header)}")
    col = {h: data[:, i] for i, h in enumerate(header)}
    nan = np.full(len(data), np.nan)
    return make_rig_record(col["t"], np.vstack([col[f"u.{n}"] for n in names]),
                           np.vstack([col[f"y.{n}"] for n in names]), names,
                           np.vstack([col.get(f"r.{n}", nan) for n in names]), source=str(path))


def load_rig_inputs(paths: Iterable[str | Path]) -> list[RigRecord]:
    """Every rig record the inputs hold (run directories, tables, campaign directories), their
    channels in the first one's order; :class:`DataError` if an input is none of these or the
    inputs are not of one rig."""
    out: list[RigRecord] = []
    for p in map(Path, paths):
        if not p.exists():
            raise DataError(f"{p} does not exist")
        if rig_section(p) is not None:
            out.append(read_rig_run(p))
        elif _table_channels(p) is not None:
            out.append(read_rig_table(p))
        elif p.is_dir() and not (p / META_FILE).exists():
            runs = sorted(q for q in p.iterdir() if q.is_dir() and rig_section(q) is not None)
            if not runs:
                raise DataError(f"{p} is a directory with no rig runs in it")
            out += [read_rig_run(q) for q in runs]
        else:
            raise DataError(f"{p} is not a rig run (a run directory whose run.json has a 'rig' "
                            "section, a table with t, u.<name>, y.<name> columns, or a "
                            "directory of such runs)")
    if not out:
        raise DataError("no input given")
    names = out[0].names
    for rec in out[1:]:
        if sorted(rec.names) != sorted(names):
            raise DataError(f"{rec.source} has channels {', '.join(rec.names)}, {out[0].source} "
                            f"{', '.join(names)}: give runs of one rig")
        if rec.names != names:
            order = [rec.names.index(n) for n in names]
            rec.channels = [rec.channels[i] for i in order]
            rec.names = list(names)
    return out
