r"""Null pacing for a rig: the programme's one clock waits at a load case until every channel's
force will be there, so no channel skips a load case and the ratios hold at each one.

As for one channel (:mod:`loading.pacing`), the programme does not run on the wall clock: its
position ``p`` (samples of the planned references, common to every channel, fractional)
advances by a speed ``s ≤ 1`` a cycle, and every reference, feedforward and schedule of the
feedback is read there. Every channel's feedforward is sent
its own delay ``τ_i = m_i·T`` ahead, so the decision on load case ``k`` (sample ``n_k``) is taken
at its *gate* ``n_k − max_i m_i``, before any channel's command toward the next load case
leaves. There every channel's force is predicted past its own delay from the commands in
flight,

.. math::  \hat y_i = y_i + \sum_{\text{in flight}} \Big( s\,\big(r_i(p + m_i + 1) - r_i(p + m_i)\big)
           + G_{ii}\,T\,(u_i - u^{ff}_i) \Big)

(the plan's rise from the feedforward's share, the feedback's extra through the channel's own
gain), scaled by what the channel delivered of the plan over its last delay, ``ρ_i`` (as for one
channel: kept while the plan asked for more than 2ε, within
:data:`loading.pacing.DELIVERY_RANGE`; a channel whose structure or valve gives less than the
model, e.g. a neighbour's flow through a softer structure, delivers less of the commands in
flight too), and the programme waits while any channel is short of its level by more than its
tolerance ``ε_i`` (``L_i − ŷ_i`` along its way; a channel whose level does not change, either
side). While it waits every reference stands, each valve's feedforward is the flow that holds
the forces (``−G⁻¹Δ``), and a P law through the design's mixing matrix drives the predicted
forces to the levels, each valve moving only toward its level (``u = u_hold + M·K_p·(L − ŷ)``).
Once every channel will be within ``ε_i/2`` (:data:`loading.pacing.RELEASE_SHARE`) the clock
goes on together and the planned motion toward the next load case leaves. A wait longer than
the timeout stops the pass (:data:`loading.pacing.PACING_TIMEOUT`), naming the channel that is
furthest from its level.

**Slowing (dynamic).** While any channel's force lags its reference in its direction of travel
by more than its tolerance, ``d_i = ±(r_i(p) − y_i) > ε_i``, the one clock slows for all, down
to ``s_min``: ``s* = clip(min_i(1 − (d_i − ε_i)/ε_i), s_min, 1)``, falling at once and rising
back over :data:`loading.pacing.RECOVERY_S`; the feedforward is that of the slowed programme,
``s·u_ff + (1 − s)·u_hold`` per valve. So the structure sees the planned load distribution
along the way, not only at the load cases: the channels that keep up wait for the one that
lags. ``static`` waits only.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from .pacing import DELIVERY_RANGE, RECOVERY_S, RELEASE_SHARE, PacedClock, PacingOptions


@dataclass
class RigGate:
    """Where the programme decides on one load case."""

    position: int           #: the common sample at which the decision is taken
    turning: int            #: the load case's sample in the references
    levels_kgf: np.ndarray  #: every channel's level there
    way: np.ndarray         #: per channel +1 rising to it, −1 falling, 0 holding its level


class RigProgrammeClock(PacedClock):
    """The rig programme's common position (module docstring).

    Parameters
    ----------
    reference : (N, K) every channel's planned reference per sample (pre-roll, programme, unload)
    cases : the load cases' samples in the reference after the first, increasing
    delay_samples : (N,) each channel's feedforward lead, whole samples
    gains : (N,) each channel's own gain ``G_ii``, kgf/(%·s)
    period_s : T
    options : static or dynamic pacing (:class:`~loading.pacing.PacingOptions`)
    tolerances_kgf : (N,) ε per channel
    start : the first sample a gate may lie at (the programme's start)
    """

    def __init__(self, reference: np.ndarray, cases: np.ndarray, delay_samples, gains, period_s: float,
                 options: PacingOptions, tolerances_kgf, start: int = 0) -> None:
        self.r = np.asarray(reference, float)
        self.n_ch = self.r.shape[0]
        self._begin_clock(self.r.shape[1], period_s, options)
        self.m = np.maximum(np.asarray(delay_samples, int), 1)
        self.gT = np.asarray(gains, float) * period_s
        self.tol = np.asarray(tolerances_kgf, float)
        lead = int(self.m.max())
        self.gates: list[RigGate] = []
        previous = start
        for c in np.asarray(cases, int):
            before = self.r[:, max(c - 1, 0)]
            self.gates.append(RigGate(max(c - lead, previous + 1), int(c), self.r[:, c].copy(),
                                      np.sign(self.r[:, c] - before)))
            previous = int(c)
        self._inflight = [deque([0.0] * int(m), maxlen=int(m)) for m in self.m]
        self._inflight_sum = np.zeros(self.n_ch)
        #: what the commands that acted over each channel's last delay should have made, and its
        #: force a delay ago: the delivery against the plan's (module docstring)
        self._acted = [deque([0.0] * int(m), maxlen=int(m)) for m in self.m]
        self._acted_sum = np.zeros(self.n_ch)
        self._forces = [deque(maxlen=int(m)) for m in self.m]
        self.delivery = np.ones(self.n_ch)
        self.predicted_kgf = np.full(self.n_ch, np.nan)

    def reference_at(self, p: float) -> np.ndarray:
        """Every channel's reference at the position ``p`` (linear between samples)."""
        k = int(p)
        if k >= self.n - 1:
            return self.r[:, -1].copy()
        f = p - k
        return self.r[:, k] + f * (self.r[:, k + 1] - self.r[:, k])

    def way_at(self, p: float) -> np.ndarray:
        """Every channel's direction of travel at ``p`` (0 where its reference stands)."""
        k = min(int(p), self.n - 2)
        return np.sign(self.r[:, k + 1] - self.r[:, k])

    def short_kgf(self, gate: RigGate) -> np.ndarray:
        """How far each channel's predicted force is short of the gate's level (along its way;
        either side for a channel that holds its level)."""
        d = gate.levels_kgf - self.predicted_kgf
        return np.where(gate.way != 0, gate.way * d, np.abs(d))

    def advance(self, y) -> float:
        """Move the position for this cycle given every force ``y``; returns the position."""
        self.cycles += 1
        self.wait_began = False
        y = np.asarray(y, float)
        if self.cycles == 1:               # the first cycle reads the start
            self.predicted_kgf = y + self._inflight_sum
            return self.position
        for i, forces in enumerate(self._forces):
            if len(forces) == self.m[i]:
                made, planned = y[i] - forces[0], self._acted_sum[i]
                if abs(planned) > 2 * self.tol[i] and made * planned > 0:
                    self.delivery[i] = min(max(made / planned, DELIVERY_RANGE[0]), DELIVERY_RANGE[1])
            forces.append(y[i])
        self.predicted_kgf = y + self.delivery * self._inflight_sum
        if self.options.mode == "dynamic" and not self.waiting:
            lag = self.way_at(self.position) * (self.reference_at(self.position) - y)
            target = float(np.clip(np.min(1.0 - (lag - self.tol) / self.tol), self.options.min_speed, 1.0))
            self.speed = target if target < self.speed else min(target, self.speed + self.T / RECOVERY_S)
        step = self.speed
        gate = self.gate
        if gate is not None and self.position + step >= gate.position:
            limit = (RELEASE_SHARE if self.waiting else 1.0) * self.tol
            if np.any(self.short_kgf(gate) > limit):
                self._wait()
                step = max(gate.position - self.position, 0.0)
            else:                          # every force is there: the planned motion leaves
                step = self._pass_gate(step)
        return self._move(step)

    def sent(self, command_pct: np.ndarray, feedforward_pct: np.ndarray) -> None:
        """Every command that went out this cycle and its feedforward share (module docstring)."""
        p = self.position
        for i, q in enumerate(self._inflight):
            a = self._ref_at(i, p + self.m[i])
            planned = self._step * (self._ref_at(i, p + self.m[i] + 1) - a) if self._step else 0.0
            delta = planned + self.gT[i] * (float(command_pct[i]) - float(feedforward_pct[i]))
            oldest = q[0]                  # it acts from now on: over the channel's next delay
            self._inflight_sum[i] += delta - oldest
            q.append(delta)
            acted = self._acted[i]
            self._acted_sum[i] += oldest - acted[0]
            acted.append(oldest)

    def _ref_at(self, i: int, p: float) -> float:
        k = int(p)
        if k >= self.n - 1:
            return float(self.r[i, -1])
        return float(self.r[i, k] + (p - k) * (self.r[i, k + 1] - self.r[i, k]))
