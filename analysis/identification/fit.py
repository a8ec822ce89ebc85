r"""Fit any plant model to measurements by least squares on the windowed simulation error.

The error is the model's *free-run* simulation against the measurement over windows (default
2 s), each window started from the measured force (see :mod:`.windows` and :mod:`.metrics`); the
command history (delay line, valve and reversal states) runs continuously through the record. The
measured start of a window carries one noise draw that the whole window inherits, so the fit
re-estimates each window's starting force (its mean residual, a linear nuisance projected out
exactly) — the classic "initial state estimated with the parameters" of output-error
identification; it makes the parameters 5-10 times more precise than fitting through the noisy
start. For a model with parameters θ the fit solves

.. math::  \hat\theta = \arg\min_\theta \sum_{w}\sum_{k\in w}
           \big(\hat y_k(\theta) - y_k - \overline{(\hat y - y)}_w\big)^2

with :func:`scipy.optimize.least_squares` (trust-region reflective, bounds from each
:class:`~plant.params.Param`; parameters declared ``log=True`` are optimized as ``log θ``). The
delay τ is a continuous parameter (the model realises fractional delays exactly for a held
command).

Starting values, so that the fit does not depend on luck:

* the base ``g, Δ`` enter the windowed output linearly for every effect except ``load_pressure``
  (``ŷ = F + g·A + Δ·B``), so for any trial of the other parameters they are solved exactly from
  three simulations (*variable projection*);
* τ from a grid of delays (0 … 1 s) with ``g, Δ`` projected, refined by a bounded scalar search;
* each effect has a small grid of physically sensible starts (:meth:`plant.Effect.start_grid`, scaled to the
  data: command levels, force range, sample time); unknown effects get a grid from their
  parameter bounds. The best grid points are polished by ``least_squares``.

Confidence intervals come from the Jacobian at the solution with a *cluster-robust* (sandwich)
covariance, windows being the clusters: within a window the errors share the measured start and
any model error, so the naive ``s²(JᵀJ)⁻¹`` would be too narrow. Parameters at a bound or in a
direction the data do not determine (near-singular Jacobian) are reported as such, with
infinite/NaN intervals.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np
from scipy import optimize, stats
from scipy.optimize._numdiff import approx_derivative

from plant import PlantModel
from plant.params import ModelError, Param

from ..parallel import one_blas_thread
from ..records.record import Record
from .projection import project_gain_trend
from .starts import DataSummary, effect_starts, initial_delay, without
from .windows import (WINDOW_S, Piece, fresh_solutions, linearised_columns, pieces_from_records,
                      residual, subset_pieces, window_labels, window_sse)

#: relative tolerance on the cost and the step of the polishing least squares
FTOL = 1e-7
#: tolerance of the refit on all windows that follows a screening fit (starts near the optimum)
REFIT_TOL = 1e-5
#: looser tolerance for screening fits (ranking candidates needs the error to ~0.1 %, not more)
SCREEN_TOL = 1e-4
#: above this many windows, start values are searched on a subset of them (see
#: :func:`~.windows.subset_pieces`) and only the polish runs on all
SEARCH_WINDOWS = 150
#: relative finite-difference step of the Jacobian (in the optimizer's coordinates)
DIFF_STEP = 1e-6
#: the polish's Jacobian columns of a model whose rate depends on the force linearised about
#: the solution they are taken at, not solved (:func:`~.windows.linearised_columns`)
LINEARISED_COLUMNS = True


# ------------------------------------------------------------------------------------------
# parameter vector <-> model
# ------------------------------------------------------------------------------------------
class Parameterization:
    """Maps the free parameters of a model spec to the optimizer's vector ``x`` (log space for
    ``log=True`` parameters) and back."""

    def __init__(self, spec: str, values: Mapping[str, float], free: Sequence[str]) -> None:
        self.spec = spec
        self.values = dict(values)
        specs = dict(PlantModel.from_spec(spec, self.values).param_specs())
        self.specs: dict[str, Param] = specs
        self.free = [n for n in specs if n in set(free)]

    def _lo_hi(self, p: Param) -> tuple[float, float]:
        if p.log:
            lo = p.lower if p.lower > 0 else max(p.upper * 1e-12, 1e-300)
            return math.log(lo), math.log(p.upper)
        return p.lower, p.upper

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = zip(*(self._lo_hi(self.specs[n]) for n in self.free)) if self.free else ((), ())
        return np.array(lo, float), np.array(hi, float)

    def to_x(self, values: Mapping[str, float]) -> np.ndarray:
        x = []
        for n in self.free:
            p = self.specs[n]
            v = float(values[n])
            if p.log:
                v = math.log(max(v, p.lower if p.lower > 0 else 1e-300))
            x.append(v)
        lo, hi = self.bounds()
        return np.clip(np.array(x, float), lo, hi)

    def to_values(self, x: np.ndarray) -> dict[str, float]:
        out = dict(self.values)
        for n, v in zip(self.free, x):
            p = self.specs[n]
            v = math.exp(v) if p.log else float(v)
            out[n] = min(max(v, p.lower), p.upper)
        return out

    def model(self, x: np.ndarray) -> PlantModel:
        return PlantModel.from_spec(self.spec, self.to_values(x))


# ------------------------------------------------------------------------------------------
# the fit
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FitOptions:
    """How :func:`fit_model` searches; the defaults fit afresh, with confidence intervals."""

    #: search start values (the projections and grids of the module docstring) besides the
    #: model's own values; False: polish the model's values only
    search_starts: bool = True
    #: effects whose start grids are tried (None: all of the model's)
    grid_effects: tuple[str, ...] | None = None
    #: grid-search τ first (with g and Δ projected)
    delay_search: bool = True
    #: how many of the best starts are polished
    n_polish: int = 2
    #: further start values tried (parameter name -> value)
    extra_starts: tuple[Mapping[str, float], ...] = ()
    #: evaluations of the first polish (None: 40 per free parameter, plus 40)
    max_nfev: int | None = None
    #: relative tolerance of the polish (None: :data:`FTOL`; :data:`REFIT_TOL` for the polish
    #: on all windows after a search on a subset)
    tol: float | None = None
    #: confidence intervals (a fresh Jacobian at the solution)
    covariance: bool = True

    @classmethod
    def refit(cls, tol: float | None = None, covariance: bool = True) -> "FitOptions":
        """Polish the model's own values, no search: a fitted model fitted again (on all
        windows after a screening fit, or without one of its effects)."""
        return cls(search_starts=False, delay_search=False, tol=tol, covariance=covariance)

    @classmethod
    def add_effect(cls, effect: str) -> "FitOptions":
        """``model + effect`` screened from a fitted model: the new effect's start grid, the
        other parameters warm, no delay search, the screening tolerance, no intervals."""
        return cls(grid_effects=(effect,), delay_search=False, covariance=False, tol=SCREEN_TOL)


@dataclass
class ParamEstimate:
    """A fitted parameter with its 95 % confidence interval."""

    name: str
    value: float
    stderr: float             #: standard error in the parameter's unit (delta method), NaN if unknown
    low: float                #: 95 % interval (asymmetric for log parameters)
    high: float
    unit: str
    fixed: bool = False
    at_bound: bool = False
    identifiable: bool = True

    def to_dict(self) -> dict:
        def num(v):
            return None if v is None or (isinstance(v, float) and math.isnan(v)) else (
                ("inf" if v > 0 else "-inf") if math.isinf(v) else v)
        return {"value": self.value, "stderr": num(self.stderr), "ci_low": num(self.low),
                "ci_high": num(self.high), "unit": self.unit, "fixed": self.fixed,
                "at_bound": self.at_bound, "identifiable": self.identifiable}


@dataclass
class FitResult:
    """Outcome of :func:`fit_model`."""

    model: PlantModel
    estimates: dict[str, ParamEstimate]
    sse: float
    n: int                    #: evaluated samples
    n_windows: int
    objective_rmse: float     #: the fit's objective: windowed RMSE, window starts re-estimated, kgf
    nfev: int
    success: bool
    message: str
    window_sse: np.ndarray | None = field(default=None, repr=False)
    correlation: np.ndarray | None = field(default=None, repr=False)
    free: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def params(self) -> dict[str, float]:
        return self.model.params()

    def non_identifiable(self) -> list[str]:
        return [n for n, e in self.estimates.items() if not e.fixed and not e.identifiable]


def _polish(par: Parameterization, pieces: Sequence[Piece], values: Mapping[str, float],
            max_nfev: int | None, tol: float = 1e-7) -> tuple[np.ndarray, optimize.OptimizeResult]:
    lo, hi = par.bounds()
    x0 = par.to_x(values)
    # keep x0 strictly inside the bounds (TRF requirement)
    eps = 1e-9 * np.maximum(1.0, np.abs(hi - lo))
    x0 = np.clip(x0, lo + eps, hi - eps)

    def simulate(x):
        return residual(par.model(x), pieces)

    last: list = []                    # (x, residual) of the last simulation

    def fun(x):
        r = simulate(x)
        last[:] = [np.array(x, copy=True), r]
        return r

    def jac(x):
        """scipy's forward differences (the same steps), their columns linearised about the
        solution at ``x`` (:func:`~.windows.linearised_columns`)."""
        if not last or not np.array_equal(last[0], x):
            fun(x)
        with linearised_columns():
            return approx_derivative(simulate, x, method="2-point", rel_step=DIFF_STEP,
                                     f0=last[1], bounds=(lo, hi))

    if max_nfev is None:
        max_nfev = 40 * (len(x0) + 1)
    linearised = LINEARISED_COLUMNS and PlantModel.from_spec(par.spec).depends_on_force
    res = optimize.least_squares(fun, x0, jac=jac if linearised else "2-point", bounds=(lo, hi),
                                 method="trf", x_scale="jac",
                                 tr_solver="lsmr" if len(x0) and _n_eval(pieces) > 400_000 else "exact",
                                 diff_step=DIFF_STEP, max_nfev=max_nfev, ftol=tol, xtol=tol)
    return res.x, res


def _n_eval(pieces: Sequence[Piece]) -> int:
    return sum(p.n_eval for p in pieces)


def _as_model(model: PlantModel | str) -> PlantModel:
    return PlantModel.from_spec(model) if isinstance(model, str) else model


@one_blas_thread
def fit_model(data: Sequence[Record] | Sequence[Piece], model: PlantModel | str, *,
              window_s: float = WINDOW_S, fixed: Iterable[str] = (),
              options: FitOptions | None = None) -> FitResult:
    """Fit ``model`` (a spec like ``"base+reversal"`` or a :class:`PlantModel` whose values are
    a start) to records (or prepared pieces) by least squares on the windowed free-run error.

    ``window_s``: the windows' length (records only; pieces come cut). ``fixed``: parameter
    names kept at their given values. ``options``: how the fit searches (:class:`FitOptions`;
    default: start values searched, intervals computed). With more than
    :data:`SEARCH_WINDOWS` windows the starts are searched (and polished loosely) on a subset
    of them, then polished on all. Returns a :class:`FitResult` with confidence intervals."""
    opt = options or FitOptions()
    fresh_solutions()
    model = _as_model(model)
    pieces = _as_pieces(data, window_s)
    search, searched_subset = (subset_pieces(pieces, SEARCH_WINDOWS) if opt.search_starts
                               else (pieces, False))
    spec = model.spec
    fixed = set(fixed)
    unknown = fixed - set(model.params())
    if unknown:
        raise ModelError(f"cannot fix {', '.join(sorted(unknown))}: model {spec} has no such parameter")
    free = [n for n in model.params() if n not in fixed]
    given = model.params()
    candidates: list[tuple[float, dict]] = []
    fit_g, fit_d = "g" not in fixed, "delta" not in fixed

    def project(vals):
        return project_gain_trend(spec, vals, search, fit_g, fit_d)

    if not free:
        r = residual(model, pieces)
        return _result(model, Parameterization(spec, given, []), pieces, r, 0, True,
                       "all parameters fixed", covariance=False)
    candidates.append(project(given)[::-1])
    for s in opt.extra_starts:
        vals = {**given, **{k: v for k, v in s.items() if k in given and k not in fixed}}
        candidates.append(project(vals)[::-1])
    if opt.search_starts:
        base_vals = dict(given)
        if opt.delay_search and "tau" not in fixed:
            tv, _ = initial_delay(search, spec, given)
            base_vals.update({k: tv[k] for k in ("g", "tau", "delta") if k not in fixed})
            candidates.append(project(base_vals)[::-1])
        names = [e.name for e in model.effects] if opt.grid_effects is None else list(opt.grid_effects)
        summary = DataSummary.of(search, without(spec, base_vals, names))
        for name in names:
            for s in effect_starts(name, summary, base_vals):
                vals = {**base_vals, **{k: v for k, v in s.items() if k not in fixed}}
                try:
                    PlantModel.from_spec(spec, vals)
                except ModelError:
                    continue
                candidates.append(project(vals)[::-1])
    candidates.sort(key=lambda c: c[0])
    par = Parameterization(spec, given, free)
    best = None
    seen = []
    for sse0, vals in candidates:
        if len(seen) >= opt.n_polish:
            break
        key = tuple(np.round(par.to_x(vals), 6))
        if key in seen:
            continue
        if seen and sse0 > 1.05 * candidates[0][0] and not (opt.grid_effects and len(seen) < 2):
            # further starts are clearly worse: one polish is enough. Except for an effect added
            # to a fitted model: its best start is often the effect switched off (the model as
            # it was), a point the polish may not leave while the model's other effects hold
            # the error it would explain (a dead zone after a flow curve): polish one more
            break
        budget = opt.max_nfev if not seen else min(opt.max_nfev or 10 ** 9, 15 * (len(free) + 1))
        seen.append(key)
        x, res = _polish(par, search, vals, budget, (FTOL if opt.tol is None else opt.tol)
                         if not searched_subset else SCREEN_TOL)
        if best is None or res.cost < best[1].cost:
            best = (x, res)
    x, res = best
    if searched_subset:  # the starts were searched on a subset of the windows: polish on all
        vals = par.to_values(x)
        sse_all = residual(par.model(x), pieces)
        candidates = [(float(sse_all @ sse_all), vals)]
        x, res = _polish(par, pieces, vals, opt.max_nfev, REFIT_TOL if opt.tol is None else opt.tol)
    # never worse than the best start (a polish can stall in a flat, non-identifiable valley)
    sse_best, vals_best = candidates[0]
    if 2 * res.cost > sse_best * (1 + 1e-9):
        x = par.to_x(vals_best)
        r = residual(par.model(x), pieces)
        return _result(par.model(x), par, pieces, r, res.nfev, False,
                       "kept the best start value: the polish did not improve on it",
                       covariance=opt.covariance)
    fitted = par.model(x)
    return _result(fitted, par, pieces, res.fun, res.nfev, bool(res.success),
                   str(res.message), covariance=opt.covariance)


def _jacobian(par: Parameterization, pieces: Sequence[Piece], x: np.ndarray,
              r: np.ndarray) -> np.ndarray:
    """Forward-difference Jacobian of the objective residual in the optimizer's coordinates."""
    lo, hi = par.bounds()
    J = np.empty((len(r), len(x)))
    for i in range(len(x)):
        h = DIFF_STEP * max(1.0, abs(x[i]))
        xi = x.copy()
        if xi[i] + h > hi[i]:
            h = -h
        xi[i] += h
        J[:, i] = (residual(par.model(xi), pieces) - r) / h
    return J


def _as_pieces(data, window_s: float) -> list[Piece]:
    data = list(data)
    if data and isinstance(data[0], Piece):
        return data
    return pieces_from_records(data, window_s)


def _result(model: PlantModel, par: Parameterization, pieces: Sequence[Piece], r: np.ndarray,
            nfev: int, success: bool, message: str, covariance: bool = True) -> FitResult:
    """Package a solution: per-window errors, intervals from a fresh forward-difference Jacobian
    at the solution (parameters at a bound are held there and get no interval)."""
    labels = window_labels(pieces)
    nw = int(labels[-1]) + 1 if len(labels) else 0
    wsse = window_sse(r, pieces)
    sse = float(r @ r)
    n = len(r)
    specs = dict(model.param_specs())
    values = model.params()
    est: dict[str, ParamEstimate] = {}
    corr = None
    warnings: list[str] = []
    lo_b, hi_b = par.bounds()
    x = par.to_x(values) if par.free else np.array([])
    span = hi_b - lo_b
    at_bound = (x - lo_b < 1e-6 * np.maximum(1.0, span)) | (hi_b - x < 1e-6 * np.maximum(1.0, span))
    inner = [i for i in range(len(par.free)) if not at_bound[i]]
    cov_x = None
    singular = np.zeros(len(par.free), bool)
    if covariance and inner:
        # the Jacobian of the interior parameters (those at a bound are held there)
        sub = Parameterization(par.spec, values, [par.free[i] for i in inner])
        J = _jacobian(sub, pieces, sub.to_x(values), r)
        cov_i, corr_i, sing_i = _cluster_covariance(J, r, labels, nw)
        cov_x = np.full((len(par.free), len(par.free)), np.nan)
        corr = np.full_like(cov_x, np.nan)
        if cov_i is not None:
            cov_x[np.ix_(inner, inner)] = cov_i
            corr[np.ix_(inner, inner)] = corr_i
        singular[inner] = sing_i
    tq = stats.t.ppf(0.975, max(1, nw - len(par.free))) if nw > len(par.free) else math.inf
    for name, p in specs.items():
        v = values[name]
        if name not in par.free:
            est[name] = ParamEstimate(name, v, math.nan, math.nan, math.nan, p.unit, fixed=True)
            continue
        i = par.free.index(name)
        if at_bound[i]:
            est[name] = ParamEstimate(name, v, math.nan, math.nan, math.nan, p.unit, at_bound=True)
            shown = p.lower if abs(v - p.lower) <= abs(v - p.upper) else p.upper   # not 1.7e-16
            unit = "" if p.unit == "1" else f" {p.unit}"       # "1": dimensionless
            warnings.append(f"{name} = {shown:g}{unit} sits at its bound [{p.lower:g}, {p.upper:g}]")
            continue
        sd = math.sqrt(cov_x[i, i]) if cov_x is not None and np.isfinite(cov_x[i, i]) and cov_x[i, i] >= 0 \
            else math.nan
        ident = not singular[i] and math.isfinite(sd) if covariance else True
        if not covariance:
            low = high = se = math.nan
        elif not ident:
            low, high, se = -math.inf, math.inf, math.inf
        elif p.log:
            k = min(tq * sd, 700.0)
            low, high = v * math.exp(-k), v * math.exp(k)
            se = v * sd
        else:
            low, high, se = v - tq * sd, v + tq * sd, sd
        if ident and covariance:
            low, high = max(low, p.lower), min(high, p.upper)
        est[name] = ParamEstimate(name, v, se, low, high, p.unit, identifiable=ident)
        if not ident:
            warnings.append(f"{name} is not identifiable from these data (the error does not "
                            "change along it, or only together with another parameter)")
    return FitResult(model=model, estimates=est, sse=sse, n=n, n_windows=nw,
                     objective_rmse=math.sqrt(sse / max(n, 1)), nfev=nfev, success=success, message=message,
                     window_sse=wsse, correlation=corr, free=list(par.free), warnings=warnings)


def _cluster_covariance(J: np.ndarray, r: np.ndarray, labels: np.ndarray,
                        nw: int) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
    """Sandwich covariance ``(JᵀJ)⁻¹ (Σ_w s_w s_wᵀ) (JᵀJ)⁻¹``, ``s_w = J_wᵀ r_w`` (windows as
    clusters, small-sample factor ``nw/(nw − p)``). Returns (cov, correlation, singular mask)."""
    p = J.shape[1]
    scale = np.sqrt((J * J).sum(axis=0))
    scale[scale == 0] = 1.0
    Js = J / scale
    U, sv, Vt = np.linalg.svd(Js, full_matrices=False)
    singular = np.zeros(p, bool)
    if sv.size == 0 or sv[0] == 0:
        return None, None, np.ones(p, bool)
    weak = sv < 1e-7 * sv[0]
    for k in np.flatnonzero(weak):
        singular |= np.abs(Vt[k]) > 0.1
    inv = (Vt.T / np.where(weak, np.inf, sv) ** 2) @ Vt            # (JsᵀJs)⁺
    S = np.zeros((nw, p))
    for j in range(p):
        S[:, j] = np.bincount(labels, weights=Js[:, j] * r, minlength=nw)
    meat = S.T @ S * (nw / max(nw - p, 1))
    cov_s = inv @ meat @ inv
    cov = cov_s / np.outer(scale, scale)
    d = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(d, d)
    cov[singular, :] = np.nan
    cov[:, singular] = np.nan
    return cov, corr, singular
