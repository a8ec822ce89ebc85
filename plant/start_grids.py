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


#: how many starts a default grid offers at most (each costs one simulation of the search windows)
GENERIC_LIMIT = 48


#: where in the signal path an effect acts -> how its trace in the residual is read
#: (:meth:`analysis.identification.starts.DataSummary.residual_periodic`)
CARRIER = {"VALVE": "rate", "FLOW": "flow"}


def generic_starts(effect: str, params: Sequence[Param], s: Any = None, stage: Any = None,
                   limit: int = GENERIC_LIMIT) -> list[dict]:
    """The start grid of an effect that declares none (a plug-in's, by default).

    Each parameter takes its default and values across its bounds (three, log-spaced for
    ``log=True``, at 1/6, 1/2 and 5/6 of the range otherwise). Where the data summary ``s`` can
    say what the residual of the model without the effect looks like, a parameter in Hz (or
    rad/s) also starts at the residual's dominant frequency, read where the effect acts
    (``stage``: the force for a disturbance, its rate over the flow for a FLOW effect, its rate
    for a VALVE effect), and one in kgf at the force residual's amplitude: those starts come
    first, with the other parameters across their grids. Beyond ``limit`` combinations, an
    even spread."""
    hints: dict[str, float | None] = {}
    if s is not None and hasattr(s, "residual_periodic"):
        units = {p.unit.strip().lower() for p in params}
        if units & {"hz", "rad/s"}:
            carrier = CARRIER.get(getattr(stage, "name", ""), "force")
            f = s.residual_periodic(carrier).frequency_hz
            hints["hz"] = f
            hints["rad/s"] = None if f is None else 2 * np.pi * f
        if "kgf" in units:
            hints["kgf"] = s.residual_periodic("force").amplitude_kgf
    axes, hinted = [], []
    for p in params:
        if p.log:
            inner = np.geomspace(p.lower, p.upper, 5)[1:-1]
        else:
            inner = p.lower + (p.upper - p.lower) * np.array([1 / 6, 1 / 2, 5 / 6])
        axes.append(sorted({float(p.default), *(float(v) for v in inner)}))
        hint = hints.get(p.unit.strip().lower())
        hinted.append([float(hint)] if hint is not None and p.lower <= hint <= p.upper else [])
    combos: list[dict] = []
    if any(hinted):
        combos += _product(effect, params, [h or a for h, a in zip(hinted, axes)])
    rest = _product(effect, params, axes)
    room = max(limit - len(combos), 1)
    if len(rest) > room:
        # the defaults first, then an even spread over the rest
        keep = np.unique(np.round(np.linspace(0, len(rest) - 1, room)).astype(int))
        rest = [rest[0]] + [rest[i] for i in keep if i != 0][:room - 1]
    combos += [c for c in rest if c not in combos]
    return combos


def _product(effect: str, params: Sequence[Param], axes: Sequence[Sequence[float]]) -> list[dict]:
    """Every combination of the axes' values, the parameters' defaults first."""
    combos: list[dict] = [{}]
    for p, vals in zip(params, axes):
        vals = sorted(vals, key=lambda v: v != p.default)
        combos = [{**c, f"{effect}.{p.name}": v} for c in combos for v in vals]
    return combos


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
