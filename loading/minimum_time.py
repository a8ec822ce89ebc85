r"""The physical limit of a programme: its valve-limited minimum time on the station the model
describes.

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

**A station's load cases** (:func:`minimum_durations_s`): between two load cases every channel
moves along a haversine of one common duration ``T``
(:mod:`loading.programme`), so at its fraction ``σ`` channel i asks the rate
``ṙ_i = v_i·sin πσ / T`` with ``v_i = π(L_{i,1} − L_{i,0})/2``, at the force
``y_i(σ) = L_{i,0} + (L_{i,1} − L_{i,0})(1 − cos πσ)/2``. Through the rig's model the flows
that make those rates are (:mod:`loading.feedforward`)

.. math::  w(σ) = G^{-1}\big(\dot r(σ) - d(y(σ))\big) = \frac{p(σ)}{T} - c(σ),
           \qquad p = G^{-1} v\,\sin πσ,\quad c = G^{-1} d

(``d_i(y)``: channel i's rate with its valve shut, its trend and force terms). Each valve makes
at most ``W^+_i(y)`` one way and ``W^-_i(y)`` the other within :data:`FEEDFORWARD_SHARE` of the
command limit (:func:`valve_limit`, as a flow:
``W^±_i = (R^±_i ∓ d_i)/g_i``). Every constraint ``−W^- ≤ p/T − c ≤ W^+`` is linear in
``x = 1/T``, so the segment's shortest duration is

.. math::  T_{min} = 1 / \min_{i,σ} \begin{cases} (W^+_i + c_i)/p_i & p_i > 0 \\
                                                  (W^-_i - c_i)/|p_i| & p_i < 0 \end{cases}

A channel whose own level does not change still moves its valve: its neighbours' flows push
its force through the structure, and its flow must take that out. A segment whose forces the
valves cannot even hold against their trends (``c`` beyond ``W`` at ``x = 0``) is refused,
naming the channel. As for one channel, a boost that lasts only a moment (the reversal's) and
the valve's dynamics are not counted; the feedforward's check lengthens a segment the valves
cannot follow (:func:`loading.time_scaling.stretch_to_valve`).
For one channel this is the segment's time above.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from core.errors import ParameterError
from plant import PlantModel

from plant.rig import RigModel

from .programme import STAND, ChannelProgramme, Programme, as_programme

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


@dataclass(frozen=True)
class FlowLimit:
    """Per channel, across a span of forces: the largest flow each way (command %) and the
    rate with the valve shut (kgf/s)."""

    names: list[str]
    forces_kgf: np.ndarray         #: (N, F) where each channel was evaluated
    up_pct: np.ndarray             #: (N, F) the largest flow raising the channel's own force
    down_pct: np.ndarray           #: (N, F) the largest flow lowering it (positive)
    shut_kgf_s: np.ndarray         #: (N, F) the rate with the valve shut: trend and force terms
    command_pct: float             #: the largest command the feedforward may use
    rates: list[ValveLimit]        #: per channel its largest force rates each way

    def at(self, force_kgf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(W+, W-, d)`` at ``force_kgf`` (N, ...), each channel interpolated on its own span."""
        y = np.asarray(force_kgf, float)
        out = [np.empty_like(y) for _ in range(3)]
        for i in range(len(self.names)):
            for o, table in zip(out, (self.up_pct, self.down_pct, self.shut_kgf_s)):
                o[i] = np.interp(y[i], self.forces_kgf[i], table[i])
        return out[0], out[1], out[2]


def flow_limit(model: RigModel, command_limit_pct: float, spans_kgf: np.ndarray,
               share: float = FEEDFORWARD_SHARE) -> FlowLimit:
    """Every channel's :class:`FlowLimit` across its span ``spans_kgf`` (N, 2: low, high)."""
    spans = np.asarray(spans_kgf, float)
    forces, up, down, shut, rates = [], [], [], [], []
    for m, (lo, hi) in zip(model.channels, spans):
        f = np.linspace(lo, hi, FORCE_POINTS) if hi > lo else np.array([lo, lo + 1.0])
        lim = valve_limit(m, command_limit_pct, f, share)
        d = np.array([steady_rate_kgf_s(m, np.zeros(1), y)[0] for y in f])
        forces.append(f)
        rates.append(lim)
        up.append((lim.up_kgf_s - d) / m.g)
        down.append((lim.down_kgf_s + d) / m.g)
        shut.append(d)
    return FlowLimit(list(model.names), np.array(forces), np.array(up), np.array(down),
                     np.array(shut), share * float(command_limit_pct), rates)


def minimum_durations_s(programme: Programme, model: RigModel, limit: FlowLimit
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Each segment's shortest duration (s) between load cases (module docstring), and which
    channel's valve sets it (its index). Raises :class:`~core.errors.ParameterError` naming the
    segment (and the channel) when a valve cannot move or hold its force at all."""
    if not programme.load_cases:
        raise ParameterError(f"{programme.source}: per-channel sequences have no common segments; "
                             "a rig's minimum time is for load cases (a CSV with a column per channel)")
    L = programme.levels_kgf
    Ginv = np.linalg.inv(model.G)
    sigma = SEGMENT_POINTS
    mins, binding = [], []
    for k in range(L.shape[1] - 1):
        a, b = L[:, k], L[:, k + 1]
        y = a[:, None] + (b - a)[:, None] * (1 - np.cos(np.pi * sigma))[None, :] / 2
        up, down, d = limit.at(y)
        p = Ginv @ (np.pi * (b - a) / 2)[:, None] * np.sin(np.pi * sigma)[None, :]
        c = Ginv @ d
        # holding at x = 0 must be possible: −W⁻ ≤ −c ≤ W⁺
        cannot = (-c > up) | (c > down)
        if cannot.any() and programme.n == 1:
            raise ParameterError(
                f"{programme.source}: by the model ({model.channels[0].spec}) the valve cannot move the "
                f"force from {a[0]:g} to {b[0]:g} kgf (segment {k + 1}) within {limit.command_pct:.3g} % "
                "of command: check the model and the command limit")
        if cannot.any():
            i = int(np.flatnonzero(cannot.any(axis=1))[0])
            raise ParameterError(
                f"{programme.source}: by the rig's model the valve of channel {programme.names[i]} "
                f"cannot hold its force against the trends between load cases {k + 1} and {k + 2} "
                f"within {limit.command_pct:.3g} % of command: check the model and the command limit")
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(p > 0, (up + c) / p, np.where(p < 0, (down - c) / -p, np.inf))
        x_max = float(x.min())
        if not math.isfinite(x_max):          # nothing moves (cannot happen between two load cases)
            mins.append(0.0)
            binding.append(0)
            continue
        mins.append(1.0 / x_max)
        binding.append(int(np.unravel_index(np.argmin(x), x.shape)[0]))
    return np.array(mins), np.array(binding, int)


def programme_flow_limit(programme: Programme, model: RigModel, command_limit_pct: float) -> FlowLimit:
    """:func:`flow_limit` across each channel's span in the programme."""
    R = programme.r_kgf
    return flow_limit(model, command_limit_pct, np.c_[R.min(axis=1), R.max(axis=1)])


@dataclass(frozen=True)
class ProgrammeTiming:
    """A programme's time beside its valve-limited minimum (``stand load --plan``)."""

    programme_time_s: float
    minimum_s: np.ndarray          #: per segment
    binding: np.ndarray            #: per segment, the channel whose valve sets its minimum
    names: list[str]
    limit: FlowLimit

    @property
    def minimum_time_s(self) -> float:
        return float(self.minimum_s.sum())

    @property
    def ratio(self) -> float:
        return self.programme_time_s / self.minimum_time_s if self.minimum_time_s > 0 else math.inf

    def binding_counts(self) -> dict[str, int]:
        """Per channel, how many segments its valve sets (the channels that set none left out)."""
        counts = np.bincount(self.binding, minlength=len(self.names))
        return {n: int(c) for n, c in zip(self.names, counts) if c}

    def text(self, label: str = "the programme") -> str:
        if self.names == [STAND]:
            return (f"{label + ':':<24s}{self.programme_time_s:10.1f} s  ({len(self.minimum_s)} segments, "
                    f"{self.ratio:.2f}x the minimum)\n"
                    f"{'valve-limited minimum:':<24s}{self.minimum_time_s:10.1f} s  "
                    f"(every segment at the largest rate:\n{'':<24s}{self.limit.rates[0].text()})")
        sets = ", ".join(f"{n} {c}" for n, c in sorted(self.binding_counts().items(), key=lambda x: -x[1]))
        return (f"{label + ':':<24s}{self.programme_time_s:10.1f} s  ({len(self.minimum_s)} segments, "
                f"{self.ratio:.2f}x the minimum)\n"
                f"{'valve-limited minimum:':<24s}{self.minimum_time_s:10.1f} s  (every segment as fast as "
                f"the slowest valve allows, the neighbours'\n{'':<24s}flows through G counted, the "
                f"feedforward's command up to ±{self.limit.command_pct:.3g} %; segments set by: {sets})")

    def to_dict(self) -> dict:
        out = {"programme_time_s": self.programme_time_s, "minimum_time_s": self.minimum_time_s,
               "ratio": self.ratio, "segments": int(len(self.minimum_s)),
               "segments_set_by": self.binding_counts()}
        if len(self.names) == 1:
            rates = self.limit.rates[0]
            out["largest_rate_up_kgf_s"] = float(rates.up_kgf_s.max())
            out["largest_rate_down_kgf_s"] = float(rates.down_kgf_s.max())
        return out


def programme_timing(programme: Programme | ChannelProgramme, model: RigModel | PlantModel,
                     command_limit_pct: float) -> ProgrammeTiming:
    """The programme's time and its valve-limited minimum on the station ``model`` describes
    (one channel's programme and model: a station of one)."""
    programme = as_programme(programme)
    if isinstance(model, PlantModel):
        model = RigModel([model], np.array([[model.g]]), list(programme.names))
    limit = programme_flow_limit(programme, model, command_limit_pct)
    minimum, binding = minimum_durations_s(programme, model, limit)
    return ProgrammeTiming(programme.duration_s, minimum, binding, list(programme.names), limit)
