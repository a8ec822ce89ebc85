r"""Loading programmes: what force the structure must see, sampled at the loop period.

Four forms, read by :func:`load_programme`:

* a **turning-point sequence**: a CSV with one column ``level`` (kgf), one turning point per
  line. Between two points the reference is a haversine

  .. math::  r(s) = L_0 + (L_1 - L_0)\,\frac{1 - \cos \pi s}{2},\qquad s \in [0, 1],

  whose peak rate ``π·|L_1 − L_0|/(2T)`` is ``rate_kgf_s`` (so the half-cycle lasts
  ``T = π·|L_1 − L_0|/(2·rate)``), or which lasts ``1/(2·frequency)``;
* a **time history**: a CSV ``t,r`` (s, kgf), resampled to the period; its turning points are
  its peaks and valleys (reversals by more than 0.5 % of its range);
* **constant amplitude**: ``sine:mean=3000,amplitude=2000,frequency=0.2,cycles=20``;
* a **block programme**: a TOML file of ``[[block]]`` tables with ``mean``, ``amplitude``,
  ``frequency`` and ``cycles``; consecutive blocks join through a haversine at the next block's
  rate.

Every form becomes a :class:`Programme`: the reference ``r`` on a uniform time grid and the
indices of its turning points (first point, each peak and valley, last point), which peak/valley
compensation moves (:meth:`Programme.with_levels`) and the tracking report measures against.
"""
from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from core.errors import DataError, ParameterError

#: a time history's reversals smaller than this share of its range are not turning points
HYSTERESIS_SHARE = 0.005


@dataclass(frozen=True)
class Programme:
    """A loading programme sampled at the loop period.

    Attributes
    ----------
    t_s : (N,) sample times from 0, uniform at ``period_s``
    r_kgf : (N,) the reference force
    turning_idx : (M,) indices into ``r_kgf`` of the turning points (first point, every peak and
        valley, last point), increasing
    period_s : the sampling period
    source : what it was made from, for reports
    haversine : True where every segment between two turning points is a haversine (turning-
        point sequences, block programmes): :meth:`with_durations` then makes them exactly
    """

    t_s: np.ndarray
    r_kgf: np.ndarray
    turning_idx: np.ndarray
    period_s: float
    source: str
    #: the reference's rate where the shape gives it exactly (kgf/s), else None
    _rate: np.ndarray | None = field(default=None, repr=False, compare=False)
    haversine: bool = field(default=False, compare=False)

    @property
    def levels_kgf(self) -> np.ndarray:
        return self.r_kgf[self.turning_idx]

    @property
    def range_kgf(self) -> float:
        return float(self.r_kgf.max() - self.r_kgf.min())

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1])

    @property
    def segment_durations_s(self) -> np.ndarray:
        """How long each segment between two turning points lasts (s), in programme order."""
        return np.diff(self.turning_idx) * self.period_s

    def rate_kgf_s(self) -> np.ndarray:
        """dr/dt per sample (kgf/s): exact for the generated shapes, else central differences."""
        if self._rate is not None:
            return self._rate
        return np.gradient(self.r_kgf, self.period_s)

    def kinds(self) -> list[str]:
        """Per turning point: 'start', 'end', 'peak' or 'valley' where the programme reverses, or
        'through' for a point it passes on the way (two segments the same way)."""
        lv = self.levels_kgf
        out = []
        for i in range(len(lv)):
            if i == 0:
                out.append("start")
            elif i == len(lv) - 1:
                out.append("end")
            elif lv[i] > lv[i - 1] and lv[i] > lv[i + 1]:
                out.append("peak")
            elif lv[i] < lv[i - 1] and lv[i] < lv[i + 1]:
                out.append("valley")
            else:
                out.append("through")
        return out

    def with_levels(self, levels_kgf: np.ndarray) -> "Programme":
        """The same programme with its turning points moved to ``levels_kgf`` (peak/valley
        compensation): each segment between two turning points is mapped affinely from its old
        end levels onto the new ones; times are unchanged."""
        new = np.asarray(levels_kgf, float)
        if new.shape != self.turning_idx.shape or not np.isfinite(new).all():
            raise ParameterError(f"{len(self.turning_idx)} finite levels expected, got {new.shape}")
        r = self.r_kgf.copy()
        rate = None if self._rate is None else self._rate.copy()
        old = self.levels_kgf
        for j in range(len(new) - 1):
            a, b = self.turning_idx[j], self.turning_idx[j + 1]
            span = old[j + 1] - old[j]
            scale = (new[j + 1] - new[j]) / span if span else 1.0
            r[a:b + 1] = new[j] + (self.r_kgf[a:b + 1] - old[j]) * scale
            if rate is not None:
                rate[a:b + 1] = self._rate[a:b + 1] * scale
        return Programme(self.t_s, r, self.turning_idx, self.period_s, self.source, rate,
                         self.haversine)

    def with_durations(self, durations_s, source: str | None = None) -> "Programme":
        """The same turning points with each segment lasting ``durations_s`` (s, one per
        segment, rounded to whole periods, at least one): time scaling. Haversine segments are
        made anew; any other shape is stretched or squeezed (cubic interpolation of the
        segment's shape over its share of the segment, and its rate scaled by the same
        factor)."""
        d = np.asarray(durations_s, float)
        if d.shape != (len(self.turning_idx) - 1,) or not (np.isfinite(d).all() and (d > 0).all()):
            raise ParameterError(f"{len(self.turning_idx) - 1} positive segment durations expected, "
                                 f"got {d.shape[0] if d.ndim == 1 else d.shape}")
        label = source or self.source
        if self.haversine:
            t, r, rate, idx = _haversine(self.levels_kgf, d, self.period_s)
            return Programme(t, r, idx, self.period_s, label, rate, True)
        from scipy.interpolate import CubicSpline
        steps = np.maximum(np.round(d / self.period_s).astype(int), 1)
        idx = np.r_[0, np.cumsum(steps)]
        r = np.empty(idx[-1] + 1)
        rate = np.empty_like(r)
        old_rate = self.rate_kgf_s()
        for j, k in enumerate(steps):
            a, b = self.turning_idx[j], self.turning_idx[j + 1]
            s_old = np.linspace(0.0, 1.0, b - a + 1)
            s_new = np.arange(k) / k
            if b - a >= 2:
                r[idx[j]:idx[j + 1]] = CubicSpline(s_old, self.r_kgf[a:b + 1])(s_new)
                rate[idx[j]:idx[j + 1]] = CubicSpline(s_old, old_rate[a:b + 1])(s_new) * (b - a) / k
            else:
                r[idx[j]:idx[j + 1]] = np.interp(s_new, s_old, self.r_kgf[a:b + 1])
                rate[idx[j]:idx[j + 1]] = np.interp(s_new, s_old, old_rate[a:b + 1]) * (b - a) / k
        r[-1] = self.r_kgf[-1]
        rate[-1] = old_rate[-1] * (self.turning_idx[-1] - self.turning_idx[-2]) / steps[-1]
        return Programme(np.arange(len(r)) * self.period_s, r, idx, self.period_s, label, rate)


# -- making programmes ----------------------------------------------------------------------------
def _haversine(levels: np.ndarray, durations: np.ndarray, period_s: float) -> tuple[np.ndarray, ...]:
    """Samples of haversines through ``levels`` with segment ``durations`` (s): t, r, dr/dt and
    the turning points' indices. Each segment is rounded to whole periods (at least one)."""
    steps = np.maximum(np.round(durations / period_s).astype(int), 1)
    n = int(steps.sum()) + 1
    r = np.empty(n)
    rate = np.zeros(n)
    idx = np.r_[0, np.cumsum(steps)]
    for j, k in enumerate(steps):
        s = np.arange(k) / k
        a, b = levels[j], levels[j + 1]
        r[idx[j]:idx[j + 1]] = a + (b - a) * (1 - np.cos(np.pi * s)) / 2
        rate[idx[j]:idx[j + 1]] = (b - a) * np.pi / (2 * k * period_s) * np.sin(np.pi * s)
    r[-1] = levels[-1]
    return np.arange(n) * period_s, r, rate, idx


def from_levels(levels_kgf, period_s: float, rate_kgf_s: float | None = None,
                frequency_hz: float | None = None, source: str = "levels") -> Programme:
    """A turning-point sequence: haversines between ``levels_kgf`` at a peak rate or frequency."""
    levels = np.asarray(levels_kgf, float)
    _check_period(period_s)
    if levels.ndim != 1 or len(levels) < 2:
        raise DataError(f"{source}: a programme needs at least 2 turning points, got {levels.size}")
    if not np.isfinite(levels).all():
        raise DataError(f"{source}: a turning point is not a finite number")
    same = np.flatnonzero(np.diff(levels) == 0)
    if len(same):
        raise DataError(f"{source}: turning points {same[0] + 1} and {same[0] + 2} are both "
                        f"{levels[same[0]]:g} kgf; a turning point must differ from the one before")
    if (rate_kgf_s is None) == (frequency_hz is None):
        raise ParameterError("give either a rate (kgf/s) or a frequency (Hz) for the haversines "
                             "between turning points, not both or neither")
    if rate_kgf_s is not None:
        if not (math.isfinite(rate_kgf_s) and rate_kgf_s > 0):
            raise ParameterError(f"rate = {rate_kgf_s} kgf/s: it must be a positive number")
        durations = np.pi * np.abs(np.diff(levels)) / (2 * rate_kgf_s)
        how = f"{rate_kgf_s:g} kgf/s"
    else:
        if not (math.isfinite(frequency_hz) and frequency_hz > 0):
            raise ParameterError(f"frequency = {frequency_hz} Hz: it must be a positive number")
        durations = np.full(len(levels) - 1, 1 / (2 * frequency_hz))
        how = f"{frequency_hz:g} Hz"
    t, r, rate, idx = _haversine(levels, durations, period_s)
    return Programme(t, r, idx, period_s, f"{source}, {how}", rate, True)


def sine(mean_kgf: float, amplitude_kgf: float, frequency_hz: float, cycles: float,
         period_s: float) -> Programme:
    """Constant amplitude: ``mean + amplitude·sin(2πft)`` for whole ``cycles``, entered from the
    mean by a quarter cycle so the first turning point is the mean."""
    _check_period(period_s)
    for name, v, low in (("amplitude", amplitude_kgf, 0.0), ("frequency", frequency_hz, 0.0),
                         ("cycles", cycles, 0.0)):
        if not (math.isfinite(v) and v > low):
            raise ParameterError(f"sine: {name} = {v} must be a positive number")
    if not math.isfinite(mean_kgf):
        raise ParameterError(f"sine: mean = {mean_kgf} must be a number")
    n = int(round(cycles / frequency_hz / period_s))
    t = np.arange(n + 1) * period_s
    w = 2 * np.pi * frequency_hz
    r = mean_kgf + amplitude_kgf * np.sin(w * t)
    rate = amplitude_kgf * w * np.cos(w * t)
    quarter = 1 / (4 * frequency_hz)
    extremes = np.round(np.arange(quarter, t[-1] - 1e-9, 2 * quarter) / period_s).astype(int)
    idx = np.unique(np.r_[0, extremes, n])
    return Programme(t, r, idx, period_s,
                     f"sine mean {mean_kgf:g} kgf, amplitude {amplitude_kgf:g} kgf, "
                     f"{frequency_hz:g} Hz, {cycles:g} cycles", rate)


def blocks(table: list[dict], period_s: float, source: str = "blocks") -> Programme:
    """A block programme: constant-amplitude blocks one after the other. Each block is
    ``cycles`` full cycles mean → peak → mean → valley → mean as haversines at its frequency
    (a quarter cycle each); the programme starts at the first block's mean."""
    if not table:
        raise DataError(f"{source}: no [[block]] in the programme")
    levels: list[float] = []
    durations: list[float] = []
    for i, b in enumerate(table, start=1):
        try:
            mean, amp, freq, cyc = (float(b[k]) for k in ("mean", "amplitude", "frequency", "cycles"))
        except KeyError as exc:
            raise DataError(f"{source}: block {i} has no {exc.args[0]!r}; a block needs mean, "
                            "amplitude, frequency and cycles") from None
        except (TypeError, ValueError):
            raise DataError(f"{source}: block {i}: mean, amplitude, frequency and cycles must be "
                            "numbers") from None
        if not (amp > 0 and freq > 0 and cyc >= 1 and cyc == int(cyc) and math.isfinite(mean)):
            raise DataError(f"{source}: block {i}: amplitude and frequency must be > 0 and cycles a "
                            "whole number >= 1")
        if not levels:
            levels.append(mean)
        elif mean + amp <= levels[-1]:
            raise DataError(f"{source}: block {i}'s peak {mean + amp:g} kgf is not above block "
                            f"{i - 1}'s valley {levels[-1]:g} kgf")
        for c in range(int(cyc)):
            levels += [mean + amp, mean - amp]
            durations += [1 / (4 * freq) if len(durations) == 0 else 1 / (2 * freq), 1 / (2 * freq)]
        last_mean, last_freq = mean, freq
    levels.append(last_mean)
    durations.append(1 / (4 * last_freq))
    t, r, rate, idx = _haversine(np.asarray(levels, float), np.asarray(durations, float), period_s)
    return Programme(t, r, idx, period_s, source, rate, True)


def from_history(t_s, r_kgf, period_s: float, source: str = "history") -> Programme:
    """A reference time history resampled (linearly) to the period; its turning points are its
    reversals by more than :data:`HYSTERESIS_SHARE` of its range."""
    t = np.asarray(t_s, float)
    r = np.asarray(r_kgf, float)
    _check_period(period_s)
    if len(t) < 2:
        raise DataError(f"{source}: a time history needs at least 2 samples, got {len(t)}")
    if not (np.isfinite(t).all() and np.isfinite(r).all()):
        raise DataError(f"{source}: a time or a force is not a finite number")
    if (np.diff(t) <= 0).any():
        k = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise DataError(f"{source}: the times must increase; sample {k + 2} (t = {t[k + 1]:g} s) "
                        f"does not come after sample {k + 1} (t = {t[k]:g} s)")
    grid = t[0] + np.arange(int(math.floor((t[-1] - t[0]) / period_s + 1e-9)) + 1) * period_s
    rr = np.interp(grid, t, r)
    idx = turning_points(rr, HYSTERESIS_SHARE * float(np.ptp(rr)))
    if len(idx) < 2 or np.ptp(rr) == 0:
        raise DataError(f"{source}: the reference never changes; nothing to load")
    return Programme(grid - grid[0], rr, idx, period_s, source)


def turning_points(x: np.ndarray, hysteresis: float) -> np.ndarray:
    """Indices of the first sample, each reversal by more than ``hysteresis`` (the extreme of
    each excursion) and the last sample."""
    out = [0]
    direction = 0
    ext = 0
    for k in range(1, len(x)):
        if direction >= 0 and x[k] >= x[ext]:
            ext = k
            direction = direction or (1 if x[k] > x[0] + hysteresis else 0)
        elif direction <= 0 and x[k] <= x[ext]:
            ext = k
            direction = direction or (-1 if x[k] < x[0] - hysteresis else 0)
        if direction > 0 and x[ext] - x[k] > hysteresis:
            out.append(ext); ext = k; direction = -1
        elif direction < 0 and x[k] - x[ext] > hysteresis:
            out.append(ext); ext = k; direction = 1
    if out[-1] != len(x) - 1:
        out.append(len(x) - 1)
    return np.asarray(sorted(set(out)), int)


def random_sequence(n: int, low_kgf: float, high_kgf: float, seed: int = 0,
                    min_span_kgf: float | None = None) -> np.ndarray:
    """``n`` turning points alternating between peaks and valleys, drawn uniformly between
    ``low_kgf`` and ``high_kgf``, each at least ``min_span_kgf`` (default 5 % of the band) from
    the one before; starts at ``low_kgf``. For benchmarks and tests (no standard spectrum)."""
    rng = np.random.default_rng(seed)
    span = (high_kgf - low_kgf) * 0.05 if min_span_kgf is None else min_span_kgf
    if n < 2 or span <= 0 or high_kgf - low_kgf <= span:
        raise ParameterError("random_sequence needs n >= 2 and a band wider than the minimum span")
    levels = [float(low_kgf)]
    while len(levels) < n:
        up = len(levels) % 2 == 1
        lo, hi = (levels[-1] + span, high_kgf) if up else (low_kgf, levels[-1] - span)
        if lo >= hi:
            lo, hi = (high_kgf - span / 2, high_kgf) if up else (low_kgf, low_kgf + span / 2)
        levels.append(float(rng.uniform(lo, hi)))
    return np.asarray(levels)


def flight_by_flight(flights: int, seed: int = 0, ground_kgf: float = 500.0,
                     flight_kgf: float = 3500.0, gust_max_kgf: float = 2500.0,
                     gust_min_kgf: float = 150.0, gusts_per_flight: tuple[int, int] = (10, 30)
                     ) -> np.ndarray:
    r"""Turning points of a synthetic flight-by-flight sequence: each flight goes from the
    ground level up to the 1 g flight level, through gust cycles about it and back to the
    ground (a ground-air-ground cycle per flight). For benchmarks and tests: it has the
    structure of a transport aircraft's wing-load sequence (many small gust cycles, one large
    cycle per flight, flights of different severity), not any standard's content (TWIST and
    FALSTAFF are not generated here; bring them as a turning-point CSV).

    Per flight a severity ``s ~ U(0.4, 1)`` and a number of gust cycles ``n ~ U(gusts)``; each
    gust cycle goes to ``flight + a`` and ``flight − b`` with

    .. math::  a, b = \min\big(g_{max},\ g_{min} + X\big),\qquad X \sim \mathrm{Exp}(0.18\,g_{max}\,s),

    so small gusts are common and large ones rare. The levels alternate between peaks and
    valleys (a valley followed by the ground keeps only the lower)."""
    if flights < 1 or not (0 < gust_min_kgf < gust_max_kgf) or ground_kgf >= flight_kgf - gust_max_kgf:
        raise ParameterError("flight_by_flight needs flights >= 1, 0 < gust_min < gust_max and the "
                             "ground below the lowest gust valley")
    rng = np.random.default_rng(seed)
    levels = [float(ground_kgf)]
    for _ in range(flights):
        severity = rng.uniform(0.4, 1.0)
        for _ in range(int(rng.integers(gusts_per_flight[0], gusts_per_flight[1] + 1))):
            a, b = (min(gust_max_kgf, gust_min_kgf + rng.exponential(0.18 * gust_max_kgf * severity))
                    for _ in range(2))
            levels += [flight_kgf + a, flight_kgf - b]
        levels.append(float(ground_kgf))
    out = [levels[0]]
    for x in levels[1:]:
        if len(out) >= 2 and (out[-1] - out[-2]) * (x - out[-1]) > 0:
            out[-1] = x                    # two steps the same way: keep the farther level
        else:
            out.append(x)
    return np.asarray(out)


# -- reading programmes -------------------------------------------------------------------------
_SINE = re.compile(r"^sine:(.*)$", re.I)


def load_programme(spec: str, period_s: float, rate_kgf_s: float | None = None,
                   frequency_hz: float | None = None) -> Programme:
    """A programme from a file or a spec (see the module docstring for the forms).

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


def _check_period(period_s: float) -> None:
    if not (math.isfinite(period_s) and 0 < period_s <= 0.1):
        raise ParameterError(f"period = {period_s} s: it must be from 0 to 0.1 s")


def check_programme(p: Programme, force_limit_kgf: float) -> None:
    """Refuse a programme the stand must not be asked for: a level at or beyond the force limit."""
    worst = int(np.argmax(np.abs(p.r_kgf)))
    if abs(p.r_kgf[worst]) >= force_limit_kgf:
        tp = np.flatnonzero(np.abs(p.levels_kgf) >= force_limit_kgf)
        where = f"turning point {tp[0] + 1} ({p.levels_kgf[tp[0]]:g} kgf)" if len(tp) else \
            f"t = {p.t_s[worst]:.3f} s ({p.r_kgf[worst]:g} kgf)"
        raise ParameterError(f"{p.source}: {where} is at or beyond the force limit "
                             f"±{force_limit_kgf:g} kgf; lower the programme or raise the limit")
