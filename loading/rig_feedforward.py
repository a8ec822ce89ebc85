r"""Feedforward through the rig model's inverse: every channel's command that makes the model
follow a multi-channel programme.

For the rig's model ``dy/dt = G·w(t − τ) + Δ + F(y)`` (:mod:`plant.rig`) the forces follow the
references ``r`` when the flows are

.. math::  w_k = G^{-1}\Big(\frac{r_{k+1} - r_k}{T} - \Delta - F(r_k)\Big),

(``F``: each channel's force-dependent rate terms, a leakage); each channel's flow ``w_j`` is
then made by its own valve as for one channel (:func:`loading.feedforward.feedforward_flow`:
its FLOW effects inverted per sample, through their own hooks, knowing the way its rod last
moved; its VALVE effects inverted; its command sent its own delay ``τ_j`` ahead). The one-channel
feedforward is the case N = 1.

The **independent** feedforward (the baseline, :func:`channel_feedforward`) is today's
one-channel feedforward on each channel from its own model (``w_j = (ṙ_j − Δ_j − F_j)/g_j``): it
ignores what the neighbours' flows do to the channel's force, which the structure adds at
``G_ij·w_j``; on a load-case programme, where all channels move at once, that is the error the
coupling makes.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from plant.rig import RigModel

from .feedforward import Feedforward, feedback_scale, feedforward, feedforward_flow, own_rate

#: the valve command's resolution (%): one count of the CiA 408 setpoint (16384 counts per
#: 100 %, dbc.profile); the rig's feedforward plans no flow below it
RESOLUTION_PCT = 100.0 / 16384


@dataclass
class RigFeedforward:
    """Each channel's :class:`~loading.feedforward.Feedforward` for one programme, and the
    flows ``w`` (N, K) they were made for."""

    channels: list[Feedforward]
    flow_pct: np.ndarray

    @property
    def u_pct(self) -> np.ndarray:
        """(N, K): every channel's command per cycle."""
        return np.array([f.u_pct for f in self.channels])

    @property
    def peak_pct(self) -> np.ndarray:
        return np.array([f.peak_pct for f in self.channels])

    def scales(self, boosts: Sequence[float]) -> np.ndarray:
        """(N, K): each valve's share of the feedback (:func:`loading.feedforward.feedback_scale`
        at its channel's ρ)."""
        return np.array([feedback_scale(f, b) for f, b in zip(self.channels, boosts)])


def required_flows(model: RigModel, r_kgf: np.ndarray, period_s: float) -> tuple[np.ndarray, list[list[str]]]:
    """``w`` (N, K) for the references ``r_kgf`` (N, K) (module docstring), and per channel the
    names of what was taken off its rate (``base``, its FORCE effects)."""
    R = np.asarray(r_kgf, float)
    rates, taken = [], []
    for m, r in zip(model.channels, R):
        rate, names = own_rate(m, r, period_s)
        rates.append(rate)
        taken.append(names)
    return np.linalg.solve(model.G, np.array(rates)), taken


def rig_feedforward(model: RigModel, r_kgf: np.ndarray, period_s: float,
                    directions: Sequence[float | None] | None = None,
                    resolution_pct: float = RESOLUTION_PCT) -> RigFeedforward:
    """Every channel's command through the rig model's inverse (module docstring);
    ``directions``: per channel the way its rod last moved before the references start (±1,
    None: the way it first moves); ``resolution_pct``: no planned flow command below it (a
    valve whose channel's force is made by its neighbours runs at small flows for long, where
    a flow of a fraction of a count, which the valve cannot be sent, would be a planned
    reversal the rod never makes)."""
    R = np.asarray(r_kgf, float)
    w, taken = required_flows(model, R, period_s)
    directions = list(directions) if directions is not None else [None] * model.n
    ffs = [feedforward_flow(m, w[i], R[i], period_s, direction=directions[i], inverted=taken[i] + ["G⁻¹"],
                            resolution_pct=resolution_pct)
           for i, m in enumerate(model.channels)]
    return RigFeedforward(ffs, w)


def channel_feedforward(model: RigModel, r_kgf: np.ndarray, period_s: float,
                        directions: Sequence[float | None] | None = None) -> RigFeedforward:
    """Today's one-channel feedforward on every channel from its own model (the independent
    baseline: the coupling is left to the feedback)."""
    R = np.asarray(r_kgf, float)
    directions = list(directions) if directions is not None else [None] * model.n
    ffs = [feedforward(m, R[i], period_s, direction=directions[i]) for i, m in enumerate(model.channels)]
    return RigFeedforward(ffs, np.array([f.q_pct for f in ffs]))
