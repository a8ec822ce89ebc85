r"""Relay-feedback estimator: the paper's eq. (4) and the exact limit-cycle estimates (Figs. 19-23).

The loop ``u = u0·sign(r − y)`` around ``dy/dt = g·u(t − τ)`` self-oscillates.

**Exact limit cycle.** Each time y crosses r the relay switches; the force keeps going for τ,
then turns. The output is a triangle of slope ±g·u0, period and peak

.. math::  P = 4\tau, \qquad A = g\,u_0\,\tau
           \quad\Longrightarrow\quad \tau = P/4, \qquad g = \frac{4A}{u_0 P}.

With relay hysteresis ε (switch at r ± ε) the peak grows by ε and the period by 4ε/(g·u0):
``g = 4A/(u0·P)`` still holds and ``τ = (A − ε)·P/(4A)``. With a trend Δ, a valve bias or an
asymmetric gain the rise and fall slopes differ (a = g·u0 + Δ up, b = g·u0 − Δ down); from the
peak-to-peak value ``A_pp`` and the rise and fall times ``T_r = A_pp/a``, ``T_f = A_pp/b``:

.. math::  g = \frac{a + b}{2 u_0}, \qquad \Delta = \frac{a - b}{2}, \qquad
           \tau = \frac{A_{pp} - 2\varepsilon}{a + b},

which reduce to the formulas above when a = b (A = A_pp/2, P = T_r + T_f).

**Describing function (paper eq. 4).** Taking y as its first harmonic ``A_y·sin(ωt)``:

.. math::  g = \frac{A_y\,\pi\,\omega}{4 u_0}, \qquad \tau = \frac{\pi}{2\omega}.       \tag{4}

τ = π/(2ω) = P/4 is the exact value, but the gain is exact only if ``A_y`` is the amplitude of
the *first harmonic* of the triangle, ``A_1 = 8A/π²``. With the peak A in its place (what one
reads off a plot) eq. (4) gives ``g·π²/8``: it **overestimates g by 23.4 %**. Both are reported
(``g_df_peak``: biased; ``g_df_harmonic``: the least-squares first harmonic at ω, unbiased for
the model), beside the exact estimates, which are the recommended ones.

**Sampling.** The gateway reads y at each SYNC (period T) and the command acts from that sample
on, held for T (zero-order hold). The relay can switch only at a sample: y crosses r at some
instant, the switch comes θ ∈ [0, T) later. When the crossing instants fall at random phases of
the sampling grid (noise alone does this: here 2 kgf of noise against ramps of g·u0·T ≈ 1-5 kgf
per sample), θ is uniform on [0, T) and adds on average T/2 to the loop's delay: the measured
cycle is that of an effective delay ``τ_e = τ + T/2`` (P = 4τ_e, A = g·u0·τ_e; g = 4A/(u0·P)
is unaffected). The same holds exactly without noise when τ is a multiple of T/2 (the lags
alternate θ and T − θ). Noise near the crossing makes the relay chatter for a few samples; the
mean of ``sign(r − y − n)`` is odd in ``y − r``, so a group of chattering switches acts like
one switch at the crossing; it is replaced by one switch at the instant with the same command
integral. Hence

.. math::  \hat\tau = \frac{A_{pp} - 2\varepsilon}{a + b} - \frac{T}{2}.

In real time the command also arrives some bus latency after the SYNC; that latency is part of
the estimated delay (as it is of the stand's behaviour under control).

**Measuring A and P.** The apexes of the triangle are not read as sample extremes (the extreme
of noisy samples is biased upward by about two noise standard deviations, i.e. by 10 % of A at
u0 = 5 %); each rise and fall is fitted by a straight line by least squares (its middle 60 %)
and the apexes are the intersections of consecutive lines. Per cycle g and τ are computed; the
estimates are the means over the cycles with Student-t 95 % intervals. The first cycle after
the relay starts is skipped.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from gateway.errors import DataError

from ..records.limits import clipped_mask
from ..records.record import Record
from .meander import CLIP_RUN, mean_ci

#: π²/8: the factor by which eq. (4) with the peak overestimates g for a triangle
DF_PEAK_BIAS = math.pi ** 2 / 8
#: relative asymmetry above which it is reported as a warning (if also beyond 3 standard errors)
ASYMMETRY_WARN = 0.05


@dataclass
class RelayEstimate:
    """Estimates from one relay run (constant r, one amplitude u0)."""

    g: float                          #: exact limit-cycle gain, kgf/(%·s) (recommended)
    g_ci: tuple[float, float]
    tau: float                        #: exact limit-cycle delay, sampling-corrected, s (recommended)
    tau_ci: tuple[float, float]
    delta: float                      #: rate offset (a − b)/2, kgf/s (trend or valve bias)
    amplitude_pct: float              #: u0 as applied (from the recorded command), %
    reference_kgf: float              #: r, kgf
    hysteresis_kgf: float             #: ε used, kgf
    period_s: float                   #: P, mean cycle period, s
    peak_kgf: float                   #: A = A_pp/2, half the apex-to-apex height, kgf
    first_harmonic_kgf: float         #: A_1, least-squares first harmonic of y at ω = 2π/P, kgf
    g_df_peak: float                  #: eq. (4) with the peak A (biased by π²/8)
    g_df_harmonic: float              #: eq. (4) with the first harmonic A_1
    tau_df: float                     #: eq. (4): π/(2ω) = P/4, s (no sampling correction)
    df_bias: float                    #: g_df_peak / g (≈ π²/8 = 1.234 for the model)
    sampling_correction_s: float      #: T/2 subtracted from the delay, s
    control_period_s: float           #: T, s
    rise_s: float                     #: mean trough-to-peak time, s
    fall_s: float                     #: mean peak-to-trough time, s
    slope_rise: float                 #: a, kgf/s
    slope_fall: float                 #: b (magnitude), kgf/s
    peak_above_kgf: float             #: mean peak − r, kgf
    trough_below_kgf: float           #: r − mean trough, kgf
    plus_s: float                     #: mean time per cycle at +u0, s
    minus_s: float                    #: mean time per cycle at −u0, s
    cycles: int                       #: complete cycles used
    start_s: float                    #: time the analysed stretch starts, s
    apexes: list[tuple[float, float]] = field(default_factory=list)   #: (t, y) of each apex
    warnings: list[str] = field(default_factory=list)

    @property
    def asymmetry(self) -> dict[str, float]:
        """Relative differences (0: symmetric): rise vs fall slope, time at +u0 vs −u0, peak
        above r vs trough below r."""
        def rel(a: float, b: float) -> float:
            return float((a - b) / ((a + b) / 2)) if a + b else math.nan
        return {"slope_rise_vs_fall": rel(self.slope_rise, self.slope_fall),
                "time_plus_vs_minus": rel(self.plus_s, self.minus_s),
                "peak_above_vs_below": rel(self.peak_above_kgf, self.trough_below_kgf)}

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("apexes")
        d["asymmetry"] = self.asymmetry
        return d


def relay_levels(u: np.ndarray) -> float:
    """The relay amplitude u0: the most frequent non-zero |u| in the second half of the record."""
    tail = np.abs(u[len(u) // 2:])
    tail = tail[tail > 0]
    if len(tail) == 0:
        return math.nan
    values, counts = np.unique(np.round(tail, 6), return_counts=True)
    return float(values[np.argmax(counts)])


def relay_part(u: np.ndarray, u0: float) -> int:
    """Index where the relay phase starts: after the last sample whose |u| is not u0 (the
    approach loop before it has a continuously varying command)."""
    tol = max(1e-3 * u0, 1e-6)
    off = np.flatnonzero(np.abs(np.abs(u) - u0) > tol)
    return int(off[-1] + 1) if len(off) else 0


def _events(t: np.ndarray, u: np.ndarray, T: float) -> list[tuple[float, int, int, int]]:
    """Relay switches as ``(t_eff, direction, i_first, i_last)``; chattering groups merged.

    Sign changes closer together than 30 % of the typical half-period (the gap length that
    covers the median sample: chatter gaps are many but short) form one group; a group with no
    net change is a glitch and dropped. ``t_eff`` is the instant of an ideal switch with the
    same command integral over the group."""
    s = np.sign(u)
    changes = np.flatnonzero(s[1:] != s[:-1]) + 1
    if len(changes) == 0:
        return []
    gaps = np.diff(changes)
    threshold = 0
    if len(gaps):
        g = np.sort(gaps)
        half = g[np.searchsorted(np.cumsum(g), 0.5 * g.sum())]
        threshold = int(0.3 * half)
    groups: list[list[int]] = [[int(changes[0])]]
    for c, gap in zip(changes[1:], gaps):
        if gap <= threshold:
            groups[-1].append(int(c))
        else:
            groups.append([int(c)])
    events = []
    for grp in groups:
        i0, i1 = grp[0], grp[-1]
        before, after = s[i0 - 1], s[i1]
        if before == after or after == 0:
            continue
        ub, ua = u[i0 - 1], u[i1]
        integral = float(np.sum(u[i0:i1]) * T)
        t_eff = (integral - ua * t[i1] + ub * t[i0]) / (ub - ua) if i1 > i0 else float(t[i0])
        events.append((t_eff, int(after), i0, i1))
    return events


def _regular(events: list) -> list:
    """Drop the start-up: events from the first one after which three half-periods in a row
    are within ±50 % of the median half-period."""
    if len(events) < 5:
        return events
    spacing = np.diff([e[0] for e in events])
    h = float(np.median(spacing))
    ok = np.abs(spacing - h) <= 0.5 * h
    for i in range(len(ok) - 2):
        if ok[i:i + 3].all():
            return events[i:]
    return events


def _line(t: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares line through (t, y): ``(slope, value at t = 0)``."""
    A = np.column_stack([t, np.ones_like(t)])
    slope, icpt = np.linalg.lstsq(A, y, rcond=None)[0]
    return float(slope), float(icpt)


def _harmonic_amplitude(t: np.ndarray, y: np.ndarray, omega: float) -> float:
    """Least-squares amplitude of the harmonic at ω (with a constant)."""
    A = np.column_stack([np.sin(omega * t), np.cos(omega * t), np.ones_like(t)])
    a, b = np.linalg.lstsq(A, y, rcond=None)[0][:2]
    return float(math.hypot(a, b))


def estimate_relay(rec: Record, hysteresis_kgf: float | None = None,
                   control_period_s: float | None = None, skip_cycles: int = 1,
                   min_cycles: int = 3) -> RelayEstimate:
    """Estimate g and τ from a relay-feedback record (exact limit cycle and eq. 4).

    Parameters
    ----------
    rec : the record; the reference r (kgf) is taken from it (if absent, the midpoint of the
        oscillation is used and a warning says so).
    hysteresis_kgf : relay hysteresis ε, kgf; default: the run's ``hysteresis_kgf`` parameter, or 0.
    control_period_s : the control loop's period T, s; default: the run's ``period_s``, or the
        record's sampling interval (a CSV is assumed to hold one row per control cycle).
    skip_cycles : cycles skipped after the relay starts (start-up of the oscillation).
    min_cycles : complete cycles needed.
    """
    params = ((rec.meta.get("experiment") or {}).get("params") or {}) if rec.meta else {}
    eps = float(hysteresis_kgf if hysteresis_kgf is not None else params.get("hysteresis_kgf", 0.0))
    T = float(control_period_s or rec.meta.get("period_s") or rec.dt)
    warnings: list[str] = []
    u0 = relay_levels(rec.u)
    if not math.isfinite(u0):
        raise DataError(f"{rec.source}: the command is zero throughout; a relay record switches "
                        "between +u0 and −u0")
    start = relay_part(rec.u, u0)
    t, u, y = rec.t[start:], rec.u[start:], rec.y[start:]
    if len(t) < 20:
        raise DataError(f"{rec.source}: the relay phase (command ±{u0:g} %) has only {len(t)} samples")
    r_part = rec.r[start:]
    levels = np.unique(r_part[np.isfinite(r_part)])
    if len(levels) > 1:
        raise DataError(f"{rec.source}: the reference changes within the relay phase ({len(levels)} "
                        f"values from {levels.min():.0f} to {levels.max():.0f} kgf); one relay estimate "
                        "needs one constant r: split the record per reference")
    events = _regular(_events(t, u, T))
    # the cycles: from one switch to −u0 (y crossing r upward) to the next
    events = events[2 * skip_cycles:]
    ncyc = (len(events) - 1) // 2
    if ncyc < min_cycles:
        raise DataError(
            f"{rec.source}: no sustained oscillation: {len(events)} relay switches after the start "
            f"give {max(ncyc, 0)} complete cycle(s) ({skip_cycles} skipped); need at least "
            f"{min_cycles}. Record a longer relay phase (duration_s) or check that the loop oscillates")
    clipped = clipped_mask(rec.y, CLIP_RUN)[start:]
    i_first = events[0][3]
    if clipped[i_first:].any():
        raise DataError(f"{rec.source}: the force is saturated (flat at {rec.y.max():.0f} / "
                        f"{rec.y.min():.0f} kgf) during the limit cycle; an estimate would be "
                        "made up. Lower u0 or move r away from the dynamometer's range")
    ys = y
    # rough τ_e: from each switch to the extreme of the force that follows it
    lags = []
    for (te, d, i0, i1), (te2, _, j0, _) in zip(events[:-1], events[1:]):
        seg = ys[i1:j0 + 1]
        if len(seg) < 3:
            continue
        k = int(np.argmax(seg) if d < 0 else np.argmin(seg))
        lags.append(t[i1 + k] - te)
    lag = float(np.median(lags)) if lags else 0.0
    # one monotone stretch of y per command segment: [event_i + lag, event_i+1 + lag]
    lines = []
    for (te, d, _, _), (te2, _, _, _) in zip(events[:-1], events[1:]):
        a, b = te + lag, te2 + lag
        span = b - a
        sel = (t >= a + 0.2 * span) & (t <= b - 0.2 * span)
        if sel.sum() < 6:
            raise DataError(f"{rec.source}: a half-cycle of the limit cycle spans only "
                            f"{int(sel.sum())} usable samples; the sampling ({T * 1e3:g} ms) is too "
                            "coarse for this oscillation")
        slope, icpt = _line(t[sel], ys[sel])
        if slope * d <= 0:
            raise DataError(f"{rec.source}: the force does not follow the relay (a {'rise' if d > 0 else 'fall'} "
                            f"after the switch at {te:.3f} s has slope {slope:.0f} kgf/s); not a relay "
                            "limit cycle of an integrating plant")
        lines.append((slope, icpt, d))
    apexes = []
    for (s1, c1, _), (s2, c2, _) in zip(lines[:-1], lines[1:]):
        ta = (c2 - c1) / (s1 - s2)
        apexes.append((ta, s1 * ta + c1, 1 if s1 > 0 else -1))    # +1: peak, −1: trough
    # per cycle: rise (trough→peak) and fall (peak→trough) pairs
    g_c, tau_c, rise_c, fall_c, a_c, b_c = [], [], [], [], [], []
    for i in range(len(apexes) - 2):
        (t0, y0, k0), (t1, y1, _), (t2, y2, _) = apexes[i], apexes[i + 1], apexes[i + 2]
        if k0 != -1:
            continue
        R, F = y1 - y0, y1 - y2
        Tr, Tf = t1 - t0, t2 - t1
        if R <= 0 or F <= 0 or Tr <= 0 or Tf <= 0:
            continue
        a, b = R / Tr, F / Tf
        app = (R + F) / 2
        g_c.append((a + b) / (2 * u0))
        tau_c.append((app - 2 * eps) / (a + b) - T / 2)
        rise_c.append(Tr)
        fall_c.append(Tf)
        a_c.append(a)
        b_c.append(b)
    if len(g_c) < min_cycles:
        raise DataError(f"{rec.source}: only {len(g_c)} complete triangle cycles could be measured; "
                        f"need at least {min_cycles}")
    g, g_lo, g_hi = mean_ci(g_c)
    tau, tau_lo, tau_hi = mean_ci(tau_c)
    peaks = np.array([ya for _, ya, k in apexes if k > 0])
    troughs = np.array([ya for _, ya, k in apexes if k < 0])
    A = float(peaks.mean() - troughs.mean()) / 2
    rise_s, fall_s = float(np.mean(rise_c)), float(np.mean(fall_c))
    P = rise_s + fall_s
    omega = 2 * math.pi / P
    # first harmonic over whole cycles, apex to apex
    t_a, t_b = apexes[0][0], apexes[0][0] + P * math.floor((apexes[-1][0] - apexes[0][0]) / P)
    sel = (t >= t_a) & (t < t_b)
    A1 = _harmonic_amplitude(t[sel], ys[sel], omega) if sel.sum() > 10 else math.nan
    g_df_peak = A * math.pi * omega / (4 * u0)                       # eq. (4) with the peak
    g_df_h = A1 * math.pi * omega / (4 * u0)                         # eq. (4), first harmonic
    # reference and asymmetry
    r_fin = rec.r[start:][np.isfinite(rec.r[start:])]
    if len(r_fin):
        r = float(np.median(r_fin))
    else:
        r = float((peaks.mean() + troughs.mean()) / 2)
        warnings.append("no reference r in the data: the midpoint of the oscillation is used as r")
    ev_t = np.array([e[0] for e in events])
    ev_d = np.array([e[1] for e in events])
    dur = np.diff(ev_t)
    plus_s = float(np.mean(dur[ev_d[:-1] > 0])) if (ev_d[:-1] > 0).any() else math.nan
    minus_s = float(np.mean(dur[ev_d[:-1] < 0])) if (ev_d[:-1] < 0).any() else math.nan
    est = RelayEstimate(
        g=g, g_ci=(g_lo, g_hi), tau=tau, tau_ci=(tau_lo, tau_hi),
        delta=float((np.mean(a_c) - np.mean(b_c)) / 2), amplitude_pct=u0, reference_kgf=r,
        hysteresis_kgf=eps, period_s=P, peak_kgf=A, first_harmonic_kgf=A1,
        g_df_peak=g_df_peak, g_df_harmonic=g_df_h, tau_df=math.pi / (2 * omega),
        df_bias=g_df_peak / g, sampling_correction_s=T / 2, control_period_s=T,
        rise_s=rise_s, fall_s=fall_s, slope_rise=float(np.mean(a_c)), slope_fall=float(np.mean(b_c)),
        peak_above_kgf=float(peaks.mean() - r), trough_below_kgf=float(r - troughs.mean()),
        plus_s=plus_s, minus_s=minus_s, cycles=len(g_c), start_s=float(t[events[0][3]]),
        apexes=[(float(a), float(b)) for a, b, _ in apexes], warnings=warnings)
    _asymmetry_warnings(est, {
        "slope_rise_vs_fall": _se_rel_diff(a_c, b_c),
        "time_plus_vs_minus": _se_rel_diff(dur[ev_d[:-1] > 0], dur[ev_d[:-1] < 0]),
        "peak_above_vs_below": _se_rel_diff(peaks - r, r - troughs)})
    if rec.meta.get("clock") == "realtime":
        warnings.append("real-time run: τ includes the bus latency from each SYNC to the command "
                        "acting (only the sampling's T/2 is corrected)")
    if eps == 0 and A < 5 * T * est.slope_rise:
        warnings.append("the oscillation spans fewer than 5 samples per quarter period: the "
                        "sampling correction dominates τ")
    return est


def _se_rel_diff(a, b) -> float:
    """Standard error of the relative difference (ā − b̄)/((ā + b̄)/2) of two samples."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) < 2 or len(b) < 2:
        return math.inf
    se = math.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
    return se / abs((a.mean() + b.mean()) / 2)


def _asymmetry_warnings(est: RelayEstimate, se: dict[str, float]) -> None:
    """Warn about an asymmetry larger than 5 % AND than three standard errors (not noise)."""
    asym = {k: (v if abs(v) > max(ASYMMETRY_WARN, 3 * se[k]) else 0.0) for k, v in est.asymmetry.items()}
    if abs(asym["slope_rise_vs_fall"]) > ASYMMETRY_WARN:
        faster = "rise" if asym["slope_rise_vs_fall"] > 0 else "fall"
        est.warnings.append(
            f"asymmetric slopes: the {faster} is {abs(asym['slope_rise_vs_fall']):.0%} steeper "
            f"(rise {est.slope_rise:.0f}, fall {est.slope_fall:.0f} kgf/s; rise {est.rise_s * 1e3:.0f} ms, "
            f"fall {est.fall_s * 1e3:.0f} ms): asymmetric gain, a valve bias or a trend "
            f"(Δ ≈ {est.delta:.0f} kgf/s)")
    if abs(asym["peak_above_vs_below"]) > ASYMMETRY_WARN:
        est.warnings.append(
            f"asymmetric peaks: {est.peak_above_kgf:.1f} kgf above r, {est.trough_below_kgf:.1f} kgf "
            "below: the oscillation is not centred on r (valve bias, asymmetric gain or a trend)")
    if abs(asym["time_plus_vs_minus"]) > ASYMMETRY_WARN:
        est.warnings.append(
            f"asymmetric half-periods: {est.plus_s * 1e3:.0f} ms at +u0, {est.minus_s * 1e3:.0f} ms "
            "at −u0")
