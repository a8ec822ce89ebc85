"""One entry for every input a user brings: a recorded run directory, a table of samples or a
bus capture (decoded with the stand's DBC), each made a :class:`~analysis.records.record.Record`;
several inputs form one data set, each split at its gaps.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterable

from gateway.errors import DataError
from gateway.runs import is_run_dir, load_run

from .record import Record, make_record, split_at_gaps
from .tables import TABLE_SUFFIXES, open_path, read_csv, type_suffix


def read_run(path: str | Path, channel: str | None = None) -> Record:
    """A run directory as a record; a rig run needs ``channel`` (one of its channels)."""
    run = load_run(path)
    if channel is None and run.channels:
        rig = run.meta["rig"]
        raise DataError(f"{path} is a run of the rig {rig.get('name')!r} with {len(run.channels)} "
                        f"channels: choose one with --channel NAME (channels: "
                        f"{', '.join(run.channels)}; the experiment drove "
                        f"{', '.join(rig.get('driven') or []) or 'none'})")
    if channel is not None:
        run = run.channel(channel)
    if len(run) == 0:
        raise DataError(f"{path}: the run has no samples")
    source = str(path) if channel is None else f"{path}#{channel}"
    rec = make_record(run.t, run.u, run.y, run.r, source=source, experiment=run.experiment,
                      meta=run.meta)
    rec.notes = run.notes + rec.notes
    return rec


def _is_capture(path: Path) -> bool:
    """A bus capture by its suffixes (``.log``, ``.blf``, ``.asc.gz``, ...); a ``.csv`` is a
    capture only if its header is python-can's (``timestamp,arbitration_id,...``)."""
    suffix = type_suffix(path)
    if not suffix:
        return False
    if suffix == ".csv":
        try:
            with open_path(path, "rt", errors="replace") as fh:
                header = fh.readline().lower()
        except OSError:
            return False
        return "arbitration_id" in header
    try:
        from captures import SUFFIXES
    except ImportError:  # pragma: no cover - captures ships with the project
        return False
    return suffix in SUFFIXES


def load_capture(path: str | Path, strict: bool = False, **options) -> Record:
    """A bus capture as a record (t, u, y, r = NaN), decoded with the stand's DBC
    (:func:`captures.decode.capture_run`). A capture holding several runs needs ``run=i``. A
    damaged capture gives what was decoded before the damage, with a note naming the position
    (``strict=True``: raise :class:`captures.CaptureDamaged` instead)."""
    from captures.decode import capture_run
    sig, meta, notes = capture_run(path, strict=strict, **options)
    rec = make_record(sig["t"], sig["u"], sig["y"], sig["r"], source=str(path), experiment=None,
                      meta=meta)
    rec.notes = notes + rec.notes
    return rec


def load(path: str | Path, channel: str | None = None) -> Record:
    """Load one input: run directory, CSV ``t,u,y[,r]``, or a bus capture (decoded with the DBC).
    ``channel``: the channel of a rig run to read (a rig run needs it; other inputs refuse it)."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path} does not exist")
    if path.is_dir():
        if is_run_dir(path):
            return read_run(path, channel)
        raise DataError(f"{path} is a directory but not a run (no run.json)")
    if channel is not None:
        raise DataError(f"--channel {channel}: {path} is not a rig run; --channel names a channel "
                        "of a rig run directory (decode a rig's capture per channel with "
                        "`stand decode RIG_RUN --channel NAME`)")
    if _is_capture(path):
        return load_capture(path)
    if type_suffix(path) in TABLE_SUFFIXES:
        return read_csv(path)
    raise DataError(f"{path}: unknown input type; give a table of samples (.csv, .tsv, .txt, .dat: "
                    "t,u,y[,r]), a run directory or a bus capture (.log, .asc, .blf, .trc, .mf4); "
                    "each optionally .gz")


def load_all(paths: Iterable[str | Path], channel: str | None = None) -> list[Record]:
    """Load every input as :func:`load` does, each split at its gaps (:func:`split_at_gaps`);
    ``channel``: the channel of every rig run among them."""
    records = [part for p in paths for part in split_at_gaps(load(p, channel))]
    if not records:
        raise DataError("no input given")
    return records
