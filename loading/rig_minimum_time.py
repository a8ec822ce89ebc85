r"""The physical limit of a rig's load cases: each segment's valve-limited minimum time.

Between two load cases every channel moves along a haversine of one common duration ``T``
(:mod:`loading.rig_programme`), so at its fraction ``σ`` channel i asks the rate
``ṙ_i = v_i·sin πσ / T`` with ``v_i = π(L_{i,1} − L_{i,0})/2``, at the force
``y_i(σ) = L_{i,0} + (L_{i,1} − L_{i,0})(1 − cos πσ)/2``. Through the rig's model the flows
that make those rates are (:mod:`loading.rig_feedforward`)

.. math::  w(σ) = G^{-1}\big(\dot r(σ) - d(y(σ))\big) = \frac{p(σ)}{T} - c(σ),
           \qquad p = G^{-1} v\,\sin πσ,\quad c = G^{-1} d

(``d_i(y)``: channel i's rate with its valve shut, its trend and force terms). Each valve makes
at most ``W^+_i(y)`` one way and ``W^-_i(y)`` the other within :data:`FEEDFORWARD_SHARE` of the
command limit (the one-channel :func:`loading.minimum_time.valve_limit`, as a flow:
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
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.errors import ParameterError
from plant.rig import RigModel

from .minimum_time import FEEDFORWARD_SHARE, FORCE_POINTS, SEGMENT_POINTS, steady_rate_kgf_s, valve_limit
from .rig_programme import RigProgramme


@dataclass(frozen=True)
class RigFlowLimit:
    """Per channel, across a span of forces: the largest flow each way (command %) and the
    rate with the valve shut (kgf/s)."""

    names: list[str]
    forces_kgf: np.ndarray         #: (N, F) where each channel was evaluated
    up_pct: np.ndarray             #: (N, F) the largest flow raising the channel's own force
    down_pct: np.ndarray           #: (N, F) the largest flow lowering it (positive)
    shut_kgf_s: np.ndarray         #: (N, F) the rate with the valve shut: trend and force terms
    command_pct: float             #: the largest command the feedforward may use

    def at(self, force_kgf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(W+, W-, d)`` at ``force_kgf`` (N, ...), each channel interpolated on its own span."""
        y = np.asarray(force_kgf, float)
        out = [np.empty_like(y) for _ in range(3)]
        for i in range(len(self.names)):
            for o, table in zip(out, (self.up_pct, self.down_pct, self.shut_kgf_s)):
                o[i] = np.interp(y[i], self.forces_kgf[i], table[i])
        return out[0], out[1], out[2]


def rig_flow_limit(model: RigModel, command_limit_pct: float, spans_kgf: np.ndarray,
                   share: float = FEEDFORWARD_SHARE) -> RigFlowLimit:
    """Every channel's :class:`RigFlowLimit` across its span ``spans_kgf`` (N, 2: low, high)."""
    spans = np.asarray(spans_kgf, float)
    forces, up, down, shut = [], [], [], []
    for m, (lo, hi) in zip(model.channels, spans):
        f = np.linspace(lo, hi, FORCE_POINTS) if hi > lo else np.array([lo, lo + 1.0])
        lim = valve_limit(m, command_limit_pct, f, share)
        d = np.array([steady_rate_kgf_s(m, np.zeros(1), y)[0] for y in f])
        forces.append(f)
        up.append((lim.up_kgf_s - d) / m.g)
        down.append((lim.down_kgf_s + d) / m.g)
        shut.append(d)
    return RigFlowLimit(list(model.names), np.array(forces), np.array(up), np.array(down),
                        np.array(shut), share * float(command_limit_pct))


def rig_minimum_durations_s(programme: RigProgramme, model: RigModel, limit: RigFlowLimit
                            ) -> tuple[np.ndarray, np.ndarray]:
    """Each segment's shortest duration (s) between load cases (module docstring), and which
    channel's valve sets it (its index). Raises :class:`~core.errors.ParameterError` naming the
    segment and the channel when a valve cannot hold its force against the trends at all."""
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


def programme_flow_limit(programme: RigProgramme, model: RigModel, command_limit_pct: float) -> RigFlowLimit:
    """:func:`rig_flow_limit` across each channel's span in the programme."""
    R = programme.r_kgf
    return rig_flow_limit(model, command_limit_pct, np.c_[R.min(axis=1), R.max(axis=1)])


@dataclass(frozen=True)
class RigProgrammeTiming:
    """A rig programme's time beside its valve-limited minimum (``stand load --rig --plan``)."""

    programme_time_s: float
    minimum_s: np.ndarray          #: per segment
    binding: np.ndarray            #: per segment, the channel whose valve sets its minimum
    names: list[str]
    limit: RigFlowLimit

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
        sets = ", ".join(f"{n} {c}" for n, c in sorted(self.binding_counts().items(), key=lambda x: -x[1]))
        return (f"{label + ':':<24s}{self.programme_time_s:10.1f} s  ({len(self.minimum_s)} segments, "
                f"{self.ratio:.2f}x the minimum)\n"
                f"{'valve-limited minimum:':<24s}{self.minimum_time_s:10.1f} s  (every segment as fast as "
                f"the slowest valve allows, the neighbours'\n{'':<24s}flows through G counted, the "
                f"feedforward's command up to ±{self.limit.command_pct:.3g} %; segments set by: {sets})")

    def to_dict(self) -> dict:
        return {"programme_time_s": self.programme_time_s, "minimum_time_s": self.minimum_time_s,
                "ratio": self.ratio, "segments": int(len(self.minimum_s)),
                "segments_set_by": self.binding_counts()}


def rig_programme_timing(programme: RigProgramme, model: RigModel, command_limit_pct: float) -> RigProgrammeTiming:
    """The programme's time and its valve-limited minimum on the rig ``model`` describes."""
    limit = programme_flow_limit(programme, model, command_limit_pct)
    minimum, binding = rig_minimum_durations_s(programme, model, limit)
    return RigProgrammeTiming(programme.duration_s, minimum, binding, list(programme.names), limit)
