r"""Open-loop square-wave ("meander") estimator: the paper's eq. (2) and Figs. 11-12.

For ``dy/dt = g·u(t − τ) + Δ`` a constant command ``u = ±u0`` gives a ramp of slope
``g·u + Δ``; the paper estimates

.. math::  g = \frac{y(t_2) - y(t_1) - \Delta\,(t_2 - t_1)}{u_0\,(t_2 - t_1)}            \tag{2}

and finds four portions in every period: the *main* rise and fall (steady ramps) and the
*transitional* rise and fall (a short stretch right after each reversal of the rod, where the
gain is much larger). This module finds them automatically:

1. the command's segments of constant sign and level, and the reversals between them
   (only where the record is open loop: samples with a reference r belong to a set-point
   approach and are left out);
2. the delay τ̂ from the extrema of the force after each reversal (the rod turns at t_s + τ);
3. the main slope of each response segment by least squares on its steady part, and the trend Δ
   jointly with one gain per amplitude from ``slope = g(u0)·u + Δ`` (both signs needed);
4. the transitional window: the time after the turn during which the local slope differs from
   the main slope by more than 10 % (ensemble over all reversals); if there is no such excess,
   a nominal window of min(0.25 s, a quarter segment) is used and reported;
5. eq. (2) per segment and portion; mean and 95 % confidence interval (Student t over segments)
   per portion and amplitude.

The recommended ``g`` is the main-portion gain pooled over rise, fall and amplitudes.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy import stats

from gateway.errors import DataError

from ..records.limits import clipped_mask
from ..records.record import Record

#: samples in a row at the record's extreme value taken for a reading clipped at the
#: dynamometer's range (a saturated dynamometer reads a constant)
CLIP_RUN = 10

PORTIONS = ("main_rise", "main_fall", "transitional_rise", "transitional_fall")


@dataclass
class PortionEstimate:
    portion: str
    amplitude_pct: float
    g: float
    ci_low: float
    ci_high: float
    n: int


@dataclass
class Segment:
    """One constant-command stretch that follows a reversal."""

    start: int            #: index of the first sample with the new command
    stop: int             #: index after the last sample
    u: float              #: command, %
    slope: float = math.nan          #: main-portion slope, kgf/s
    g_main: float = math.nan
    g_transitional: float = math.nan
    clipped: bool = False


@dataclass
class MeanderEstimate:
    g: float
    g_ci: tuple[float, float]
    delta: float                      #: trend Δ, kgf/s
    tau: float | None                 #: rough delay from the reversal extrema, s
    transitional_s: float             #: length of the transitional window used, s
    transitional_detected: bool       #: False: no excess slope found, nominal window used
    portions: list[PortionEstimate]
    segments: list[Segment] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def table(self) -> list[dict]:
        """Rows for the Figs. 11/12 tables: one per portion and amplitude."""
        return [asdict(p) for p in self.portions]

    def portion(self, name: str, amplitude_pct: float | None = None) -> PortionEstimate | None:
        for p in self.portions:
            if p.portion == name and (amplitude_pct is None or abs(p.amplitude_pct - amplitude_pct) < 1e-6):
                return p
        return None


def mean_ci(values, level: float = 0.95) -> tuple[float, float, float]:
    """Mean and its two-sided Student-t confidence interval (NaN interval for one value)."""
    v = np.asarray([x for x in values if math.isfinite(x)], float)
    if len(v) == 0:
        return math.nan, math.nan, math.nan
    m = float(v.mean())
    if len(v) < 2:
        return m, math.nan, math.nan
    half = float(stats.t.ppf(0.5 + level / 2, len(v) - 1) * v.std(ddof=1) / math.sqrt(len(v)))
    return m, m - half, m + half


def command_segments(u: np.ndarray, tolerance_pct: float = 1e-6) -> list[tuple[int, int, float]]:
    """Runs of (numerically) constant command: ``(start, stop, value)``."""
    change = np.flatnonzero(np.abs(np.diff(u)) > tolerance_pct) + 1
    bounds = np.concatenate([[0], change, [len(u)]])
    return [(int(a), int(b), float(u[a])) for a, b in zip(bounds[:-1], bounds[1:])]


def open_loop_stretches(rec: Record) -> list[tuple[int, int]]:
    """``(start, stop)`` of the open-loop parts of a record: where the reference r is NaN.

    The gateway's meander records its set-point approach (a closed loop) with r = the set point
    and the square wave with r = NaN; the approach is no part of the estimate. A record with a
    reference everywhere (or none at all) is taken as open loop throughout."""
    open_ = ~np.isfinite(rec.r)
    if open_.all() or not open_.any():
        return [(0, len(rec))]
    edges = np.flatnonzero(np.diff(open_.astype(np.int8))) + 1
    bounds = np.concatenate([[0], edges, [len(rec)]])
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if open_[a]]


def _smooth(y: np.ndarray, n: int) -> np.ndarray:
    if n <= 1:
        return y
    kernel = np.ones(n) / n
    pad = n // 2
    return np.convolve(np.pad(y, (pad, n - 1 - pad), mode="edge"), kernel, mode="valid")


def estimate_meander(rec: Record, transitional_s: float | None = None) -> MeanderEstimate:
    """Estimate g (per portion and amplitude), Δ and a rough τ from a square-wave record."""
    t, u, y = rec.t, rec.u, rec.y
    dt = rec.dt
    warnings: list[str] = []
    segs: list[Segment] = []
    for lo, hi in open_loop_stretches(rec):
        prev_sign = 0
        for a, b, v in command_segments(u[lo:hi]):
            if v == 0 or b - a < 4:
                continue
            sign = 1 if v > 0 else -1
            if prev_sign and sign != prev_sign:
                segs.append(Segment(lo + a, lo + b, v))
            prev_sign = sign
    if len(segs) < 2:
        raise DataError(
            f"{rec.source}: a meander estimate needs at least two reversals of a square-wave "
            f"command; found {len(segs)} (is this an open-loop meander record?)")
    clipped = clipped_mask(y, CLIP_RUN)
    # -- delay from the extrema after each reversal ------------------------------------------
    ys = _smooth(y, max(1, int(round(0.01 / dt))))
    taus = []
    for s in segs:
        look = min(s.stop, s.start + max(4, int(0.5 * (s.stop - s.start))))
        window = ys[s.start:look]
        k = int(np.argmax(window) if s.u < 0 else np.argmin(window))
        if 0 < k < len(window) - 1:
            taus.append(k * dt)
    tau = float(np.median(taus)) if taus else None
    lag = int(round((tau or 0.0) / dt))

    def response(s: Segment) -> tuple[int, int]:
        return min(len(y), s.start + lag), min(len(y), s.stop + lag)

    # -- main slopes (first pass: the second half of each response) ------------------------------
    def fit_slopes(skip_s: float) -> None:
        for s in segs:
            a, b = response(s)
            a = min(b, a + int(round(skip_s / dt)))
            if b - a < 4:
                s.slope = math.nan
                continue
            s.clipped = bool(clipped[a:b].any())
            if s.clipped:
                s.slope = math.nan
                continue
            s.slope = float(np.polyfit(t[a:b] - t[a], y[a:b], 1)[0])

    seg_len_s = float(np.median([(s.stop - s.start) * dt for s in segs]))
    fit_slopes(0.5 * seg_len_s)
    if all(s.clipped for s in segs):
        raise DataError(f"{rec.source}: the force is saturated (flat at {y.max():.0f} / {y.min():.0f} kgf) "
                        "in every segment; lower the amplitude or the period")
    n_clipped = sum(s.clipped for s in segs)
    if n_clipped:
        warnings.append(f"{n_clipped} segment(s) skipped: force saturated")
    delta, gains = _trend_and_gains(segs, warnings)

    # -- transitional window ---------------------------------------------------------------------
    detected = False
    if transitional_s is None:
        w = _transitional_width(segs, ys, t, dt, lag, seg_len_s)
        if w is not None:
            transitional_s, detected = w, True
        else:
            transitional_s = min(0.25, 0.25 * seg_len_s)
    transitional_s = float(min(max(transitional_s, 2 * dt), 0.5 * seg_len_s))
    # second pass: main portion = everything after the transitional window (at least half the segment)
    fit_slopes(max(transitional_s, 0.25 * seg_len_s) if detected else 0.5 * seg_len_s)
    delta, gains = _trend_and_gains(segs, warnings)
    n_tr = max(1, int(round(transitional_s / dt)))
    avg = max(1, min(n_tr // 4, int(round(0.01 / dt))))
    for s in segs:
        if math.isfinite(s.slope):
            s.g_main = (s.slope - delta) / s.u
        a, b = response(s)
        if b - a > n_tr + avg and not clipped[a:a + n_tr + avg].any():
            y1 = y[max(0, a - avg // 2):a + avg // 2 + 1].mean()
            y2 = y[a + n_tr - avg // 2:a + n_tr + avg // 2 + 1].mean()
            s.g_transitional = (y2 - y1 - delta * transitional_s) / (s.u * transitional_s)  # eq. (2)
    portions = []
    amplitudes = sorted({round(abs(s.u), 6) for s in segs})
    for amp in amplitudes:
        for name in PORTIONS:
            rise = name.endswith("rise")
            vals = [(s.g_main if name.startswith("main") else s.g_transitional)
                    for s in segs if round(abs(s.u), 6) == amp and (s.u > 0) == rise]
            m, lo, hi = mean_ci(vals)
            n = sum(math.isfinite(v) for v in vals)
            if n:
                portions.append(PortionEstimate(name, amp, m, lo, hi, n))
    g, g_lo, g_hi = mean_ci([s.g_main for s in segs])
    if not math.isfinite(g):
        raise DataError(f"{rec.source}: no usable ramp in any segment (segments too short or saturated)")
    return MeanderEstimate(g=g, g_ci=(g_lo, g_hi), delta=delta, tau=tau,
                           transitional_s=transitional_s, transitional_detected=detected,
                           portions=portions, segments=segs, warnings=warnings)


def _trend_and_gains(segs: list[Segment], warnings: list[str]) -> tuple[float, dict]:
    """Least squares ``slope_i = g(amplitude_i)·u_i + Δ`` over all main segments."""
    ok = [s for s in segs if math.isfinite(s.slope)]
    amps = sorted({round(abs(s.u), 6) for s in ok})
    signs_ok = all({s.u > 0 for s in ok if round(abs(s.u), 6) == a} == {True, False} for a in amps)
    A = np.zeros((len(ok), len(amps) + 1))
    for i, s in enumerate(ok):
        A[i, amps.index(round(abs(s.u), 6))] = s.u
        A[i, -1] = 1.0
    b = np.array([s.slope for s in ok])
    if not signs_ok:
        if "trend" not in " ".join(warnings):
            warnings.append("trend Δ not identifiable (an amplitude lacks rises or falls): Δ = 0 assumed")
        A = A[:, :-1]
        sol = np.linalg.lstsq(A, b, rcond=None)[0]
        return 0.0, dict(zip(amps, sol))
    sol = np.linalg.lstsq(A, b, rcond=None)[0]
    return float(sol[-1]), dict(zip(amps, sol[:-1]))


def _transitional_width(segs, ys, t, dt, lag, seg_len_s) -> float | None:
    """Length of the transitional portion, from the ensemble of *excess force* curves.

    After the rod turns (sample ``a``), the excess force ``E(θ) = y(a+θ) − y(a) − s·θ`` (s: the
    segment's main slope) is zero for a pure ramp and settles at the extra force a reversal
    effect adds (negative for a slow start, e.g. a lag). Being an integral it is robust to noise.
    The window ends when the median of ``E/|s|`` over all reversals reaches 90 % of its final
    value; None if the final value is not clearly above the noise."""
    n = int(0.5 * seg_len_s / dt)
    if n < 8:
        return None
    curves, noise = [], []
    theta = np.arange(n) * dt
    for s in segs:
        if not math.isfinite(s.slope) or s.slope == 0:
            continue
        a = s.start + lag
        if a + n >= len(ys):
            continue
        e = (ys[a:a + n] - ys[a] - s.slope * theta) / abs(s.slope)
        curves.append(e)
        late = e[n // 2:]
        noise.append(np.std(late - np.polyval(np.polyfit(theta[n // 2:], late, 1), theta[n // 2:])))
    if len(curves) < 2:
        return None
    med = np.median(np.vstack(curves), axis=0)
    final = float(np.median(med[n // 2:]))
    if abs(final) < max(5 * float(np.median(noise)), 2 * dt):
        return None
    reached = np.flatnonzero(np.abs(med) >= 0.9 * abs(final))
    return float(reached[0] * dt) if len(reached) else None
