r"""Multi-channel loading programmes: what force every channel of a rig must see, on one clock.

Two forms, read by :func:`load_rig_programme`:

* **load cases**: a CSV with one column per channel (named as the rig names its channels) and
  an optional first column ``case`` (a label, e.g. the case's number); a row is a load case,
  every channel's turning point at the same moment. Between two load cases every channel moves
  along a haversine of one common duration, set by the channel that moves the most:

  .. math::  T_k = \max_i \frac{\pi\,|L_{i,k+1} - L_{i,k}|}{2\,R},

  (``R`` the ``--rate``, the fastest channel's peak rate in kgf/s), or ``T_k = 1/(2f)`` with a
  frequency. So every channel arrives at the next load case together and the load case's ratios
  between the channels hold at its turning point (the tracking report measures how well). A
  channel may keep its level from one case to the next (it holds while the others move);
* **per-channel sequences**: a TOML file with a ``[channel.NAME]`` table per channel, each with
  ``programme`` (any one-channel programme: a turning-point CSV relative to the TOML file, a
  ``t,r`` history, ``sine:...``, a block programme) and optionally its own ``rate`` or
  ``frequency`` (kgf/s, Hz; default: the command line's). The channels run their own turning
  points on the common clock; a shorter one holds its last level until the longest ends. There
  are no load cases, so no ratios.

Every form becomes a :class:`RigProgramme`: one :class:`~loading.programme.Programme` per channel
on the same time grid (``channels[i].t_s`` are equal), and for load cases the shared turning
points. Everything is checked on reading; a mistake is one error naming the file, the line and
the column.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from core.errors import DataError, ParameterError

from .programme import Programme, _check_period, _haversine, _read_rows, check_programme, load_programme

#: the optional label column of a load-case CSV
CASE_COLUMN = "case"


@dataclass(frozen=True)
class RigProgramme:
    """A programme for every channel of a rig on one time grid.

    Attributes
    ----------
    names : the channels, in the rig's order
    channels : one programme per channel, all with the same ``t_s``
    load_cases : True when a turning point is a load case of every channel (the same
        ``turning_idx`` for all): the ratios between channels at each is part of the report
    source : what it was made from, for reports
    case_labels : a label per load case (the CSV's ``case`` column, or 1, 2, ...)
    """

    names: list[str]
    channels: list[Programme]
    load_cases: bool
    source: str
    case_labels: list[str] | None = None

    def __post_init__(self) -> None:
        if len(self.names) != len(self.channels) or not self.channels:
            raise ParameterError(f"{len(self.names)} names for {len(self.channels)} programmes")
        n = len(self.channels[0].t_s)
        if any(len(p.t_s) != n for p in self.channels):
            raise ParameterError("every channel's programme must have the same time grid")

    @property
    def n(self) -> int:
        return len(self.channels)

    @property
    def period_s(self) -> float:
        return self.channels[0].period_s

    @property
    def t_s(self) -> np.ndarray:
        return self.channels[0].t_s

    @property
    def duration_s(self) -> float:
        return self.channels[0].duration_s

    @property
    def r_kgf(self) -> np.ndarray:
        """(N, K): every channel's reference."""
        return np.array([p.r_kgf for p in self.channels])

    @property
    def turning_idx(self) -> np.ndarray:
        """The load cases' samples (load cases only)."""
        self._load_cases_only()
        return self.channels[0].turning_idx

    @property
    def levels_kgf(self) -> np.ndarray:
        """(N, M): every channel's level at each load case (load cases only)."""
        return np.array([p.r_kgf[self.turning_idx] for p in self.channels])

    @property
    def ranges_kgf(self) -> np.ndarray:
        return np.array([p.range_kgf for p in self.channels])

    def _load_cases_only(self) -> None:
        if not self.load_cases:
            raise ParameterError(f"{self.source}: per-channel sequences have no load cases")

    @property
    def segment_durations_s(self) -> np.ndarray:
        """How long each segment between two load cases lasts (s; load cases only)."""
        self._load_cases_only()
        return self.channels[0].segment_durations_s

    def with_durations(self, durations_s, source: str | None = None) -> "RigProgramme":
        """The same load cases with each segment lasting ``durations_s`` (s, one per segment;
        :meth:`Programme.with_durations` on every channel, so they stay on one grid): time
        scaling."""
        self._load_cases_only()
        label = source or self.source
        return RigProgramme(self.names, [p.with_durations(durations_s, label) for p in self.channels],
                            True, label, self.case_labels)

    def channel(self, name: str) -> Programme:
        try:
            return self.channels[self.names.index(name)]
        except ValueError:
            raise ParameterError(f"{self.source}: no channel {name!r}; it has "
                                 f"{', '.join(self.names)}") from None

    def with_levels(self, levels: Sequence[np.ndarray]) -> "RigProgramme":
        """Each channel's turning points moved to ``levels[i]`` (peak/valley compensation,
        :meth:`Programme.with_levels`); the times are kept, so load cases stay load cases."""
        return RigProgramme(self.names, [p.with_levels(lv) for p, lv in zip(self.channels, levels)],
                            self.load_cases, self.source, self.case_labels)

    def check(self, force_limits_kgf: Sequence[float]) -> None:
        """Refuse a level at or beyond a channel's force limit (naming the channel)."""
        for name, p, limit in zip(self.names, self.channels, force_limits_kgf):
            try:
                check_programme(p, limit)
            except ParameterError as exc:
                raise ParameterError(f"channel {name}: {exc}") from None


# -- making rig programmes --------------------------------------------------------------------------
def from_load_cases(levels_kgf, names: Sequence[str], period_s: float,
                    rate_kgf_s: float | None = None, frequency_hz: float | None = None,
                    source: str = "load cases", labels: Sequence[str] | None = None) -> RigProgramme:
    """Load cases ``levels_kgf`` (N channels × M cases): haversines of a common duration per
    segment, the channel that moves the most at ``rate_kgf_s`` (module docstring), or one half
    cycle at ``frequency_hz``."""
    L = np.asarray(levels_kgf, float)
    names = list(names)
    _check_period(period_s)
    if L.ndim != 2 or L.shape[0] != len(names):
        raise DataError(f"{source}: {len(names)} channels expected, got levels of shape {L.shape}")
    if L.shape[1] < 2:
        raise DataError(f"{source}: a programme needs at least 2 load cases, got {L.shape[1]}")
    if not np.isfinite(L).all():
        raise DataError(f"{source}: a level is not a finite number")
    span = np.max(np.abs(np.diff(L, axis=1)), axis=0)
    still = np.flatnonzero(span == 0)
    if len(still):
        k = int(still[0])
        raise DataError(f"{source}: load cases {_label(labels, k)} and {_label(labels, k + 1)} are "
                        "the same for every channel; a load case must differ from the one before")
    if (rate_kgf_s is None) == (frequency_hz is None):
        raise ParameterError("give either a rate (kgf/s) or a frequency (Hz) for the haversines "
                             "between load cases, not both or neither")
    if rate_kgf_s is not None:
        if not (math.isfinite(rate_kgf_s) and rate_kgf_s > 0):
            raise ParameterError(f"rate = {rate_kgf_s} kgf/s: it must be a positive number")
        durations = np.pi * span / (2 * rate_kgf_s)
        how = f"{rate_kgf_s:g} kgf/s"
    else:
        if not (math.isfinite(frequency_hz) and frequency_hz > 0):
            raise ParameterError(f"frequency = {frequency_hz} Hz: it must be a positive number")
        durations = np.full(L.shape[1] - 1, 1 / (2 * frequency_hz))
        how = f"{frequency_hz:g} Hz"
    label = f"{source}, {how}"
    programmes = []
    for row in L:
        t, r, rate, idx = _haversine(row, durations, period_s)
        programmes.append(Programme(t, r, idx, period_s, label, rate, True))
    return RigProgramme(names, programmes, True, label,
                        list(labels) if labels is not None else [str(k + 1) for k in range(L.shape[1])])


def from_channel_programmes(programmes: Sequence[Programme], names: Sequence[str],
                            source: str = "per-channel sequences") -> RigProgramme:
    """Independent programmes on one clock: each shorter one holds its last level until the
    longest ends (its last turning point moves to the end, the hold is part of its last
    segment)."""
    programmes = list(programmes)
    if len({p.period_s for p in programmes}) != 1:
        raise ParameterError("every channel's programme must be sampled at the same period")
    n = max(len(p.t_s) for p in programmes)
    T = programmes[0].period_s
    out = []
    for p in programmes:
        pad = n - len(p.t_s)
        if pad:
            r = np.r_[p.r_kgf, np.full(pad, p.r_kgf[-1])]
            rate = np.r_[p.rate_kgf_s(), np.zeros(pad)]
            idx = p.turning_idx.copy()
            idx[-1] = n - 1
            p = Programme(np.arange(n) * T, r, idx, T, p.source, rate)
        out.append(p)
    return RigProgramme(list(names), out, False, source)


def random_load_cases(n_cases: int, bands_kgf: Sequence[tuple[float, float]], seed: int = 0,
                      antiphase: Sequence[bool] | None = None) -> np.ndarray:
    r"""``n_cases`` load cases (N × n_cases) alternating between peaks and valleys on every
    channel at once: each channel's levels drawn uniformly in its band (low, high), at least
    5 % of the band from the one before (:func:`loading.programme.random_sequence`, a seed per
    channel from ``seed``), so the ratios between the channels change from case to case. A
    channel in ``antiphase`` is mirrored in its band (its valleys at the others' peaks). For
    benchmarks and tests: the structure of a multi-channel test's load cases, not any test's
    content."""
    from .programme import random_sequence
    antiphase = list(antiphase) if antiphase is not None else [False] * len(bands_kgf)
    rows = []
    for i, ((low, high), anti) in enumerate(zip(bands_kgf, antiphase)):
        seq = random_sequence(n_cases, low, high, seed=seed * 1000 + i)
        rows.append(low + high - seq if anti else seq)
    return np.array(rows)


# -- reading rig programmes ---------------------------------------------------------------------------
def load_rig_programme(spec: str, names: Sequence[str], period_s: float,
                       rate_kgf_s: float | None = None,
                       frequency_hz: float | None = None) -> RigProgramme:
    """A rig programme from a load-case CSV or a per-channel TOML (module docstring) for the
    channels ``names`` (the rig's, in its order: the CSV's columns may come in any order but
    must name every channel and no other)."""
    names = list(names)
    path = Path(spec)
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
    # the header is read in lower case: channels are matched regardless of case
    by_lower = {n.lower(): n for n in names}
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
                 frequency_hz: float | None) -> RigProgramme:
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
            from .programme import is_sequence
            seq = is_sequence(spec)
            programmes.append(load_programme(spec, period_s, rate if seq else None,
                                             freq if seq else None))
        except (DataError, ParameterError) as exc:
            raise type(exc)(f"{where}: {exc}") from None
    return from_channel_programmes(programmes, names, source=f"per-channel {path.name}")


def write_load_cases(path: str | Path, levels_kgf: np.ndarray, names: Sequence[str]) -> Path:
    """A load-case CSV (``case`` and a column per channel) for ``levels_kgf`` (N × M)."""
    path = Path(path)
    lines = [",".join([CASE_COLUMN, *names])]
    for k, col in enumerate(np.asarray(levels_kgf, float).T, start=1):
        lines.append(",".join([str(k), *(f"{v:.1f}" for v in col)]))
    path.write_text("\n".join(lines) + "\n")
    return path


def _label(labels: Sequence[str] | None, k: int) -> str:
    return labels[k] if labels is not None else str(k + 1)


def _fmt(v: float) -> str:
    return str(int(v)) if float(v).is_integer() else f"{v:g}"
