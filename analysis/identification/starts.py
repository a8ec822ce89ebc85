"""Start values of the fit, so that it does not depend on luck: what the start grids need to
know about the data (:class:`DataSummary`), each effect's grid of physically sensible starts
scaled to the data (:meth:`plant.Effect.start_grid`), and the delay τ from a grid of delays with
g and Δ projected (:mod:`.projection`), refined by a bounded scalar search.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
from scipy import optimize

from plant import PlantModel

from .periodic import NONE, Periodic, residual_periodic
from .projection import project_gain_trend
from .windows import Piece


@dataclass
class DataSummary:
    """What the start grids need to know about the data, and (computed when a grid asks) what
    the residual of the model without the effects being tried looks like."""

    dt: float
    u_abs_levels: list[float]      #: distinct |u| levels (≤ 8) or quantiles
    u_abs_max: float
    y_abs_max: float
    y_span: float
    duration_s: float              #: the longest piece's end, s since its record began
    #: the model the effects are tried on, at its fitted values (None: unknown)
    reference: PlantModel | None = field(default=None, repr=False, compare=False)
    pieces: Sequence[Piece] = field(default=(), repr=False, compare=False)
    _periodic: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def of(cls, pieces: Sequence[Piece], reference: PlantModel | None = None) -> "DataSummary":
        u = np.concatenate([p.u for p in pieces])
        y = np.concatenate([p.y for p in pieces])
        ua = np.abs(u[u != 0]) if np.any(u != 0) else np.array([1.0])
        levels = np.unique(np.round(ua, 3))
        if len(levels) > 8:
            levels = np.quantile(ua, [0.25, 0.5, 0.75, 0.95])
        return cls(dt=min(p.dt for p in pieces), u_abs_levels=[float(v) for v in levels],
                   u_abs_max=float(ua.max()), y_abs_max=float(np.abs(y).max()),
                   y_span=float(np.ptp(y)),
                   duration_s=max(p.t0 + len(p.u) * p.dt for p in pieces),
                   reference=reference, pieces=pieces)

    def residual_periodic(self, carrier: str = "force") -> Periodic:
        """The dominant sinusoid in the reference model's residual, read as ``carrier`` (the
        force, its rate, or its rate over the flow: :func:`.periodic.residual_periodic`);
        computed once per carrier, and only when a start grid asks."""
        if self.reference is None:
            return NONE
        if carrier not in self._periodic:
            self._periodic[carrier] = residual_periodic(self.reference, self.pieces, carrier)
        return self._periodic[carrier]

    @property
    def residual_frequency_hz(self) -> float | None:
        """The force residual's dominant frequency (a disturbance's)."""
        return self.residual_periodic().frequency_hz

    @property
    def residual_amplitude_kgf(self) -> float | None:
        return self.residual_periodic().amplitude_kgf


def without(model_spec: str, values: Mapping[str, float], effects: Sequence[str]) -> PlantModel:
    """The model ``model_spec`` without ``effects``, at ``values`` (theirs left out)."""
    parts = [p for p in model_spec.split("+") if p not in set(effects)]
    keep = {k: v for k, v in values.items() if k.split(".", 1)[0] not in set(effects)}
    return PlantModel.from_spec("+".join(parts), keep)


def effect_starts(effect: str, summary: DataSummary, values: Mapping[str, float]) -> list[dict]:
    """The effect's start grid (:meth:`plant.Effect.start_grid`) for these data and base fit."""
    from plant.catalogue import effect_class
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
