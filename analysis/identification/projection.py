"""Variable projection of the base gain g and trend Δ: for any trial of the other parameters, the
windowed output is affine in them (``ŷ = F + g·A + Δ·B``, exactly for every effect except
``load_pressure``, whose play is crossed at a speed set by g), so they are solved exactly by
linear least squares from one simulation, or three around the current values.
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from plant import PlantModel

from .windows import Piece, demean_windows, known_response, residual


def _linear_in_gain_and_trend(spec: str) -> bool:
    """True if ŷ is affine in g and Δ with no other additive term: no force-dependent effect and
    no disturbance (then one simulation gives the projection)."""
    from plant.catalogue import effect_class
    from plant.contract import Stage
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
    ``stiffness`` and ``stiction``, whose play is crossed at a speed set by g). A known rate
    the pieces carry (a rig's coupling) adds its windowed response ``C`` to ŷ, in neither
    column: ``residual = demean(g·A + Δ·B + C − y)``."""
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
        if any(p.known is not None for p in pieces):   # a known rate adds its response C
            dy = dy - _demeaned(known_response(pieces), pieces)
        if fit_g:  # s1 = demean(g0·A + d0·B + C − y)
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
    ok = np.isfinite(s1) & np.all(np.isfinite(A), axis=1)
    if ok.sum() < max(A.shape[1] + 1, 0.5 * len(s1)):
        # the simulation failed at this trial (a force-dependent law stepped across its
        # discontinuity by the integrator's difference quotient): a start not to take
        return vals, math.inf
    step, *_ = np.linalg.lstsq(A[ok], -s1[ok], rcond=None)
    names = ["g"] * fit_g + ["delta"] * fit_delta
    for n, b in zip(names, beta0 + step):
        p = specs[n]
        vals[n] = float(min(max(b, p.lower), p.upper)) if math.isfinite(b) else p.default
    r = residual(PlantModel.from_spec(spec, vals), pieces)
    sse = float(r @ r)
    return vals, sse if math.isfinite(sse) else math.inf


def _trend_basis(pieces: Sequence[Piece]) -> np.ndarray:
    """demean(time since the window start), the objective's column for Δ."""
    return np.concatenate([demean_windows(p.horizon() * p.dt, p.window) for p in pieces])


def _demeaned(r: np.ndarray, pieces: Sequence[Piece]) -> np.ndarray:
    """A concatenated series over the pieces' evaluated samples, demeaned in each window."""
    out, k = [], 0
    for p in pieces:
        out.append(demean_windows(r[k:k + p.n_eval], p.window))
        k += p.n_eval
    return np.concatenate(out)
