r"""Proportional-feedback estimator with a harmonic reference: the paper's eq. (3), Figs. 13-18.

In the loop ``u = k·(r − y)``, ``r = r0 + A_r·sin(ωt)``, around ``dy/dt = g·u(t − τ) + Δ`` the
stationary u and y are harmonics at ω, ``u = A_u·sin(ωt + φ_u)``, ``y = A_y·sin(ωt + φ_y)``,
and the plant alone gives ``A_y = g·A_u/ω``, so

.. math::  g = \frac{A_y\,\omega}{A_u}.                                                   \tag{3}

This holds for the plant whatever the controller does (a clamped command too), provided A_u and
A_y are the amplitudes of the *harmonics at ω*: they are fitted by linear least squares,
``x(t) ≈ a·sin ωt + b·cos ωt + c``, over whole periods of the stationary part (not read
from peaks, which noise and higher harmonics bias).

**Stationary part.** Model (1) makes the loop's error dynamics first order with time constant
``1/(k·g)`` (slightly faster with the delay), so the start-up transient decays as
``e^{−k·g·t}``. A first fit on the last period gives g₁; the transient left at the start of the
sine, ``e₀ = |y(t₀) − ŷ(t₀)|``, must decay below 0.5 % of the smaller of A_y and A_e = A_u/k;
the stationary part starts ``ln(e₀/(0.005·A))/(k·g₁)`` after the sine starts. The estimate then
uses the last whole number of periods after that instant (at least one).

**Delay from the phase.** For model (1) ``φ_y − φ_u = −π/2 − ω·(τ + T/2)``: the command
recorded at t_k is held over [t_k, t_k + T), i.e. centred T/2 later. Hence
``τ = (−π/2 − (φ_y − φ_u))/ω − T/2``. It is exact for the model, but at the paper's low
frequencies ωτ is a few degrees, so any unmodelled phase (a valve lag, the reversal effect)
enters it fully: the relay's τ is the better one.

**Intervals.** With two or more stationary periods: Student-t over the per-period estimates;
with one: least-squares standard errors of the amplitudes (residual variance, corrected for
its lag-1 autocorrelation), propagated to g.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import optimize, stats

from gateway.errors import DataError

from ..records.limits import clipped_mask
from ..records.record import Record
from .meander import CLIP_RUN, mean_ci

#: the start-up transient must have decayed below this fraction of the amplitudes
TRANSIENT_TOLERANCE = 0.005


@dataclass
class Harmonic:
    """``x(t) ≈ A·sin(ωt + φ) + c + d·t``: amplitude, phase (rad) and the amplitude's std. error."""

    amplitude: float
    phase: float
    amplitude_se: float


@dataclass
class PFeedbackEstimate:
    """Estimates from one P-feedback run (one ω, one A_r)."""

    g: float                          #: eq. (3), kgf/(%·s) (recommended)
    g_ci: tuple[float, float]
    tau: float | None                 #: delay from the phase of y against u, s (model-sensitive)
    omega_rad_s: float                #: ω
    reference_kgf: float              #: A_r as fitted on the recorded reference, kgf
    gain: float                       #: k, %/kgf (from the run, or fitted on u = k·(r − y))
    amplitude_u_pct: float            #: A_u, first harmonic of u, %
    amplitude_y_kgf: float            #: A_y, first harmonic of y, kgf
    phase_u: float                    #: φ_u, rad
    phase_y: float                    #: φ_y, rad
    stationary_from_s: float          #: start of the stationary part used, s
    stationary_s: float               #: its length (whole periods), s
    periods: int                      #: whole periods used
    transient_s: float                #: time from the sine's start to the stationary part, s
    control_period_s: float           #: T, s
    period_g: list[float] = field(default_factory=list)   #: g per stationary period
    warnings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def fit_harmonic(t: np.ndarray, x: np.ndarray, omega: float) -> Harmonic:
    """Least-squares first harmonic at ``omega`` with a constant (over whole periods this is
    the Fourier coefficient, unaffected by the other harmonics)."""
    X = np.column_stack([np.sin(omega * t), np.cos(omega * t), np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(X, x, rcond=None)
    a, b = coef[:2]
    amp = float(math.hypot(a, b))
    resid = x - X @ coef
    n, p = X.shape
    s2 = float(resid @ resid) / max(n - p, 1)
    rho = float(np.corrcoef(resid[:-1], resid[1:])[0, 1]) if n > 3 and resid.std() > 0 else 0.0
    inflate = (1 + rho) / (1 - rho) if 0 < rho < 0.99 else (199.0 if rho >= 0.99 else 1.0)
    cov = s2 * inflate * np.linalg.pinv(X.T @ X)[:2, :2]
    se = float(math.sqrt(max((a * a * cov[0, 0] + 2 * a * b * cov[0, 1] + b * b * cov[1, 1]), 0.0)) / amp) if amp else math.inf
    return Harmonic(amp, float(math.atan2(b, a)), se)


def reference_frequency(t: np.ndarray, r: np.ndarray) -> float:
    """ω of a sinusoidal reference: the periodogram's peak, refined by least squares."""
    x = r - r.mean()
    n = len(x)
    dt = float(t[1] - t[0])
    pad = 1 << int(math.ceil(math.log2(max(n, 2)))) + 2
    spec = np.abs(np.fft.rfft(x * np.hanning(n), pad))
    freqs = np.fft.rfftfreq(pad, dt) * 2 * math.pi
    k = int(np.argmax(spec[1:]) + 1)
    w0 = float(freqs[k])
    step = float(freqs[1])

    def residual(w: float) -> float:
        X = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])
        coef, *_ = np.linalg.lstsq(X, r, rcond=None)
        e = r - X @ coef
        return float(e @ e)

    res = optimize.minimize_scalar(residual, bounds=(max(w0 - 2 * step, 1e-6), w0 + 2 * step),
                                   method="bounded", options={"xatol": 1e-9})
    return float(res.x)


def sine_start(r: np.ndarray) -> int:
    """Index where the sine starts: the last sample of the constant reference held during the
    set-point approach (0 when the reference varies from the start)."""
    finite = np.isfinite(r)
    if not finite.any():
        return 0
    first = int(np.flatnonzero(finite)[0])
    r0 = r[first]
    moving = np.flatnonzero(finite & (np.abs(r - r0) > 1e-9 * max(1.0, abs(r0))))
    if len(moving) == 0:
        return first
    return max(first, int(moving[0]) - 1)


def estimate_pfeedback(rec: Record, omega_rad_s: float | None = None, gain: float | None = None,
                       control_period_s: float | None = None) -> PFeedbackEstimate:
    """Estimate g by eq. (3) (and τ from the phase) from a P-feedback record with sinusoidal r.

    Parameters
    ----------
    omega_rad_s : ω; default: the run's parameter, else fitted on the recorded reference.
    gain : k, %/kgf; default: the run's parameter, else fitted on ``u = k·(r − y)``.
    control_period_s : T, s; default: the run's period, else the sampling interval.
    """
    params = ((rec.meta.get("experiment") or {}).get("params") or {}) if rec.meta else {}
    T = float(control_period_s or rec.meta.get("period_s") or rec.dt)
    warnings: list[str] = []
    if not rec.has_reference():
        raise DataError(f"{rec.source}: a P-feedback estimate needs the reference r (column r of "
                        "the CSV): A_r·sin(ωt) is what the loop follows")
    i0 = sine_start(rec.r)
    t, u, y, r = rec.t[i0:], rec.u[i0:], rec.y[i0:], rec.r[i0:]
    ok = np.isfinite(r)
    if ok.sum() < 20:
        raise DataError(f"{rec.source}: only {int(ok.sum())} samples with a reference")
    t, u, y, r = t[ok], u[ok], y[ok], r[ok]
    omega = float(omega_rad_s or params.get("omega_rad_s") or reference_frequency(t, r))
    period = 2 * math.pi / omega
    if t[-1] - t[0] < period:
        raise DataError(f"{rec.source}: the sinusoidal part lasts {t[-1] - t[0]:.1f} s, less than one "
                        f"period of the reference ({period:.1f} s at ω = {omega:.4g} rad/s); record "
                        "at least a few periods after the transient")
    rh = fit_harmonic(t, r, omega)
    X = np.column_stack([np.sin(omega * t), np.cos(omega * t), np.ones_like(t)])
    r_res = r - X @ np.linalg.lstsq(X, r, rcond=None)[0]
    if rh.amplitude <= 0 or np.std(r_res) > 0.05 * rh.amplitude:
        raise DataError(f"{rec.source}: the reference is not a sinusoid at ω = {omega:.4g} rad/s "
                        f"(residual {np.std(r_res):.0f} kgf against amplitude {rh.amplitude:.0f} kgf); "
                        "not a P-feedback record with harmonic reference")
    if clipped_mask(rec.y, CLIP_RUN)[i0:][ok].any():
        raise DataError(f"{rec.source}: the force is saturated (flat at {rec.y.max():.0f} / "
                        f"{rec.y.min():.0f} kgf); eq. (3) needs the unclipped force. Lower A_r")
    e = r - y
    k = float(gain or params.get("gain") or (float(u @ e) / float(e @ e) if float(e @ e) > 0 else math.nan))
    # first pass on the last period: g₁ and the steady-state fit
    last = t >= t[-1] - period
    hy1, hu1 = fit_harmonic(t[last], y[last], omega), fit_harmonic(t[last], u[last], omega)
    noise = float(np.std(np.diff(y)) / math.sqrt(2))
    if hu1.amplitude < 1e-6 or hy1.amplitude < 3 * noise:
        raise DataError(f"{rec.source}: no harmonic response at ω = {omega:.4g} rad/s (A_y = "
                        f"{hy1.amplitude:.1f} kgf, A_u = {hu1.amplitude:.3g} %, noise {noise:.1f} kgf); "
                        "raise A_r or k")
    g1 = hy1.amplitude * omega / hu1.amplitude
    lam = abs(k) * g1 if math.isfinite(k) and k != 0 else math.nan
    Xs = np.column_stack([np.sin(omega * t[last]), np.cos(omega * t[last]), np.ones_like(t[last])])
    coef = np.linalg.lstsq(Xs, y[last], rcond=None)[0]
    n0 = min(len(t), max(1, int(round(0.01 / T))))
    y_ss0 = np.column_stack([np.sin(omega * t[:n0]), np.cos(omega * t[:n0]), np.ones(n0)]) @ coef
    e0 = float(abs(np.mean(y[:n0] - y_ss0)))
    a_ref = min(hy1.amplitude, hu1.amplitude / abs(k)) if math.isfinite(lam) else hy1.amplitude
    if not math.isfinite(lam) or lam <= 0:
        transient = 0.5 * (t[-1] - t[0])
        warnings.append("the loop gain k is unknown: the first half of the sine is skipped as transient")
    else:
        transient = max(0.0, math.log(max(e0, 1e-12) / (TRANSIENT_TOLERANCE * a_ref)) / lam)
    t_stat = t[0] + transient
    n_per = int(math.floor((t[-1] + T - t_stat) / period + 1e-9))
    if n_per < 1:
        raise DataError(
            f"{rec.source}: no stationary period: the transient lasts about {transient:.1f} s "
            f"(1/(k·g) = {1 / lam:.1f} s) and leaves {max(t[-1] - t_stat, 0):.1f} s of a {period:.1f} s "
            "period; record longer (more periods or a longer transient_s)")
    start_t = t[-1] + T - n_per * period
    sel = t >= start_t - 1e-9
    hy, hu = fit_harmonic(t[sel], y[sel], omega), fit_harmonic(t[sel], u[sel], omega)
    g = hy.amplitude * omega / hu.amplitude                           # eq. (3)
    per = []
    for j in range(n_per):
        a = start_t + j * period
        m = (t >= a - 1e-9) & (t < a + period - 1e-9)
        if m.sum() > 8:
            per.append(fit_harmonic(t[m], y[m], omega).amplitude * omega /
                       fit_harmonic(t[m], u[m], omega).amplitude)
    if len(per) >= 2:
        _, lo, hi = mean_ci(per)
        half = (hi - lo) / 2
        lo, hi = g - half, g + half
        if abs(per[0] - per[-1]) > 0.03 * g:
            warnings.append(f"g changes from {per[0]:.1f} to {per[-1]:.1f} over the stationary part: "
                            "not quite stationary (or a time-varying stand)")
    else:
        rel = math.hypot(hy.amplitude_se / hy.amplitude, hu.amplitude_se / hu.amplitude)
        z = float(stats.norm.ppf(0.975))
        lo, hi = g * (1 - z * rel), g * (1 + z * rel)
    dphi = (hy.phase - hu.phase) % (2 * math.pi) - 2 * math.pi      # in (−2π, 0]
    tau = (-math.pi / 2 - dphi) / omega - T / 2
    if not (0 <= tau < period / 4):
        warnings.append(f"the phase of y against u ({math.degrees(dphi):.1f}°) does not fit an "
                        "integrator with a delay: no τ from the phase")
        tau_out: float | None = None
    else:
        tau_out = float(tau)
    limit = params.get("command_limit_pct")
    if limit and (np.abs(u) >= float(limit) - 1e-6).mean() > 0.01:
        warnings.append(f"the command hit its clamp ±{float(limit):g} % ({(np.abs(u) >= float(limit) - 1e-6).mean():.0%} "
                        "of the time): eq. (3) still holds for the plant, the loop is not linear")
    return PFeedbackEstimate(
        g=float(g), g_ci=(float(lo), float(hi)), tau=tau_out, omega_rad_s=omega,
        reference_kgf=rh.amplitude, gain=k, amplitude_u_pct=hu.amplitude, amplitude_y_kgf=hy.amplitude,
        phase_u=hu.phase, phase_y=hy.phase, stationary_from_s=float(start_t),
        stationary_s=float(n_per * period), periods=n_per, transient_s=float(transient),
        control_period_s=T, period_g=[float(p) for p in per], warnings=warnings)
