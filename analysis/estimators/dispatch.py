"""One entry point for the paper's three estimators: which experiment is this, and its estimates.

The experiment is taken from the run's metadata (``run.json``) when there is one; for a CSV it is
recognised from the signals (:func:`detect_experiment`):

* **pfeedback** — a reference that is a sinusoid and a command that is ``k·(r − y)``
  (a least-squares fit explains ≥ 90 % of its variance);
* **relay** — a command on a few levels (each held by ≥ 5 % of the samples, ≥ 60 % in all)
  switching sign, whose sign follows the sign of ``r − y`` (r, or the middle of the force if
  there is no r) at least 75 % of the time;
* **meander** — the same kind of command, open loop: its sign agrees with ``r − y`` at most
  65 % of the time (about half: it switches at the force's extremes, not at its middle).

Anything else is refused with the features that were measured: say which experiment it is.

:func:`result_json` gives the stable JSON form printed by ``stand estimate --json`` (schema
``hydrostand-estimate/1``, documented in ``docs/experiments.md``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Union

import numpy as np

from gateway.errors import DataError

from ..records.load import load
from ..records.record import Record, split_at_gaps
from .meander import MeanderEstimate, estimate_meander, mean_ci
from .pfeedback import PFeedbackEstimate, estimate_pfeedback, fit_harmonic, reference_frequency, sine_start
from .relay import RelayEstimate, estimate_relay, relay_levels

SCHEMA = "hydrostand-estimate/1"
from ..defaults import EXPERIMENT_NAMES  # noqa: E402  (re-exported)

Result = Union[MeanderEstimate, PFeedbackEstimate, RelayEstimate]


@dataclass
class EstimateOptions:
    """Optional overrides for the estimators (None: from the run's metadata or the data)."""

    experiment: str | None = None          #: force the experiment instead of detecting it
    hysteresis_kgf: float | None = None    #: relay hysteresis ε
    control_period_s: float | None = None  #: control period T (relay and P-feedback corrections)
    omega_rad_s: float | None = None       #: P-feedback ω
    gain: float | None = None              #: P-feedback k
    transitional_s: float | None = None    #: meander transitional window


@dataclass
class Detection:
    experiment: str
    detected_from: str                     #: "metadata" | "signals" | "option"
    reason: str


@dataclass
class Estimate:
    """An estimate of one input: what it was, how we know, and the estimator's result."""

    source: str
    detection: Detection
    result: Result
    notes: list[str] = field(default_factory=list)

    @property
    def experiment(self) -> str:
        return self.detection.experiment

    @property
    def g(self) -> float:
        return self.result.g

    @property
    def tau(self) -> float | None:
        return self.result.tau


# -- detection ---------------------------------------------------------------------------------
def detect_experiment(rec: Record) -> Detection:
    """Which of the paper's experiments a record is; :class:`DataError` if it cannot tell."""
    if rec.experiment in EXPERIMENT_NAMES:
        return Detection(rec.experiment, "metadata", f"run metadata names the experiment {rec.experiment!r}")
    feats = signal_features(rec)
    if feats["sinusoidal_reference"] and feats["proportional_fit_r2"] >= 0.9:
        return Detection("pfeedback", "signals",
                         f"sinusoidal reference (ω ≈ {feats['reference_omega']:.4g} rad/s) and u ≈ "
                         f"{feats['proportional_gain']:.3g}·(r − y) (R² = {feats['proportional_fit_r2']:.2f})")
    if feats["piecewise_constant"] >= 0.6 and feats["sign_changes"] >= 4:
        agree = feats["relay_agreement"]
        if agree >= 0.75:
            return Detection("relay", "signals",
                             f"command on two levels ±{feats['u0']:.3g} % whose sign follows r − y "
                             f"{agree:.0%} of the time")
        if agree <= 0.65:
            return Detection("meander", "signals",
                             f"piecewise-constant open-loop command with {feats['sign_changes']} sign "
                             f"changes, independent of r − y (agreement {agree:.0%})")
    summary = ", ".join(f"{k} = {_fmt(v)}" for k, v in feats.items())
    raise DataError(
        f"{rec.source}: cannot tell which experiment this is (meander, pfeedback or relay); "
        f"measured {summary}. Name it with --experiment")


def _fmt(v: Any) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def signal_features(rec: Record) -> dict[str, Any]:
    """The numbers :func:`detect_experiment` decides on."""
    u, y, r = rec.u, rec.y, rec.r
    n = len(u)
    # command levels: values of u held by at least 5 % of the samples each
    values, counts = np.unique(np.round(u, 6), return_counts=True)
    frequent = values[(counts >= 0.05 * n) & (values != 0)]
    on_any = np.isin(np.round(u, 6), frequent)
    piecewise = float(on_any.mean())
    s = np.sign(u[on_any])
    sign_changes = int(np.count_nonzero(s[1:] != s[:-1]))
    u0 = relay_levels(u)
    on_levels = np.abs(np.abs(u) - u0) <= max(1e-3 * u0, 1e-6) if math.isfinite(u0) else np.zeros(n, bool)
    ref = np.where(np.isfinite(r), r, np.median(y[on_levels]) if on_levels.any() else np.median(y))
    if on_levels.any():
        agreement = float(np.mean(np.sign(u[on_levels]) == np.sign(ref[on_levels] - y[on_levels])))
    else:
        agreement = math.nan
    feats: dict[str, Any] = {"u0": u0, "piecewise_constant": float(piecewise), "sign_changes": sign_changes,
                             "relay_agreement": agreement, "sinusoidal_reference": False,
                             "reference_omega": math.nan, "proportional_gain": math.nan,
                             "proportional_fit_r2": math.nan}
    finite = np.isfinite(r)
    if finite.sum() >= 20 and np.ptp(r[finite]) > 0:
        i0 = sine_start(r)
        tt, rr = rec.t[i0:][finite[i0:]], r[i0:][finite[i0:]]
        if len(tt) >= 20:
            w = reference_frequency(tt, rr)
            h = fit_harmonic(tt, rr, w)
            X = np.column_stack([np.sin(w * tt), np.cos(w * tt), np.ones_like(tt)])
            res = rr - X @ np.linalg.lstsq(X, rr, rcond=None)[0]
            feats["reference_omega"] = w
            feats["sinusoidal_reference"] = bool(h.amplitude > 0 and np.std(res) < 0.05 * h.amplitude
                                                 and (tt[-1] - tt[0]) * w >= 2 * math.pi)
        e = (r - y)[finite]
        uu = u[finite]
        if float(e @ e) > 0:
            X = np.column_stack([e, np.ones_like(e)])
            coef = np.linalg.lstsq(X, uu, rcond=None)[0]
            res = uu - X @ coef
            var = float(np.var(uu))
            feats["proportional_gain"] = float(coef[0])
            feats["proportional_fit_r2"] = float(1 - np.var(res) / var) if var > 0 else math.nan
    return feats


# -- estimation --------------------------------------------------------------------------------
def estimate_record(rec: Record, options: EstimateOptions | None = None) -> Estimate:
    """Detect the experiment (unless given) and run its estimator. A record with gaps (samples
    missing) is estimated on its longest part between them (said in the notes): the paper's
    estimators read slopes and cycles that a bridged gap would fake."""
    opt = options or EstimateOptions()
    parts = split_at_gaps(rec)
    if len(parts) > 1:
        longest = max(parts, key=len)
        longest.notes.append(f"the data has gaps: estimated on its longest part "
                             f"({longest.duration_s:.1f} s of {rec.duration_s:.1f} s, {longest.source})")
        rec = longest
    if opt.experiment:
        if opt.experiment not in EXPERIMENT_NAMES:
            raise DataError(f"unknown experiment {opt.experiment!r}; choose one of {', '.join(EXPERIMENT_NAMES)}")
        det = Detection(opt.experiment, "option", "named on the command line")
    else:
        det = detect_experiment(rec)
    if det.experiment == "meander":
        result: Result = estimate_meander(rec, transitional_s=opt.transitional_s)
    elif det.experiment == "relay":
        result = estimate_relay(rec, hysteresis_kgf=opt.hysteresis_kgf, control_period_s=opt.control_period_s)
    else:
        result = estimate_pfeedback(rec, omega_rad_s=opt.omega_rad_s, gain=opt.gain,
                                    control_period_s=opt.control_period_s)
    return Estimate(rec.source, det, result, list(rec.notes))


def estimate_path(path: str | Path, options: EstimateOptions | None = None) -> Estimate:
    return estimate_record(load(path), options)


# -- JSON ----------------------------------------------------------------------------------------
def _num(x: Any) -> Any:
    if x is None:
        return None
    if isinstance(x, (list, tuple)):
        return [_num(v) for v in x]
    if isinstance(x, dict):
        return {k: _num(v) for k, v in x.items()}
    if isinstance(x, (bool, str)):
        return x
    try:
        f = float(x)
    except (TypeError, ValueError):
        return x
    if isinstance(x, (int, np.integer)) and not isinstance(x, bool):
        return int(x)
    return f if math.isfinite(f) else None


def _ci(ci: tuple[float, float] | None) -> list | None:
    if ci is None or not all(math.isfinite(v) for v in ci):
        return None
    return [float(ci[0]), float(ci[1])]


def estimates_dict(result: Result) -> dict[str, Any]:
    """The ``estimates`` object of the JSON: ``g``, ``g_ci``, ``tau``, ``tau_ci``, ``delta``
    (the recommended values) and the paper's formulas under their own keys."""
    if isinstance(result, MeanderEstimate):
        tr = [s.g_transitional for s in result.segments]
        g_tr, lo, hi = mean_ci(tr)
        out = {"g": result.g, "g_ci": _ci(result.g_ci), "tau": result.tau, "tau_ci": None,
               "delta": result.delta, "g_eq2_main": result.g,
               "g_eq2_transitional": g_tr, "g_eq2_transitional_ci": _ci((lo, hi)),
               "transitional_ratio": g_tr / result.g if result.g else None,
               "transitional_s": result.transitional_s,
               "transitional_detected": result.transitional_detected,
               "amplitudes_pct": sorted({p.amplitude_pct for p in result.portions})}
        for name in ("main_rise", "main_fall", "transitional_rise", "transitional_fall"):
            vals = [p for p in result.portions if p.portion == name]
            out[f"g_eq2_{name}"] = float(np.mean([p.g for p in vals])) if vals else None
        return _num(out)
    if isinstance(result, RelayEstimate):
        return _num({"g": result.g, "g_ci": _ci(result.g_ci), "tau": result.tau, "tau_ci": _ci(result.tau_ci),
                     "delta": result.delta, "g_eq4_peak": result.g_df_peak,
                     "g_eq4_harmonic": result.g_df_harmonic, "tau_eq4": result.tau_df,
                     "eq4_peak_bias": result.df_bias, "amplitude_pct": result.amplitude_pct,
                     "reference_kgf": result.reference_kgf, "hysteresis_kgf": result.hysteresis_kgf,
                     "period_s": result.period_s, "peak_kgf": result.peak_kgf,
                     "first_harmonic_kgf": result.first_harmonic_kgf,
                     "sampling_correction_s": result.sampling_correction_s, "cycles": result.cycles})
    return _num({"g": result.g, "g_ci": _ci(result.g_ci), "tau": result.tau, "tau_ci": None,
                 "delta": None, "g_eq3": result.g, "omega_rad_s": result.omega_rad_s,
                 "reference_kgf": result.reference_kgf, "gain": result.gain,
                 "amplitude_u_pct": result.amplitude_u_pct, "amplitude_y_kgf": result.amplitude_y_kgf,
                 "stationary_from_s": result.stationary_from_s, "periods": result.periods})


def details_dict(result: Result) -> dict[str, Any]:
    if isinstance(result, MeanderEstimate):
        return _num({"portions": result.table()})
    if isinstance(result, RelayEstimate):
        return _num({"asymmetry": result.asymmetry, "rise_s": result.rise_s, "fall_s": result.fall_s,
                     "slope_rise": result.slope_rise, "slope_fall": result.slope_fall,
                     "peak_above_kgf": result.peak_above_kgf, "trough_below_kgf": result.trough_below_kgf,
                     "plus_s": result.plus_s, "minus_s": result.minus_s, "start_s": result.start_s,
                     "control_period_s": result.control_period_s})
    return _num({"phase_u": result.phase_u, "phase_y": result.phase_y, "transient_s": result.transient_s,
                 "stationary_s": result.stationary_s, "period_g": result.period_g,
                 "control_period_s": result.control_period_s})


def result_json(est: Estimate) -> dict[str, Any]:
    """One input's JSON object (schema ``hydrostand-estimate/1``)."""
    return {"schema": SCHEMA, "source": est.source, "experiment": est.experiment,
            "detected_from": est.detection.detected_from, "detection": est.detection.reason,
            "estimates": estimates_dict(est.result), "details": details_dict(est.result),
            "warnings": list(est.result.warnings), "notes": list(est.notes), "error": None}


def error_json(source: str, message: str) -> dict[str, Any]:
    """The JSON object for an input that could not be estimated."""
    return {"schema": SCHEMA, "source": source, "experiment": None, "detected_from": None,
            "detection": None, "estimates": None, "details": None, "warnings": [], "notes": [],
            "error": message}
