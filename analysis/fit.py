r"""Fit any plant model to measurements by least squares on the windowed simulation error.

The error is the model's *free-run* simulation against the measurement over windows (default
2 s), each window started from the measured force (see :mod:`analysis.metrics`); the command
history (delay line, valve and reversal states) runs continuously through the record. The
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

from gateway.errors import DataError
from plant import PlantModel
from plant.model import Drive
from plant.params import ModelError, Param

from .records.limits import held_mask
from .records.record import Record
from .parallel import one_blas_thread

#: default window of the free-run error, s
from .defaults import WINDOW_S  # noqa: E402  (re-exported)
#: lead-in at the start of every record, s: the commands before a record are unknown, so its
#: first samples only prime the command history (delay line, valve and reversal states)
LEAD_S = 0.5
#: relative tolerance on the cost and the step of the polishing least squares
FTOL = 1e-7
#: tolerance of the refit on all windows that follows a screening fit (starts near the optimum)
REFIT_TOL = 1e-5
#: looser tolerance for screening fits (ranking candidates needs the error to ~0.1 %, not more)
SCREEN_TOL = 1e-4
#: above this many windows, start values are searched on a subset of them (see
#: :func:`subset_pieces`) and only the polish runs on all
SEARCH_WINDOWS = 150
#: relative finite-difference step of the Jacobian (in the optimizer's coordinates)
DIFF_STEP = 1e-6


# ------------------------------------------------------------------------------------------
# data pieces and the windowed simulation
# ------------------------------------------------------------------------------------------
@dataclass
class Piece:
    """A contiguous stretch of one record, simulated in one pass.

    The first ``warmup`` samples only prime the command history (delay line, valve and
    reversal states); the error is taken from there on, in windows of ``window`` samples each
    started from the measured force."""

    u: np.ndarray
    y: np.ndarray
    dt: float
    window: int
    warmup: int = 0
    record: int = 0           #: index of the record in the data set
    start: int = 0            #: index of u[0] in the record
    t0: float = 0.0           #: time of u[0] since the record's first sample, s

    @property
    def n_eval(self) -> int:
        return len(self.u) - self.warmup

    @property
    def n_windows(self) -> int:
        return -(-self.n_eval // self.window)

    def window_index(self) -> np.ndarray:
        """Window number (within the piece) of every evaluated sample."""
        return np.arange(self.n_eval) // self.window

    def horizon(self) -> np.ndarray:
        """Samples since the start of the window, for every evaluated sample."""
        return np.arange(self.n_eval) % self.window


def window_samples(dt: float, window_s: float) -> int:
    return max(2, int(round(window_s / dt)))


def lead_samples(n: int, dt: float, window: int, lead_s: float = LEAD_S) -> int:
    """Lead-in of a record: ``lead_s``, but at most a quarter window and a tenth of the record."""
    return int(min(round(lead_s / dt), window // 4, n // 10))


def clipped_mask(y: np.ndarray, run: int = 5) -> np.ndarray:
    """Samples where the dynamometer sits at the record's extreme value for ``run`` or more
    samples in a row: a reading clipped at its range (the true force is unknown there)."""
    y = np.asarray(y, float)
    mask = np.zeros(len(y), bool)
    for extreme in (y.max(), y.min()):
        at = np.concatenate([[0], (y == extreme).astype(int), [0]])
        edges = np.flatnonzero(np.diff(at))
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a >= run:
                mask[a:b] = True
    return mask


def valid_stretches(rec: Record, min_samples: int) -> list[tuple[int, int]]:
    """``(start, stop)`` of the stretches of a record whose force reading is not clipped and not
    held at a hydraulic limit (:mod:`analysis.records.limits`), at least ``min_samples`` long."""
    bad = clipped_mask(rec.y) | held_mask(rec.u, rec.y, rec.dt)
    if not bad.any():
        return [(0, len(rec.y))]
    z = np.concatenate([[1], bad.astype(int), [1]])
    edges = np.flatnonzero(np.diff(z))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2]) if b - a >= min_samples]


def pieces_from_records(records: Sequence[Record], window_s: float = WINDOW_S,
                        lead_s: float = LEAD_S) -> list[Piece]:
    """The evaluated pieces of a data set: one per record, after its lead-in, or one per
    unclipped stretch when the force reading hits the dynamometer's range (the clipped samples
    only carry the command history into the next stretch)."""
    if not records:
        raise DataError("no data to fit")
    out = []
    for i, rec in enumerate(records):
        n = len(rec.u)
        w = window_samples(rec.dt, window_s)
        lead = lead_samples(n, rec.dt, w, lead_s)
        stretches = valid_stretches(rec, max(2, w // 4))
        if stretches == [(0, n)]:
            out.append(Piece(rec.u, rec.y, rec.dt, max(2, min(w, n - lead)), lead, i, 0, 0.0))
            continue
        for a, b in stretches:
            first = max(a, lead)
            if b - first < 2:
                continue
            s0 = max(0, first - max(lead, int(round(lead_s / rec.dt))))
            out.append(Piece(rec.u[s0:b], rec.y[s0:b], rec.dt, max(2, min(w, b - first)),
                             first - s0, i, s0, float(rec.t[s0] - rec.t[0])))
    if not out:
        raise DataError("no usable data: every record is too short or its force reading is "
                        "clipped at the dynamometer's range throughout")
    return out


def screening_pieces(records: Sequence[Record], window_s: float = WINDOW_S,
                     max_windows: int = 150, chunk_windows: int = 10,
                     warmup_s: float = 1.0) -> tuple[list[Piece], bool]:
    """A subset of windows for fast screening: all windows if there are at most ``max_windows``,
    else evenly spread chunks of ``chunk_windows`` windows, each with ``warmup_s`` of command
    history before it. Returns ``(pieces, is_subset)``."""
    return subset_pieces(pieces_from_records(records, window_s), max_windows, chunk_windows,
                         warmup_s)


def subset_pieces(full: Sequence[Piece], max_windows: int = 150, chunk_windows: int = 10,
                  warmup_s: float = 1.0) -> tuple[list[Piece], bool]:
    """See :func:`screening_pieces` (same, from prepared pieces)."""
    full = list(full)
    total = sum(p.n_windows for p in full)
    if total <= max_windows:
        return full, False
    n_chunks = max(1, max_windows // chunk_windows)
    # chunks per piece in proportion to its windows
    share = np.array([p.n_windows for p in full], float)
    alloc = np.floor(n_chunks * share / share.sum()).astype(int)
    out: list[Piece] = []
    for p, n in zip(full, alloc):
        if n <= 0:
            continue
        W = p.window
        span = chunk_windows * W
        warm = int(round(warmup_s / p.dt))
        N = len(p.u)
        if N - p.warmup <= span or n * span >= N - p.warmup:
            out.append(p)
            continue
        starts = np.linspace(p.warmup, N - span, n).astype(int)
        for s in starts:
            a = max(0, s - warm)
            out.append(Piece(p.u[a:s + span], p.y[a:s + span], p.dt, W, s - a, p.record,
                             p.start + a, p.t0 + a * p.dt))
    return (out, True) if out else (full, False)


def _cut_windows(model: PlantModel, piece: Piece) -> tuple[Drive, np.ndarray, list[dict] | None]:
    """The piece's drive (delay, valve, flow preparation over the whole piece, so the command
    history runs through) cut into its evaluated windows, the measured starts, and the sensor
    filters' states at the starts (None without SENSOR effects)."""
    u, y, dt, W, a = piece.u, piece.y, piece.dt, piece.window, piece.warmup
    state = model.new_state(1, dt, 0.0, u[0], piece.t0)
    drv = model.drive(u[None, :], dt, state)
    n = len(u) - a
    nw = -(-n // W)
    pad = nw * W - n

    def cut(arr):
        if arr is None:
            return None
        arr = arr[0, a:]
        if pad:
            arr = np.concatenate([arr, np.repeat(arr[-1:], pad)])
        return arr.reshape(nw, W)

    wdrv = Drive(q=cut(drv.q), aux=[cut(x) for x in drv.aux], dist=cut(drv.dist))
    steps = a + np.arange(nw) * W
    sensor = model.window_filter_states(drv, y, dt, steps) if model.has_sensor_effects else None
    return wdrv, y[steps], sensor


def simulate_pieces(model: PlantModel, pieces: Sequence[Piece]) -> list[np.ndarray]:
    """Windowed free-run simulation of several pieces: ŷ for the evaluated samples of each.

    Pieces with the same sample time and window length are integrated together, all their
    windows side by side (one pass of the integrator, however many pieces)."""
    out: list[np.ndarray | None] = [None] * len(pieces)
    groups: dict[tuple[float, int], list[int]] = {}
    for i, p in enumerate(pieces):
        groups.setdefault((p.dt, p.window), []).append(i)
    for (dt, W), idx in groups.items():
        cuts = [_cut_windows(model, pieces[i]) for i in idx]
        if len(cuts) == 1:
            drv, starts, sensor = cuts[0]
        else:
            def cat(arrs):
                return None if arrs[0] is None else np.concatenate(arrs, axis=0)
            drv = Drive(q=np.concatenate([c[0].q for c in cuts], axis=0),
                        aux=[cat([c[0].aux[j] for c in cuts]) for j in range(len(cuts[0][0].aux))],
                        dist=cat([c[0].dist for c in cuts]))
            starts = np.concatenate([c[1] for c in cuts])
            sensor = None if cuts[0][2] is None else [
                {k: np.concatenate([c[2][j][k] for c in cuts]) for k in cuts[0][2][j]}
                for j in range(len(cuts[0][2]))]
        yy = model.integrate_from_readings(drv, starts, dt, sensor)[:, :-1]
        row = 0
        for i, (d, _, _) in zip(idx, cuts):
            k = d.q.shape[0]
            out[i] = yy[row:row + k].reshape(-1)[:pieces[i].n_eval]
            row += k
    return out  # type: ignore[return-value]


def simulate_piece(model: PlantModel, piece: Piece) -> np.ndarray:
    """Windowed free-run simulation of one piece: ŷ for the evaluated samples (after warm-up).

    Same computation as :meth:`PlantModel.simulate_windows` (which it equals for
    ``warmup = 0``), with the windows starting after the warm-up."""
    return simulate_pieces(model, [piece])[0]


def window_means(r: np.ndarray, W: int) -> np.ndarray:
    """Mean of ``r`` over consecutive windows of ``W`` samples (the last may be shorter)."""
    n = len(r)
    full = n // W
    nw = -(-n // W)
    out = np.empty(nw)
    if full:
        out[:full] = r[:full * W].reshape(full, W).mean(axis=1)
    if nw > full:
        out[-1] = r[full * W:].mean()
    return out


def demean_windows(r: np.ndarray, W: int) -> np.ndarray:
    """``r`` minus its mean in each window of ``W`` samples."""
    m = window_means(r, W)
    out = np.array(r, float, copy=True)
    full = len(r) // W
    if full:
        out[:full * W].reshape(full, W)[:] -= m[:full, None]
    if len(m) > full:
        out[full * W:] -= m[-1]
    return out


def residual(model: PlantModel, pieces: Sequence[Piece], adjust_start: bool = True) -> np.ndarray:
    """ŷ − y over all evaluated samples of all pieces, concatenated.

    ``adjust_start=True`` (the fit's objective): each window's starting force is re-estimated,
    i.e. the window's mean residual is removed. The measured start carries one noise draw
    ``e_0`` that the whole window inherits; fitting through it biases the parameters toward that
    draw (five to ten times larger parameter errors in tests). ``False``: the error from the
    measured start, as reported by :mod:`analysis.metrics`."""
    out = []
    for p, yhat in zip(pieces, simulate_pieces(model, pieces)):
        r = yhat - p.y[p.warmup:]
        out.append(demean_windows(r, p.window) if adjust_start else r)
    return np.concatenate(out) if len(out) > 1 else out[0]


def errors(model: PlantModel, pieces: Sequence[Piece]) -> tuple[np.ndarray, float]:
    """From one simulation: the objective's squared error per window (starts re-estimated) and
    the RMSE from the measured starts."""
    raw = residual(model, pieces, adjust_start=False)
    adj, k = [], 0
    for p in pieces:
        adj.append(demean_windows(raw[k:k + p.n_eval], p.window))
        k += p.n_eval
    return window_sse(np.concatenate(adj), pieces), math.sqrt(float(raw @ raw) / len(raw))


def window_sse(r: np.ndarray, pieces: Sequence[Piece]) -> np.ndarray:
    """Sum of squares of a concatenated residual per window, all pieces in order."""
    out, k = [], 0
    for p in pieces:
        seg = r[k:k + p.n_eval]
        k += p.n_eval
        out.append(window_means(seg * seg, p.window) * np.diff(
            np.minimum(np.arange(p.n_windows + 1) * p.window, p.n_eval)))
    return np.concatenate(out)


def window_labels(pieces: Sequence[Piece]) -> np.ndarray:
    """A global window number for every evaluated sample (clusters for the covariance)."""
    out, base = [], 0
    for p in pieces:
        out.append(p.window_index() + base)
        base += p.n_windows
    return np.concatenate(out)


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
# variable projection of g and Δ
# ------------------------------------------------------------------------------------------
def _linear_in_gain_and_trend(spec: str) -> bool:
    """True if ŷ is affine in g and Δ with no other additive term: no force-dependent effect and
    no disturbance (then one simulation gives the projection)."""
    from plant.effects import Stage, effect_class
    for name in spec.split("+")[1:]:
        c = effect_class(name)
        if c.depends_on_force or not c.linear_in_gain or c.stage in (Stage.FORCE, Stage.DISTURBANCE):
            return False
    return True


def gain_trend_columns(spec: str, values: Mapping[str, float], pieces: Sequence[Piece],
                       fit_g: bool = True, fit_delta: bool = True
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The objective's residual as an affine function of g and Δ (the other parameters fixed):
    ``residual(β) ≈ s1 + A·(β − β0)`` with β = (g, Δ) (only those fitted). Returns ``s1``
    (the residual at ``β0``), ``A`` (one column per fitted parameter) and ``β0``.

    With window starts re-estimated the residual is ``demean(g·A + Δ·B − y)`` (A: the windowed
    response to the flow at unit gain, B: time since the window start), exactly, when no effect
    makes the rate depend on the force and there is no disturbance: one simulation gives it.
    Otherwise ``ŷ ≈ F + g·A + Δ·B`` is taken from three simulations around the current g and Δ,
    one Gauss-Newton step (exact for ``leakage``, first order for ``load_pressure``,
    ``stiffness`` and ``stiction``, whose play is crossed at a speed set by g)."""
    vals = dict(values)
    linear = _linear_in_gain_and_trend(spec)
    if not fit_g:
        g0 = vals["g"]
    elif linear:
        g0 = 1.0
    else:   # linearize where the model is: a play crossed at g = 1 is crossed at no other g
        g = vals.get("g", math.nan)
        g0 = g if math.isfinite(g) and abs(g) > 1e-6 else 1.0
    d0 = 0.0 if linear and fit_delta else vals["delta"]
    s1 = residual(PlantModel.from_spec(spec, {**vals, "g": g0, "delta": d0}), pieces)
    cols = []
    if linear:
        dy = np.concatenate([demean_windows(p.y[p.warmup:], p.window) for p in pieces])
        if fit_g:  # s1 = demean(g0·A + d0·B − y)
            cols.append((s1 + dy - d0 * _trend_basis(pieces)) / g0)
        if fit_delta:
            cols.append(_trend_basis(pieces))
    else:
        if fit_g:
            s2 = residual(PlantModel.from_spec(spec, {**vals, "g": 1.1 * g0, "delta": d0}), pieces)
            cols.append((s2 - s1) / (0.1 * g0))
        if fit_delta:
            s3 = residual(PlantModel.from_spec(spec, {**vals, "g": g0, "delta": d0 + 1.0}), pieces)
            cols.append(s3 - s1)
    beta0 = np.array([g0] * fit_g + [d0] * fit_delta)
    return s1, np.column_stack(cols), beta0


def project_gain_trend(spec: str, values: Mapping[str, float], pieces: Sequence[Piece],
                       fit_g: bool = True, fit_delta: bool = True) -> tuple[dict[str, float], float]:
    """Solve g and Δ by linear least squares for the other parameters fixed (see
    :func:`gain_trend_columns`). Returns the updated values and the sum of squared errors."""
    vals = dict(values)
    if not (fit_g or fit_delta):
        r = residual(PlantModel.from_spec(spec, vals), pieces)
        return vals, float(r @ r)
    specs = dict(PlantModel.from_spec(spec, vals).param_specs())
    s1, A, beta0 = gain_trend_columns(spec, vals, pieces, fit_g, fit_delta)
    step, *_ = np.linalg.lstsq(A, -s1, rcond=None)
    names = ["g"] * fit_g + ["delta"] * fit_delta
    for n, b in zip(names, beta0 + step):
        p = specs[n]
        vals[n] = float(min(max(b, p.lower), p.upper)) if math.isfinite(b) else p.default
    r = residual(PlantModel.from_spec(spec, vals), pieces)
    return vals, float(r @ r)


def _trend_basis(pieces: Sequence[Piece]) -> np.ndarray:
    """demean(time since the window start), the objective's column for Δ."""
    return np.concatenate([demean_windows(p.horizon() * p.dt, p.window) for p in pieces])


# ------------------------------------------------------------------------------------------
# start values
# ------------------------------------------------------------------------------------------
@dataclass
class DataSummary:
    """What the start grids need to know about the data."""

    dt: float
    u_abs_levels: list[float]      #: distinct |u| levels (≤ 8) or quantiles
    u_abs_max: float
    y_abs_max: float
    y_span: float
    duration_s: float              #: the longest piece's end, s since its record began

    @classmethod
    def of(cls, pieces: Sequence[Piece]) -> "DataSummary":
        u = np.concatenate([p.u for p in pieces])
        y = np.concatenate([p.y for p in pieces])
        ua = np.abs(u[u != 0]) if np.any(u != 0) else np.array([1.0])
        levels = np.unique(np.round(ua, 3))
        if len(levels) > 8:
            levels = np.quantile(ua, [0.25, 0.5, 0.75, 0.95])
        return cls(dt=min(p.dt for p in pieces), u_abs_levels=[float(v) for v in levels],
                   u_abs_max=float(ua.max()), y_abs_max=float(np.abs(y).max()),
                   y_span=float(np.ptp(y)),
                   duration_s=max(p.t0 + len(p.u) * p.dt for p in pieces))










































def effect_starts(effect: str, summary: DataSummary, values: Mapping[str, float]) -> list[dict]:
    """The effect's start grid (:meth:`plant.Effect.start_grid`) for these data and base fit."""
    from plant.effects import effect_class
    return effect_class(effect).start_grid(summary, values)


def initial_delay(pieces: Sequence[Piece], spec: str = "base",
                  values: Mapping[str, float] | None = None,
                  tau_max: float = 1.0) -> tuple[dict[str, float], float]:
    """τ (continuous) with g, Δ projected: a grid of delays, then a bounded scalar search around
    the best grid point. Returns the values and the SSE."""
    values = dict(values or PlantModel.from_spec(spec).params())
    dt = min(p.dt for p in pieces)
    tau_max = min(tau_max, 0.45 * min(p.window for p in pieces) * dt)
    grid = np.unique(np.concatenate([np.arange(0, min(0.1, tau_max) + 1e-12, max(dt, 0.005)),
                                     np.linspace(0.1, tau_max, 13) if tau_max > 0.1 else []]))

    def sse(tau: float) -> tuple[dict, float]:
        return project_gain_trend(spec, {**values, "tau": float(tau)}, pieces)

    scored = [(sse(t)[1], t) for t in grid]
    scored.sort()
    best_val, best_tau = scored[0]
    i = int(np.searchsorted(grid, best_tau))
    lo = grid[max(0, i - 1)]
    hi = grid[min(len(grid) - 1, i + 1)]
    if hi > lo:
        res = optimize.minimize_scalar(lambda t: sse(t)[1], bounds=(lo, hi), method="bounded",
                                       options={"xatol": max(1e-5, dt * 1e-3)})
        if res.fun < best_val:
            best_tau = float(res.x)
    return sse(best_tau)


# ------------------------------------------------------------------------------------------
# the fit
# ------------------------------------------------------------------------------------------
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

    def fun(x):
        return residual(par.model(x), pieces)

    if max_nfev is None:
        max_nfev = 40 * (len(x0) + 1)
    res = optimize.least_squares(fun, x0, bounds=(lo, hi), method="trf", x_scale="jac",
                                 tr_solver="lsmr" if len(x0) and _n_eval(pieces) > 400_000 else "exact",
                                 diff_step=DIFF_STEP, max_nfev=max_nfev, ftol=tol, xtol=tol)
    return res.x, res


def _n_eval(pieces: Sequence[Piece]) -> int:
    return sum(p.n_eval for p in pieces)


def _as_model(model: PlantModel | str) -> PlantModel:
    return PlantModel.from_spec(model) if isinstance(model, str) else model


@one_blas_thread
def fit_model(data: Sequence[Record] | Sequence[Piece], model: PlantModel | str,
              window_s: float = WINDOW_S, fixed: Iterable[str] = (), starts: str = "auto",
              max_nfev: int | None = None, n_polish: int = 2,
              extra_starts: Sequence[Mapping[str, float]] = (),
              grid_effects: Sequence[str] | None = None, delay_search: bool = True,
              covariance: bool = True, tol: float | None = None) -> FitResult:
    """Fit ``model`` (a spec like ``"base+reversal"`` or a :class:`PlantModel` whose values are
    a start) to records (or prepared pieces) by least squares on the windowed free-run error.

    ``fixed``: parameter names kept at their given values. ``starts``: ``"auto"`` (grids and
    projections described in the module docstring, plus the given values) or ``"given"`` (only
    the model's values). ``grid_effects``: effects whose start grids are tried (default: all of
    the model's); ``delay_search``: grid-search τ first; ``n_polish``: how many of the best
    starts are polished; ``tol``: relative tolerance of the polish (default :data:`FTOL`). With
    more than :data:`SEARCH_WINDOWS` windows the starts are searched (and polished loosely) on a
    subset of them, then polished on all. Returns a :class:`FitResult` with confidence
    intervals."""
    model = _as_model(model)
    pieces = _as_pieces(data, window_s)
    search, searched_subset = subset_pieces(pieces, SEARCH_WINDOWS) if starts == "auto" else (pieces, False)
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
    for s in extra_starts:
        vals = {**given, **{k: v for k, v in s.items() if k in given and k not in fixed}}
        candidates.append(project(vals)[::-1])
    if starts == "auto":
        base_vals = dict(given)
        if delay_search and "tau" not in fixed:
            tv, _ = initial_delay(search, spec, given)
            base_vals.update({k: tv[k] for k in ("g", "tau", "delta") if k not in fixed})
            candidates.append(project(base_vals)[::-1])
        summary = DataSummary.of(search)
        names = [e.name for e in model.effects] if grid_effects is None else list(grid_effects)
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
        if len(seen) >= n_polish:
            break
        key = tuple(np.round(par.to_x(vals), 6))
        if key in seen:
            continue
        if seen and sse0 > 1.05 * candidates[0][0] and not (grid_effects and len(seen) < 2):
            # further starts are clearly worse: one polish is enough. Except for an effect added
            # to a fitted model: its best start is often the effect switched off (the model as
            # it was), a point the polish may not leave while the model's other effects hold
            # the error it would explain (a dead zone after a flow curve): polish one more
            break
        budget = max_nfev if not seen else min(max_nfev or 10 ** 9, 15 * (len(free) + 1))
        seen.append(key)
        x, res = _polish(par, search, vals, budget, (FTOL if tol is None else tol)
                         if not searched_subset else SCREEN_TOL)
        if best is None or res.cost < best[1].cost:
            best = (x, res)
    x, res = best
    if searched_subset:  # the starts were searched on a subset of the windows: polish on all
        vals = par.to_values(x)
        sse_all = residual(par.model(x), pieces)
        candidates = [(float(sse_all @ sse_all), vals)]
        x, res = _polish(par, pieces, vals, max_nfev, REFIT_TOL if tol is None else tol)
    # never worse than the best start (a polish can stall in a flat, non-identifiable valley)
    sse_best, vals_best = candidates[0]
    if 2 * res.cost > sse_best * (1 + 1e-9):
        x = par.to_x(vals_best)
        r = residual(par.model(x), pieces)
        return _result(par.model(x), par, pieces, r, res.nfev, False,
                       "kept the best start value: the polish did not improve on it",
                       covariance=covariance)
    fitted = par.model(x)
    return _result(fitted, par, pieces, res.fun, res.nfev, bool(res.success),
                   str(res.message), covariance=covariance)


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
