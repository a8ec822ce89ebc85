"""Helpers for the effects' start grids (:meth:`plant.Effect.start_grid`).

A start grid is a list of ``{"effect.param": value}`` dicts (may also set base parameters such
as ``tau``) from which the fit starts a local search; it is built from a data summary (``dt``,
``u_abs_levels``, ``u_abs_max``, ``y_abs_max``, ``y_span``, ``duration_s``) and the base fit.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from .params import Param


def and_less_delay(start: dict, base: Mapping[str, float], extra_s: float) -> list[dict]:
    """``start``, and the same with τ shortened by ``extra_s``: an effect that holds the
    response back (a lag, a stuck rod, a late direction) looks like more delay, which the base
    fit has put into τ."""
    tau = base.get("tau", 0.05)
    if extra_s > 0 and tau > 0:
        return [start, {**start, "tau": max(0.0, tau - extra_s)}]
    return [start]


def generic_starts(effect: str, params: Sequence[Param], limit: int = 27) -> list[dict]:
    """Default, and a low and a high value per parameter (log-spaced for log parameters)."""
    axes = []
    for p in params:
        if p.log:
            vals = [p.default, max(p.lower, p.default / 5), min(p.upper, p.default * 5)]
        else:
            span = p.upper - p.lower
            vals = [p.default, p.lower + 0.2 * span, p.lower + 0.6 * span]
        axes.append(sorted(set(vals)))
    combos = [{}]
    for p, vals in zip(params, axes):
        combos = [{**c, f"{effect}.{p.name}": v} for c in combos for v in vals]
    return combos[:limit]


def warming_starts(effect: str, changes: Sequence[float], limit: float, s: Any) -> list[dict]:
    """Start grid of an effect that drifts from the start of each run (``rate``,
    ``time_constant``): a total change of each of ``changes`` over the longest run, reached
    linearly (T far beyond the run) or settling within it; rates within ±``limit``."""
    D = max(s.duration_s, 1.0)

    def rate(r: float) -> float:
        return float(np.clip(r, -limit, limit))
    out = []
    for change in changes:
        out += [{f"{effect}.rate": rate(change / D), f"{effect}.time_constant": 1e5},
                {f"{effect}.rate": rate(3 * change / D),
                 f"{effect}.time_constant": max(1.0, D / 3)}]
    return out


def renamed(starts: list[dict], effect: str, twin: str) -> list[dict]:
    """The start grid of ``effect`` for ``twin``, an effect with the same parameters (a sensor
    lag starts like a valve lag, a command-timed reversal like a rod-timed one)."""
    return [{(twin + k[len(effect):] if k.startswith(effect + ".") else k): v
             for k, v in start.items()} for start in starts]
