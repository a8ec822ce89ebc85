"""Reading and writing loading programmes (:mod:`loading.programme`).

One channel's programme (:func:`load_channel_programme`) is

* a turning-point CSV with one column ``level`` (kgf), haversines between the points at
  ``--rate`` (kgf/s peak) or ``--frequency`` (Hz);
* a time history CSV ``t,r`` (s, kgf);
* ``sine:mean=3000,amplitude=2000,frequency=0.2,cycles=20``;
* a block programme: a TOML file of ``[[block]]`` tables with ``mean``, ``amplitude``,
  ``frequency`` and ``cycles``.

A station's programme (:func:`load_programme`, for the station's channels) is one of those for a
one-channel stand, or

* **load cases**: a CSV with one column per channel (named as the rig names its channels) and
  an optional first column ``case`` (a label); a row is a load case, every channel's turning
  point at the same moment, the segment's duration set by the channel that moves the most at
  the rate (or a half cycle at the frequency);
* **per-channel sequences**: a TOML file with a ``[channel.NAME]`` table per channel, each with
  ``programme`` (any one-channel programme: a file relative to the TOML file, or ``sine:...``)
  and optionally its own ``rate`` or ``frequency``; the channels run on the common clock, a
  shorter one holding its last level; with several channels there are no load cases.

A CSV may be ``,``, ``;`` or tab separated, with ``#`` comments, and with ``;`` a decimal comma;
a Windows-1251 file is read too. Everything is checked on reading; a mistake is one error naming
the file, the line and the column.
"""
from __future__ import annotations

import csv
import math
import re
from pathlib import Path
from typing import Sequence

import numpy as np

from core.errors import DataError, ParameterError

from .programme import (ChannelProgramme, Programme, blocks, from_channel_programmes, from_history,
                        from_levels, from_load_cases, sine)

#: the optional label column of a load-case CSV
CASE_COLUMN = "case"

# -- one channel -----------------------------------------------------------------------------------
_SINE = re.compile(r"^sine:(.*)$", re.I)


def load_channel_programme(spec: str, period_s: float, rate_kgf_s: float | None = None,
                           frequency_hz: float | None = None) -> ChannelProgramme:
    """One channel's programme from a file or a spec (see the module docstring for the forms).

    Raises :class:`~core.errors.DataError` / :class:`~core.errors.ParameterError` with the file,
    the line and what to write when the programme cannot be read."""
    m = _SINE.match(spec.strip())
    if m:
        fields = _keyvalues(m.group(1), spec)
        need = ("mean", "amplitude", "frequency", "cycles")
        missing = [k for k in need if k not in fields]
        extra = sorted(set(fields) - set(need))
        if missing or extra:
            raise ParameterError(f"{spec!r}: write sine:mean=KGF,amplitude=KGF,frequency=HZ,cycles=N"
                                 + (f" (missing {', '.join(missing)})" if missing else "")
                                 + (f" (unknown {', '.join(extra)})" if extra else ""))
        return sine(fields["mean"], fields["amplitude"], fields["frequency"], fields["cycles"], period_s)
    path = Path(spec)
    if not path.is_file():
        raise DataError(f"programme {spec!r}: no such file; give a turning-point CSV (column "
                        "'level'), a time history CSV (columns 't,r'), a block programme (.toml) or "
                        "sine:mean=...,amplitude=...,frequency=...,cycles=...")
    if path.suffix.lower() == ".toml":
        from plant.config import read_toml
        data = read_toml(path)
        table = data.get("block")
        if not isinstance(table, list):
            raise DataError(f"{path}: a block programme is a list of [[block]] tables with mean, "
                            "amplitude, frequency and cycles")
        return blocks(table, period_s, source=f"blocks {path.name}")
    header, rows = _read_rows(path)
    if header == ["level"] or (header is None and rows and len(rows[0][1]) == 1):
        levels = [v[0] for _, v in rows]
        if rate_kgf_s is None and frequency_hz is None:
            raise ParameterError(f"{path}: a turning-point sequence needs --rate KGF_PER_S (the "
                                 "haversines' peak rate) or --frequency HZ")
        return from_levels(levels, period_s, rate_kgf_s, frequency_hz, source=f"sequence {path.name}")
    if header in (["t", "r"], None) and rows and len(rows[0][1]) == 2:
        a = np.array([v for _, v in rows], float)
        return from_history(a[:, 0], a[:, 1], period_s, source=f"history {path.name}")
    raise DataError(f"{path}: the header {','.join(header or [])!r} is neither 'level' (a turning-"
                    "point sequence) nor 't,r' (a time history in s, kgf)")


def is_sequence(spec: str) -> bool:
    """True if ``spec`` names a turning-point sequence (a CSV of levels), whose segments take
    their time from a rate or a frequency (the other forms carry their own)."""
    path = Path(spec)
    if _SINE.match(spec.strip()) or not path.is_file() or path.suffix.lower() == ".toml":
        return False
    header, rows = _read_rows(path)
    return header == ["level"] or (header is None and bool(rows) and len(rows[0][1]) == 1)


def _keyvalues(text: str, spec: str) -> dict[str, float]:
    out = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, sep, value = part.partition("=")
        try:
            if not sep:
                raise ValueError
            out[key.strip().lower()] = float(value)
        except ValueError:
            raise ParameterError(f"{spec!r}: {part!r} is not key=number") from None
    return out


def _read_rows(path: Path) -> tuple[list[str] | None, list[tuple[int, list[float]]]]:
    """A small CSV: an optional header, '#' comments, ',' ';' or tab separated, a decimal comma
    with ';'. Rows as (line number, values)."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        text = path.read_text(encoding="cp1251")
    except OSError as exc:
        raise DataError(f"cannot read {path}: {exc}") from None
    lines = [(i, ln.strip()) for i, ln in enumerate(text.splitlines(), start=1)
             if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise DataError(f"{path}: empty programme")
    delim = ";" if ";" in lines[0][1] else "\t" if "\t" in lines[0][1] else ","
    decimal_comma = delim != ","
    header = None
    first = [c.strip().lower() for c in next(csv.reader([lines[0][1]], delimiter=delim))]
    if not all(_is_number(c, decimal_comma) for c in first if c):
        header = [re.sub(r"\s*[\[(].*$", "", c) for c in first if c]
        lines = lines[1:]
    rows = []
    for lineno, ln in lines:
        cells = [c.strip() for c in next(csv.reader([ln], delimiter=delim)) if c.strip()]
        try:
            rows.append((lineno, [_number(c, decimal_comma) for c in cells]))
        except ValueError as exc:
            raise DataError(f"{path}:{lineno}: {exc}") from None
        if header and len(cells) != len(header):
            raise DataError(f"{path}:{lineno}: {len(cells)} values for the {len(header)} columns "
                            f"{','.join(header)}")
    if not rows:
        raise DataError(f"{path}: empty programme (a header and no values)")
    return header, rows


def _is_number(text: str, decimal_comma: bool) -> bool:
    try:
        _number(text, decimal_comma)
        return True
    except ValueError:
        return False


def _number(text: str, decimal_comma: bool) -> float:
    try:
        v = float(text.replace(",", ".") if decimal_comma else text)
    except ValueError:
        raise ValueError(f"{text!r} is not a number") from None
    if not math.isfinite(v):
        raise ValueError(f"{text!r} is not a finite number")
    return v


# -- a station --------------------------------------------------------------------------------------
def load_programme(spec: str, names: Sequence[str], period_s: float, rate_kgf_s: float | None = None,
                   frequency_hz: float | None = None) -> Programme:
    """The programme of a station whose channels are ``names`` (in its order) from a file or a
    spec (module docstring): for one channel any one-channel form, or a load-case CSV (its
    columns in any order, naming every channel and no other) or a per-channel TOML."""
    names = list(names)
    path = Path(spec)
    if len(names) == 1 and not _names_channels(path, names):
        return Programme.of(load_channel_programme(spec, period_s, rate_kgf_s, frequency_hz), names[0])
    if not path.is_file():
        raise DataError(f"programme {spec!r}: no such file; a rig's programme is a load-case CSV "
                        f"(a column per channel: {','.join(names)}) or a TOML of [channel.NAME] "
                        "tables with a programme each")
    if path.suffix.lower() == ".toml":
        return _per_channel(path, names, period_s, rate_kgf_s, frequency_hz)
    header, rows = _read_rows(path)
    if header is None:
        raise DataError(f"{path}: a load-case CSV needs a header naming the channels, e.g. "
                        f"{CASE_COLUMN},{','.join(names)}")
    # the header is read in lower case: channels are matched regardless of case; one channel's
    # column may be called level, as a one-channel turning-point CSV's
    by_lower = {n.lower(): n for n in names} | ({"level": names[0]} if len(names) == 1 else {})
    columns = [by_lower.get(c, c) for c in header]
    label_col = columns.index(CASE_COLUMN) if CASE_COLUMN in columns else None
    named = [c for c in columns if c != CASE_COLUMN]
    unknown = [c for c in named if c not in names]
    if unknown:
        raise DataError(f"{path}: column {unknown[0]!r} is not a channel of the rig (it has "
                        f"{', '.join(names)})")
    twice = sorted({c for c in named if named.count(c) > 1})
    if twice:
        raise DataError(f"{path}: column {twice[0]!r} appears twice")
    missing = [n for n in names if n not in named]
    if missing:
        raise DataError(f"{path}: no column for channel(s) {', '.join(missing)}; a load case gives "
                        "every channel's level (repeat a level to hold it)")
    values = np.array([v for _, v in rows], float)
    levels = np.array([values[:, columns.index(n)] for n in names])
    labels = ([_fmt(v) for v in values[:, label_col]] if label_col is not None
              else [str(k + 1) for k in range(len(rows))])
    if rate_kgf_s is None and frequency_hz is None:
        raise ParameterError(f"{path}: load cases need --rate KGF_PER_S (the peak rate of the "
                             "channel that moves the most between two cases) or --frequency HZ")
    return from_load_cases(levels, names, period_s, rate_kgf_s, frequency_hz,
                           source=f"load cases {path.name}", labels=labels)


def _per_channel(path: Path, names: list[str], period_s: float, rate_kgf_s: float | None,
                 frequency_hz: float | None) -> Programme:
    from plant.config import read_toml
    from plant.params import ModelError
    try:
        data = read_toml(path)
    except ModelError as exc:
        raise DataError(str(exc)) from None
    tables = data.get("channel")
    if not isinstance(tables, dict) or not tables:
        raise DataError(f"{path}: a per-channel programme has a [channel.NAME] table per channel "
                        "with programme = \"FILE.csv\" (or sine:...)")
    unknown = [n for n in tables if n not in names]
    if unknown:
        raise DataError(f"{path}: [channel.{unknown[0]}] is not a channel of the rig (it has "
                        f"{', '.join(names)})")
    missing = [n for n in names if n not in tables]
    if missing:
        raise DataError(f"{path}: no [channel.{missing[0]}] table; give every channel a programme")
    programmes = []
    for n in names:
        table = tables[n]
        where = f"{path}: [channel.{n}]"
        if not isinstance(table, dict) or "programme" not in table:
            raise DataError(f"{where} needs programme = \"FILE.csv\" (or sine:...)")
        extra = set(table) - {"programme", "rate", "frequency"}
        if extra:
            raise DataError(f"{where}: unknown key(s) {', '.join(sorted(extra))}; it takes "
                            "programme, rate, frequency")
        spec = str(table["programme"])
        if not spec.lower().startswith("sine:") and not Path(spec).is_absolute():
            spec = str(path.parent / spec)
        rate = table.get("rate", rate_kgf_s if "frequency" not in table else None)
        freq = table.get("frequency", frequency_hz if "rate" not in table else None)
        try:
            seq = is_sequence(spec)
            programmes.append(load_channel_programme(spec, period_s, rate if seq else None,
                                                     freq if seq else None))
        except (DataError, ParameterError) as exc:
            raise type(exc)(f"{where}: {exc}") from None
    return from_channel_programmes(programmes, names, source=f"per-channel {path.name}")


def _names_channels(path: Path, names: list[str]) -> bool:
    """True when ``path`` is a station's file (a per-channel TOML, or a CSV whose header has
    ``case`` or names a channel) rather than one channel's programme."""
    if not path.is_file():
        return False
    if path.suffix.lower() == ".toml":
        from plant.config import read_toml
        from plant.params import ModelError
        try:
            return isinstance(read_toml(path).get("channel"), dict)
        except ModelError:
            return False
    header, _ = _read_rows(path)
    return header is not None and CASE_COLUMN in header or bool(header and {n.lower() for n in names} & set(header))


def needs_rate(spec: str) -> bool:
    """True if ``spec`` takes its segments' times from a rate or a frequency: a turning-point
    CSV or a load-case CSV (a time history, a sine and a TOML carry their own)."""
    path = Path(spec)
    if _SINE.match(spec.strip()) or not path.is_file() or path.suffix.lower() == ".toml":
        return False
    header, rows = _read_rows(path)
    history = header == ["t", "r"] or (header is None and bool(rows) and len(rows[0][1]) == 2)
    return not history


def write_load_cases(path: str | Path, levels_kgf: np.ndarray, names: Sequence[str]) -> Path:
    """A load-case CSV (``case`` and a column per channel) for ``levels_kgf`` (N × M)."""
    path = Path(path)
    lines = [",".join([CASE_COLUMN, *names])]
    for k, col in enumerate(np.asarray(levels_kgf, float).T, start=1):
        lines.append(",".join([str(k), *(f"{v:.1f}" for v in col)]))
    path.write_text("\n".join(lines) + "\n")
    return path


def _fmt(v: float) -> str:
    return str(int(v)) if float(v).is_integer() else f"{v:g}"
