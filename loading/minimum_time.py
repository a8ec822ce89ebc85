r"""The physical limit of a programme: its valve-limited minimum time on a stand the model describes.

A programme's time is set by the rate asked of each segment; the stand sets the largest rate it
can deliver. For a flow command ``q`` held steady the model's force rate is

.. math::  \dot y(q, y) = g\,q'(q)\,\prod_i G_i\big(q'(q), y\big) + \Delta + \sum_j F_j(y)

(``q'``: the VALVE effects' steady output, e.g. a flow limit or a dead zone; ``G_i``: the FLOW
effects' factors once settled, e.g. a supply sagged to its level for that opening or the
asymmetry's ``1 ± a``; ``F_j``: the FORCE effects' rate terms, e.g. a leakage). A boost that
only lasts a moment (the reversal's) is not counted: it decays within a segment. The feedforward
may use at most :data:`FEEDFORWARD_SHARE` of the command limit (the rest is the feedback's),
so the largest rate each way at a force ``y`` is

.. math::  R_{\pm}(y) = \max_{0 \le u \le s\,u_{max}} \pm\,\dot y(\pm u, y),

``s`` the share and ``u_max`` the command limit (the smaller of the controller's and the
supervisor's). A haversine segment from ``L_0`` to ``L_1`` asks ``π·|L_1 − L_0|/(2T)·sin πσ`` at
its fraction ``σ``, so its shortest duration is

.. math::  T_{min} = \max_{\sigma} \frac{\pi\,|L_1 - L_0|\,\sin\pi\sigma}{2\,R_{\pm}\big(y(\sigma)\big)}

(at the middle, ``T = π·|ΔL|/(2R)``, where ``R`` does not depend on the force). The programme's
valve-limited minimum is the sum over its segments: every segment at the largest rate the
model says the valve can deliver, in the programme's own shape. A ramp at ``R`` would take
``2/π`` of it, but a ramp asks an infinite acceleration of the rod at each end.

What this does not count: the valve's dynamics (a lag, a slew limit, a resonance) and a sag
that has not settled; where they matter, the feedforward's check
(:func:`loading.time_scaling.stretch_to_valve`) lengthens the segments the valve cannot follow.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from core.errors import ParameterError
from plant import PlantModel

from .programme import Programme

#: the feedforward may use at most this share of the command limit (the rest is the feedback's)
FEEDFORWARD_SHARE = 0.9
#: the held command is evaluated after this long (s), at this step: settled effects
HOLD_S = 5.0
HOLD_STEP_S = 0.01
#: commands tried between 0 and the largest, and forces across the programme's span
COMMAND_POINTS = 101
FORCE_POINTS = 21
#: fractions of a segment where its rate is checked against the valve's
SEGMENT_POINTS = np.linspace(0.05, 0.95, 19)


@dataclass(frozen=True)
class ValveLimit:
    """The largest force rates the valve can deliver, each way, across a span of forces."""

    forces_kgf: np.ndarray          #: (F,) where the rates were evaluated
    up_kgf_s: np.ndarray            #: (F,) the largest rising rate at each force
    down_kgf_s: np.ndarray          #: (F,) the largest falling rate (positive) at each force
    command_pct: float              #: the largest command the feedforward may use
    model_spec: str

    def rate_kgf_s(self, way: np.ndarray, force_kgf: np.ndarray) -> np.ndarray:
        """The largest rate (positive) moving ``way`` (±1) at ``force_kgf``, interpolated."""
        up = np.interp(force_kgf, self.forces_kgf, self.up_kgf_s)
        down = np.interp(force_kgf, self.forces_kgf, self.down_kgf_s)
        return np.where(np.asarray(way) > 0, up, down)

    def text(self) -> str:
        def span(a: np.ndarray) -> str:
            lo, hi = float(a.min()), float(a.max())
            return f"{lo:,.0f}" if math.isclose(lo, hi, rel_tol=1e-3) else f"{lo:,.0f}-{hi:,.0f}"
        return (f"up to {span(self.up_kgf_s)} kgf/s rising, {span(self.down_kgf_s)} kgf/s falling "
                f"by the model {self.model_spec} with the feedforward's command up to ±{self.command_pct:.3g} %")


def steady_rate_kgf_s(model: PlantModel, command_pct: np.ndarray, force_kgf: float) -> np.ndarray:
    """The model's force rate (kgf/s) for each command of ``command_pct`` held long enough for
    every effect to settle (module docstring), at the force ``force_kgf``; disturbances left
    out. Through the model's own stages, so a plug-in's effects count too."""
    u = np.asarray(command_pct, float)
    k = int(round(HOLD_S / HOLD_STEP_S))
    state = model.new_state(len(u), HOLD_STEP_S, y0=force_kgf, u0=u, t0=0.0)
    drive = model.drive(np.repeat(u[:, None], k, axis=1), HOLD_STEP_S, state)
    drive = replace(drive, dist=None)
    rate = model.rate_along(drive, np.full((len(u), k), float(force_kgf)))
    return rate[:, -1]


def valve_limit(model: PlantModel, command_limit_pct: float, forces_kgf: np.ndarray,
                share: float = FEEDFORWARD_SHARE) -> ValveLimit:
    """The largest rates each way at ``forces_kgf`` (see the module docstring)."""
    u_max = share * float(command_limit_pct)
    if not (u_max > 0 and math.isfinite(u_max)):
        raise ParameterError(f"command limit {command_limit_pct} %: it must be a positive number")
    u = np.linspace(0.0, u_max, COMMAND_POINTS)[1:]
    forces = np.asarray(forces_kgf, float)
    up = np.empty(len(forces))
    down = np.empty(len(forces))
    for i, y in enumerate(forces):
        rising = steady_rate_kgf_s(model, u, y)
        falling = -steady_rate_kgf_s(model, -u, y)
        up[i], down[i] = rising.max(), falling.max()
    return ValveLimit(forces, up, down, u_max, model.spec)


def programme_valve_limit(programme: Programme, model: PlantModel,
                          command_limit_pct: float) -> ValveLimit:
    """:func:`valve_limit` across the programme's span of forces."""
    lo, hi = float(programme.r_kgf.min()), float(programme.r_kgf.max())
    forces = np.linspace(lo, hi, FORCE_POINTS) if hi > lo else np.array([lo])
    return valve_limit(model, command_limit_pct, forces)


def minimum_durations_s(programme: Programme, limit: ValveLimit) -> np.ndarray:
    """Each segment's shortest duration (s) as a haversine at the valve's largest rate
    (module docstring). Raises :class:`~core.errors.ParameterError` naming the segment when
    the model says the valve cannot move the force that way at all."""
    lv = programme.levels_kgf
    a, b = lv[:-1], lv[1:]
    span = np.abs(b - a)
    way = np.sign(b - a)
    sigma = SEGMENT_POINTS[None, :]
    force = a[:, None] + (b - a)[:, None] * (1 - np.cos(np.pi * sigma)) / 2
    rate = limit.rate_kgf_s(np.broadcast_to(way[:, None], force.shape), force)
    if (rate <= 0).any():
        j = int(np.flatnonzero((rate <= 0).any(axis=1))[0])
        raise ParameterError(
            f"{programme.source}: by the model ({limit.model_spec}) the valve cannot move the force "
            f"from {a[j]:g} to {b[j]:g} kgf (segment {j + 1}) within {limit.command_pct:.3g} % of "
            "command: check the model and the command limit")
    need = np.pi * span[:, None] * np.sin(np.pi * sigma) / (2 * rate)
    return need.max(axis=1)


@dataclass(frozen=True)
class ProgrammeTiming:
    """A programme's time beside its valve-limited minimum (``stand load --plan``)."""

    programme_time_s: float
    minimum_time_s: float
    limit: ValveLimit
    segments: int

    @property
    def ratio(self) -> float:
        """The programme's time over the minimum (1: as fast as the valve allows)."""
        return self.programme_time_s / self.minimum_time_s if self.minimum_time_s > 0 else math.inf

    def text(self, label: str = "the programme") -> str:
        return (f"{label + ':':<24s}{self.programme_time_s:10.1f} s  ({self.segments} segments, "
                f"{self.ratio:.2f}x the minimum)\n"
                f"{'valve-limited minimum:':<24s}{self.minimum_time_s:10.1f} s  "
                f"(every segment at the largest rate:\n{'':<24s}{self.limit.text()})")

    def to_dict(self) -> dict:
        return {"programme_time_s": self.programme_time_s, "minimum_time_s": self.minimum_time_s,
                "ratio": self.ratio, "segments": self.segments,
                "largest_rate_up_kgf_s": float(self.limit.up_kgf_s.max()),
                "largest_rate_down_kgf_s": float(self.limit.down_kgf_s.max())}


def programme_timing(programme: Programme, model: PlantModel, command_limit_pct: float) -> ProgrammeTiming:
    """The programme's time and its valve-limited minimum on the stand ``model`` describes."""
    limit = programme_valve_limit(programme, model, command_limit_pct)
    minimum = minimum_durations_s(programme, limit)
    return ProgrammeTiming(programme.duration_s, float(minimum.sum()), limit, len(minimum))
