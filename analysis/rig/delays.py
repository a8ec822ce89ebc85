r"""Each moving channel's delay τ_j from its own reversals, and its transitional window.

After channel j's command reverses at ``t_s`` its rod keeps moving the old way until
``t_s + τ_j``: there the channel's own force turns (the meander estimator's rough τ is the
extremum, :mod:`analysis.estimators.meander`; here the extremum is refined by a two-line fit,
:func:`hinge_time`). In a simultaneous run the other channels' flows move the force too,
``Σ_{k≠j} G_jk·u_k(t − τ_k)``; with a first estimate of G that part is taken off before the
turns are read ("cleaned" force), so the turn is the channel's own.

The transitional window (how long the reversal boost lasts) is read as the meander estimator
reads it, from the excess force after the turns, but against the steady rate the estimate
predicts, ``E(θ) = y_j(a + θ) − y_j(a) − ∫_a^{a+θ} (Σ_k Ĝ_jk u_k(t − τ_k) + Δ̂_j) dt`` (a: the
turn): zero for the main portions, it settles at the extra force the boost adds (each curve
cut where a reversal of a channel that moves this force arrives: its boost is not this one's).
The window ends where the median of ``E/(Ĝ_jj·u_j)`` (positive for a boost, negative for a
slow start) over the reversals reaches 90 % of its final value
(:func:`boost_window`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from core.errors import DataError

from .steady import command_events

#: the force is smoothed over this long before its extremum is read (as the meander estimator)
SMOOTH_S = 0.006


@dataclass
class ChannelTiming:
    """A moving channel's delay and transitional window, from all the runs it moved in."""

    tau_s: float
    tau_ci_s: tuple[float, float]       #: distribution-free interval of the median
    reversals: int                      #: reversals whose turn was found
    transitional_s: float               #: the reversal boost's window (90 % of its extra force)
    transitional_detected: bool         #: False: none found
    #: the boost's extra force per reversal over the steady ``G_jj·u_j`` (s; 0: none found)
    boost_extra_s: float = 0.0
    #: the command's median |u| at the reversals, %
    amplitude_pct: float = 0.0


def turn_delays(u: np.ndarray, y: np.ndarray, dt: float) -> np.ndarray:
    """The time from each reversal of ``u`` to the turn of ``y`` after it (s), one per reversal
    whose turn lies inside the first half of the segment that follows.

    The turn is first found as the extremum of the force smoothed over :data:`SMOOTH_S` (the
    meander estimator's rough τ), then placed between samples by :func:`hinge_time`: a
    smoothed extremum sits early where the force leaves the turn faster than it came (the
    reversal boost), by up to a third of the smoothing."""
    n = max(1, int(round(SMOOTH_S / dt)))
    pad = n // 2
    ys = np.convolve(np.pad(y, (pad, n - 1 - pad), mode="edge"), np.ones(n) / n, mode="valid") \
        if n > 1 else y
    changes, reversal = command_events(u)
    ends = np.concatenate([changes[1:], [len(u)]])
    out = []
    for k, (e, rev, end) in enumerate(zip(changes, reversal, ends)):
        if not rev or k == 0 or u[e] == 0:
            continue
        look = min(end, e + max(4, (end - e) // 2))
        window = ys[e:look]
        i = int(np.argmax(window) if u[e] < 0 else np.argmin(window))
        if 0 < i < len(window) - 1:
            out.append(hinge_time(y, e + i, dt) - e * dt)
    return np.array(out)


#: the hinge is fitted on this long before and after the smoothed turn, s
HINGE_BEFORE_S = 0.03
HINGE_AFTER_S = 0.016


def hinge_time(y: np.ndarray, k: int, dt: float) -> float:
    """The time (s, from sample 0) of the kink of the continuous two-line fit
    ``y = a + s_1·min(t − T, 0) + s_2·max(t − T, 0)`` to the samples around ``k``: for each
    ``T`` on a grid of a tenth of a sample the lines are least squares, and the ``T`` of the
    smallest residual is taken (the window is fixed, so the residuals compare). The boost's
    decay bends the line after the turn little over :data:`HINGE_AFTER_S`."""
    a = max(0, k - int(round(HINGE_BEFORE_S / dt)))
    b = min(len(y), k + int(round(HINGE_AFTER_S / dt)) + 1)
    t = np.arange(a, b) * dt
    yy = y[a:b]
    best, best_T = math.inf, k * dt
    for T in (k + np.arange(-30, 31) / 10.0) * dt:
        X = np.column_stack([np.ones_like(t), np.minimum(t - T, 0.0), np.maximum(t - T, 0.0)])
        coef, *_ = np.linalg.lstsq(X, yy, rcond=None)
        r = yy - X @ coef
        sse = float(r @ r)
        if sse < best:
            best, best_T = sse, float(T)
    return best_T


def median_interval(values: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """Distribution-free interval of the median: order statistics ``x_(k), x_(n+1−k)`` with
    ``k`` the largest for which the binomial(n, ½) puts at least ``level`` between them."""
    v = np.sort(np.asarray(values, float))
    n = len(v)
    if n < 2:
        return math.nan, math.nan
    k = int(stats.binom.ppf((1 - level) / 2, n, 0.5))
    k = max(k, 1)
    if stats.binom.cdf(k - 1, n, 0.5) * 2 > 1 - level and k > 1:
        k -= 1
    if k > n - k + 1:
        return float(v[0]), float(v[-1])
    return float(v[k - 1]), float(v[n - k])


def boost_window(u: np.ndarray, y: np.ndarray, rate: np.ndarray, own_gain: float, tau_s: float,
                 dt: float, cuts: np.ndarray | None = None) -> tuple[float, float] | None:
    """The transitional window of one run (s), where the median excess force after the turns
    (module docstring; ``rate``: the predicted steady force rate, kgf/s, per sample) reaches
    90 % of its final value, and that final value (s of the steady rate); None when the final
    value is not clearly above the noise. ``cuts``: samples where another channel's reversal
    reaches this force (its boost, through G, is no part of this one's): each curve ends
    there."""
    changes, reversal = command_events(u)
    ends = np.concatenate([changes[1:], [len(u)]])
    lag = int(round(tau_s / dt))
    segs = [(e, end) for k, (e, rev, end) in enumerate(zip(changes, reversal, ends))
            if rev and k > 0 and u[e] != 0]
    if len(segs) < 2:
        return None
    n = int(0.5 * np.median([end - e for e, end in segs]))
    if n < 8:
        return None
    step = np.concatenate([[0.0], np.cumsum(rate)]) * dt      # ∫ rate from sample 0
    theta = np.arange(n) * dt
    cuts = np.sort(np.asarray(cuts if cuts is not None else [], int))
    curves, noise = [], []
    for e, end in segs:
        a = e + lag
        if a + n >= len(y):
            continue
        scale = own_gain * u[e] or 1.0         # signed: a boost's excess is positive
        ex = (y[a:a + n] - y[a] - (step[a:a + n] - step[a])) / scale
        nxt = cuts[np.searchsorted(cuts, a, side="right"):]
        if len(nxt) and nxt[0] < a + n:
            ex[nxt[0] - a:] = np.nan
        curves.append(ex)
        late = ex[n // 2:]
        ok = np.isfinite(late)
        if ok.sum() > 8:
            fit = np.polyval(np.polyfit(theta[n // 2:][ok], late[ok], 1), theta[n // 2:][ok])
            noise.append(np.std(late[ok] - fit))
    if len(curves) < 2:
        return None
    stack = np.vstack(curves)
    count = np.isfinite(stack).sum(axis=0)
    n = int(np.flatnonzero(count >= max(2, len(curves) // 3))[-1]) + 1 \
        if (count >= max(2, len(curves) // 3)).any() else 0
    if n < 8:
        return None
    with np.errstate(all="ignore"):
        med = np.nanmedian(stack[:, :n], axis=0)
    final = float(np.nanmedian(med[n // 2:]))
    if not noise:
        return None
    if abs(final) < max(5 * float(np.median(noise)), 2 * dt):
        return None
    reached = np.flatnonzero(np.abs(med) >= 0.9 * abs(final))
    return (float(reached[0] * dt), final) if len(reached) else None


def channel_timing(parts: list[tuple[np.ndarray, np.ndarray, np.ndarray | None, float, float,
                                     np.ndarray | None]],
                   name: str, level: float = 0.95) -> ChannelTiming:
    """τ_j and the transitional window of channel ``name`` from the runs it moved in, each
    ``(u_j, cleaned y_j, the predicted steady rate of the cleaned force or None, Ĝ_jj, dt,
    the samples where the other channels' reversals reach it)`` (module docstring); without a
    prediction the window is not read (0, not detected)."""
    delays, windows, extras, amps = [], [], [], []
    for u, y, rate, own_gain, dt, cuts in parts:
        d = turn_delays(u, y, dt)
        delays.append(d)
        changes, reversal = command_events(u)
        amps += [abs(u[e]) for e, rev in zip(changes, reversal) if rev and u[e] != 0]
        if rate is not None and len(d):
            w = boost_window(u, y, rate, own_gain, float(np.median(d)), dt, cuts)
            if w is not None:
                windows.append(w[0])
                extras.append(w[1])
    d = np.concatenate(delays) if delays else np.array([])
    if len(d) == 0:
        raise DataError(f"channel {name}: no turn of its force found after its reversals (is "
                        "its valve connected? does its force move with its command?)")
    trans = float(np.median(windows)) if windows else 0.0
    return ChannelTiming(float(np.median(d)), median_interval(d, level), len(d), trans,
                         bool(windows), float(np.median(extras)) if extras else 0.0,
                         float(np.median(amps)) if amps else 0.0)
