r"""Loading programmes: what force every channel of the station must see, on one clock, sampled
at the loop period.

A **station** is N loading channels (a rig's; a one-channel stand is a station of one, its
channel called :data:`STAND`). Its programme is a :class:`Programme`: one
:class:`ChannelProgramme` per channel on a common time grid and, where every channel's turning
points fall on the same samples, **load cases**: a row of N levels, every channel's turning
point at the same moment (a one-channel programme's turning points are its load cases).
Between two load cases every channel moves along a haversine of one common duration, set by the
channel that moves the most:

.. math::  T_k = \max_i \frac{\pi\,|L_{i,k+1} - L_{i,k}|}{2\,R},

(``R`` the peak rate in kgf/s), or ``T_k = 1/(2f)`` with a frequency, so every channel arrives
at the next load case together and its ratios between the channels hold at its turning point.
A channel may keep its level from one case to the next (it holds while the others move).

One channel's programme (:class:`ChannelProgramme`) comes in four forms:

* a **turning-point sequence** (:func:`from_levels`): haversines between levels,

  .. math::  r(s) = L_0 + (L_1 - L_0)\,\frac{1 - \cos \pi s}{2},\qquad s \in [0, 1],

  at a peak rate ``π·|L_1 − L_0|/(2T)`` or lasting ``1/(2·frequency)``;
* a **time history** (:func:`from_history`), resampled to the period; its turning points are
  its peaks and valleys (reversals by more than 0.5 % of its range);
* **constant amplitude** (:func:`sine`);
* a **block programme** (:func:`blocks`): constant-amplitude blocks joined by haversines.

A station's programme is made of load cases (:func:`from_load_cases`, N levels per row) or of
independent per-channel programmes on one clock (:func:`from_channel_programmes`: each shorter
one holds its last level; with several channels there are no load cases, so no ratios).
Programmes are read from files by :mod:`loading.programme_files`. Peak/valley compensation
moves turning points (:meth:`Programme.with_levels`), time scaling moves their times
(:meth:`Programme.with_durations`), and the tracking report measures against them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from core.errors import DataError, ParameterError

#: a time history's reversals smaller than this share of its range are not turning points
HYSTERESIS_SHARE = 0.005
#: the name of a one-channel stand's channel (a rig's channels are named in its file)
STAND = "stand"


@dataclass(frozen=True)
class ChannelProgramme:
    """One channel's loading programme sampled at the loop period.

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
        'rising' / 'falling' for a point it passes on the way (two segments the same way: on a
        station, a load case where other channels turn)."""
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
                out.append("rising" if lv[i + 1] > lv[i - 1] else "falling")
        return out

    def with_levels(self, levels_kgf: np.ndarray) -> "ChannelProgramme":
        """The same programme with its turning points moved to ``levels_kgf`` (peak/valley
        compensation): each segment between two turning points is mapped affinely from its old
        end levels onto the new ones (a segment that holds a level, a station's channel while
        the others move, goes from the one correction to the other along a haversine); times
        are unchanged."""
        new = np.asarray(levels_kgf, float)
        if new.shape != self.turning_idx.shape or not np.isfinite(new).all():
            raise ParameterError(f"{len(self.turning_idx)} finite levels expected, got {new.shape}")
        r = self.r_kgf.copy()
        rate = None if self._rate is None else self._rate.copy()
        old = self.levels_kgf
        for j in range(len(new) - 1):
            a, b = self.turning_idx[j], self.turning_idx[j + 1]
            span = old[j + 1] - old[j]
            if span == 0 and new[j + 1] != new[j]:
                s = np.arange(b - a + 1) / max(b - a, 1)
                move = new[j + 1] - new[j]
                r[a:b + 1] = self.r_kgf[a:b + 1] + (new[j] - old[j]) + move * (1 - np.cos(np.pi * s)) / 2
                if rate is not None:
                    rate[a:b + 1] = self._rate[a:b + 1] + move * np.pi / (2 * (b - a) * self.period_s) * np.sin(np.pi * s)
                continue
            scale = (new[j + 1] - new[j]) / span if span else 1.0
            r[a:b + 1] = new[j] + (self.r_kgf[a:b + 1] - old[j]) * scale
            if rate is not None:
                rate[a:b + 1] = self._rate[a:b + 1] * scale
        return ChannelProgramme(self.t_s, r, self.turning_idx, self.period_s, self.source, rate,
                         self.haversine)

    def with_offsets(self, offsets_kgf: np.ndarray) -> "ChannelProgramme":
        """The same programme with ``offsets_kgf`` (one per sample) added to its reference, its
        rate with theirs (a station's shape correction, :mod:`loading.compensation`: zero at
        every turning point, so the turning points stay where they are)."""
        d = np.asarray(offsets_kgf, float)
        if d.shape != self.r_kgf.shape or not np.isfinite(d).all():
            raise ParameterError(f"{len(self.r_kgf)} finite offsets expected, got {d.shape}")
        rate = None if self._rate is None else self._rate + np.gradient(d, self.period_s)
        return ChannelProgramme(self.t_s, self.r_kgf + d, self.turning_idx, self.period_s, self.source, rate,
                                self.haversine)

    def with_durations(self, durations_s, source: str | None = None) -> "ChannelProgramme":
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
            return ChannelProgramme(t, r, idx, self.period_s, label, rate, True)
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
        return ChannelProgramme(np.arange(len(r)) * self.period_s, r, idx, self.period_s, label, rate)


# -- a segment's shape -------------------------------------------------------------------------------
#: a segment's shape is told in half waves down to this long (s) (:func:`shape_basis`)
SHAPE_HALF_WAVE_S = 0.08
#: and in at least this many, at most this many
SHAPE_MODES = (4, 40)


def shape_modes(duration_s: float) -> int:
    """How many half waves a segment of ``duration_s`` is told in (:func:`shape_basis`)."""
    return int(np.clip(round(duration_s / SHAPE_HALF_WAVE_S), *SHAPE_MODES))


def shape_basis(samples: int, modes: int) -> np.ndarray:
    r"""(samples, modes): the shapes a segment's deviation is told in, over its samples from one
    turning point to the next (both included): the sine series

    .. math::  \phi_m(s) = \sin(m\pi s),\qquad m = 1 \ldots M,\ s \in [0, 1],

    zero at both turning points (a shape moves no turning point's level), the m-th with m half
    waves: features down to :data:`SHAPE_HALF_WAVE_S` (:func:`shape_modes`), the noise above
    that left out."""
    s = np.linspace(0.0, 1.0, max(int(samples), 2))
    out = np.sin(np.pi * s[:, None] * np.arange(1, modes + 1)[None, :])
    out[[0, -1]] = 0.0                   # exactly (sin(mπ) is not, in floating point)
    return out


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


def _segment_durations(spans_kgf: np.ndarray, rate_kgf_s: float | None, frequency_hz: float | None,
                       between: str) -> tuple[np.ndarray, str]:
    """Each segment's duration (s) as a haversine over ``spans_kgf`` at a peak rate, or half a
    cycle at a frequency, and how it was timed (for the programme's name)."""
    if (rate_kgf_s is None) == (frequency_hz is None):
        raise ParameterError("give either a rate (kgf/s) or a frequency (Hz) for the haversines "
                             f"between {between}, not both or neither")
    if rate_kgf_s is not None:
        if not (math.isfinite(rate_kgf_s) and rate_kgf_s > 0):
            raise ParameterError(f"rate = {rate_kgf_s} kgf/s: it must be a positive number")
        return np.pi * spans_kgf / (2 * rate_kgf_s), f"{rate_kgf_s:g} kgf/s"
    if not (math.isfinite(frequency_hz) and frequency_hz > 0):
        raise ParameterError(f"frequency = {frequency_hz} Hz: it must be a positive number")
    return np.full(len(spans_kgf), 1 / (2 * frequency_hz)), f"{frequency_hz:g} Hz"


def from_levels(levels_kgf, period_s: float, rate_kgf_s: float | None = None,
                frequency_hz: float | None = None, source: str = "levels") -> ChannelProgramme:
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
    durations, how = _segment_durations(np.abs(np.diff(levels)), rate_kgf_s, frequency_hz, "turning points")
    t, r, rate, idx = _haversine(levels, durations, period_s)
    return ChannelProgramme(t, r, idx, period_s, f"{source}, {how}", rate, True)


def sine(mean_kgf: float, amplitude_kgf: float, frequency_hz: float, cycles: float,
         period_s: float) -> ChannelProgramme:
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
    return ChannelProgramme(t, r, idx, period_s,
                     f"sine mean {mean_kgf:g} kgf, amplitude {amplitude_kgf:g} kgf, "
                     f"{frequency_hz:g} Hz, {cycles:g} cycles", rate)


def blocks(table: list[dict], period_s: float, source: str = "blocks") -> ChannelProgramme:
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
    return ChannelProgramme(t, r, idx, period_s, source, rate, True)


def from_history(t_s, r_kgf, period_s: float, source: str = "history") -> ChannelProgramme:
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
    return ChannelProgramme(grid - grid[0], rr, idx, period_s, source)


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


def _check_period(period_s: float) -> None:
    if not (math.isfinite(period_s) and 0 < period_s <= 0.1):
        raise ParameterError(f"period = {period_s} s: it must be from 0 to 0.1 s")


def check_programme(p: ChannelProgramme, force_limit_kgf: float) -> None:
    """Refuse a programme the stand must not be asked for: a level at or beyond the force limit."""
    worst = int(np.argmax(np.abs(p.r_kgf)))
    if abs(p.r_kgf[worst]) >= force_limit_kgf:
        tp = np.flatnonzero(np.abs(p.levels_kgf) >= force_limit_kgf)
        where = f"turning point {tp[0] + 1} ({p.levels_kgf[tp[0]]:g} kgf)" if len(tp) else \
            f"t = {p.t_s[worst]:.3f} s ({p.r_kgf[worst]:g} kgf)"
        raise ParameterError(f"{p.source}: {where} is at or beyond the force limit "
                             f"±{force_limit_kgf:g} kgf; lower the programme or raise the limit")


# -- a station's programme ----------------------------------------------------------------------
@dataclass(frozen=True)
class Programme:
    """A programme for every channel of a station on one time grid (module docstring).

    Attributes
    ----------
    names : the channels, in the station's order (a one-channel stand's: ``[STAND]``)
    channels : one programme per channel, all with the same ``t_s``
    load_cases : True when a turning point is a load case of every channel (the same
        ``turning_idx`` for all; always for one channel): the ratios between channels at each
        is part of the report
    source : what it was made from, for reports
    case_labels : a label per load case (the CSV's ``case`` column, or 1, 2, ...)
    """

    names: list[str]
    channels: list[ChannelProgramme]
    load_cases: bool
    source: str
    case_labels: list[str] | None = None

    def __post_init__(self) -> None:
        if len(self.names) != len(self.channels) or not self.channels:
            raise ParameterError(f"{len(self.names)} names for {len(self.channels)} programmes")
        n = len(self.channels[0].t_s)
        if any(len(p.t_s) != n for p in self.channels):
            raise ParameterError("every channel's programme must have the same time grid")

    @classmethod
    def of(cls, channel: ChannelProgramme, name: str = STAND) -> "Programme":
        """One channel's programme as a station's of one channel (its turning points are
        its load cases)."""
        return cls([name], [channel], True, channel.source)

    @property
    def n(self) -> int:
        return len(self.channels)

    @property
    def stand(self) -> bool:
        """True for a one-channel stand's programme (its files keep the one-channel forms)."""
        return self.names == [STAND]

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

    def kinds(self) -> list[list[str]]:
        """Per channel, per turning point: :meth:`ChannelProgramme.kinds`."""
        return [p.kinds() for p in self.channels]

    def turning_cases(self) -> np.ndarray:
        """The load cases (indices from 0, the first and the last left out) where some
        channel turns (a peak or a valley of its own): where the programme's clock waits for
        the forces (null pacing) and the tracking report judges the ratios."""
        kinds = self.kinds()
        return np.array([k for k in range(1, len(self.turning_idx) - 1)
                         if any(c[k] in ("peak", "valley") for c in kinds)], int)

    def _load_cases_only(self) -> None:
        if not self.load_cases:
            raise ParameterError(f"{self.source}: per-channel sequences have no load cases")

    @property
    def segment_durations_s(self) -> np.ndarray:
        """How long each segment between two load cases lasts (s; load cases only)."""
        self._load_cases_only()
        return self.channels[0].segment_durations_s

    def with_durations(self, durations_s, source: str | None = None) -> "Programme":
        """The same load cases with each segment lasting ``durations_s`` (s, one per segment;
        :meth:`ChannelProgramme.with_durations` on every channel, so they stay on one grid): time
        scaling."""
        self._load_cases_only()
        label = source or self.source
        return Programme(self.names, [p.with_durations(durations_s, label) for p in self.channels],
                         True, label, self.case_labels)

    def from_case(self, k: int) -> "Programme":
        """The programme from load case ``k`` (0-based) on: its samples from there, on a clock
        from 0 (an interrupted programme taken up again at a load case; load cases only)."""
        self._load_cases_only()
        idx = self.turning_idx
        if not 0 <= k <= len(idx) - 2:
            raise ParameterError(f"{self.source}: load case {k + 1}: a programme from there needs it "
                                 f"and one more of its {len(idx)} load cases")
        a = int(idx[k])
        out = []
        for p in self.channels:
            out.append(ChannelProgramme(p.t_s[a:] - p.t_s[a], p.r_kgf[a:], idx[k:] - a, p.period_s, p.source,
                                        p.rate_kgf_s()[a:], p.haversine))
        labels = self.case_labels[k:] if self.case_labels is not None else None
        return Programme(self.names, out, True, f"{self.source}, from load case {k + 1}", labels)

    def channel(self, name: str) -> ChannelProgramme:
        try:
            return self.channels[self.names.index(name)]
        except ValueError:
            raise ParameterError(f"{self.source}: no channel {name!r}; it has "
                                 f"{', '.join(self.names)}") from None

    def with_levels(self, levels: Sequence[np.ndarray]) -> "Programme":
        """Each channel's turning points moved to ``levels[i]`` (peak/valley compensation,
        :meth:`ChannelProgramme.with_levels`); the times are kept, so load cases stay load cases."""
        return Programme(self.names, [p.with_levels(lv) for p, lv in zip(self.channels, levels)],
                         self.load_cases, self.source, self.case_labels)

    def with_offsets(self, offsets_kgf: Sequence[np.ndarray]) -> "Programme":
        """Each channel's reference plus ``offsets_kgf[i]`` (:meth:`ChannelProgramme.with_offsets`)."""
        return Programme(self.names, [p.with_offsets(d) for p, d in zip(self.channels, offsets_kgf)],
                         self.load_cases, self.source, self.case_labels)

    def check(self, force_limits_kgf: Sequence[float]) -> None:
        """Refuse a level at or beyond a channel's force limit (naming the channel)."""
        for name, p, limit in zip(self.names, self.channels, force_limits_kgf):
            try:
                check_programme(p, limit)
            except ParameterError as exc:
                raise ParameterError(f"channel {name}: {exc}") from None


def as_programme(programme: "Programme | ChannelProgramme") -> Programme:
    """A station's programme as it is, or one channel's as a one-channel stand's
    (:meth:`Programme.of`): what a station's functions take, as numpy takes a scalar."""
    return Programme.of(programme) if isinstance(programme, ChannelProgramme) else programme


# -- making a station's programmes ------------------------------------------------------------------
def from_load_cases(levels_kgf, names: Sequence[str], period_s: float,
                    rate_kgf_s: float | None = None, frequency_hz: float | None = None,
                    source: str = "load cases", labels: Sequence[str] | None = None) -> Programme:
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
    durations, how = _segment_durations(span, rate_kgf_s, frequency_hz, "load cases")
    label = f"{source}, {how}"
    programmes = []
    for row in L:
        t, r, rate, idx = _haversine(row, durations, period_s)
        programmes.append(ChannelProgramme(t, r, idx, period_s, label, rate, True))
    return Programme(names, programmes, True, label,
                     list(labels) if labels is not None else [str(k + 1) for k in range(L.shape[1])])


def from_channel_programmes(programmes: Sequence[ChannelProgramme], names: Sequence[str],
                            source: str = "per-channel sequences") -> Programme:
    """Independent programmes on one clock: each shorter one holds its last level until the
    longest ends (its last turning point moves to the end, the hold is part of its last
    segment). With several channels they share no load cases; one channel's turning points
    are its load cases."""
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
            p = ChannelProgramme(np.arange(n) * T, r, idx, T, p.source, rate)
        out.append(p)
    return Programme(list(names), out, len(out) == 1, source)


def random_load_cases(n_cases: int, bands_kgf: Sequence[tuple[float, float]], seed: int = 0,
                      antiphase: Sequence[bool] | None = None) -> np.ndarray:
    r"""``n_cases`` load cases (N × n_cases) alternating between peaks and valleys on every
    channel at once: each channel's levels drawn uniformly in its band (low, high), at least
    5 % of the band from the one before (:func:`random_sequence`, a seed per
    channel from ``seed``), so the ratios between the channels change from case to case. A
    channel in ``antiphase`` is mirrored in its band (its valleys at the others' peaks). For
    benchmarks and tests: the structure of a multi-channel test's load cases, not any test's
    content."""
    antiphase = list(antiphase) if antiphase is not None else [False] * len(bands_kgf)
    rows = []
    for i, ((low, high), anti) in enumerate(zip(bands_kgf, antiphase)):
        seq = random_sequence(n_cases, low, high, seed=seed * 1000 + i)
        rows.append(low + high - seq if anti else seq)
    return np.array(rows)


def _label(labels: Sequence[str] | None, k: int) -> str:
    return labels[k] if labels is not None else str(k + 1)
