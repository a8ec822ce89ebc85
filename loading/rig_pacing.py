r"""Null pacing for a rig: the programme's one clock waits at a load case until every channel's
force will be there, so no channel skips a load case and the ratios hold at each one.

As for one channel (:mod:`loading.pacing`, ``static``), the programme does not run on the wall
clock: its position ``p`` (samples of the planned references, common to every channel) advances
one sample a cycle, or stands while the programme waits. Every channel's feedforward is sent
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

Only ``static`` pacing on a rig: slowing the common clock for a lagging channel (``dynamic``)
is one channel's so far.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from .pacing import DELIVERY_RANGE, RELEASE_SHARE, PacingOptions, PacingRecord


@dataclass
class RigGate:
    """Where the programme decides on one load case."""

    position: int           #: the common sample at which the decision is taken
    case: int               #: the load case's sample in the references
    levels_kgf: np.ndarray  #: every channel's level there
    way: np.ndarray         #: per channel +1 rising to it, −1 falling, 0 holding its level


class RigProgrammeClock:
    """The rig programme's common position (module docstring).

    Parameters
    ----------
    reference : (N, K) every channel's planned reference per sample (pre-roll, programme, unload)
    cases : the load cases' samples in the reference after the first, increasing
    delay_samples : (N,) each channel's feedforward lead, whole samples
    gains : (N,) each channel's own gain ``G_ii``, kgf/(%·s)
    period_s : T
    options : static pacing
    tolerances_kgf : (N,) ε per channel
    start : the first sample a gate may lie at (the programme's start)
    """

    def __init__(self, reference: np.ndarray, cases: np.ndarray, delay_samples, gains, period_s: float,
                 options: PacingOptions, tolerances_kgf, start: int = 0) -> None:
        self.r = np.asarray(reference, float)
        self.n_ch, self.n = self.r.shape
        self.m = np.maximum(np.asarray(delay_samples, int), 1)
        self.gT = np.asarray(gains, float) * period_s
        self.T = period_s
        self.options = options
        self.tol = np.asarray(tolerances_kgf, float)
        lead = int(self.m.max())
        self.gates: list[RigGate] = []
        previous = start
        for c in np.asarray(cases, int):
            before = self.r[:, max(c - 1, 0)]
            self.gates.append(RigGate(max(c - lead, previous + 1), int(c), self.r[:, c].copy(),
                                      np.sign(self.r[:, c] - before)))
            previous = int(c)
        self.position = 0
        self.waiting = False
        self.wait_began = False
        self.next_gate = 0
        self.cycles = 0
        self._step = 1
        self._wait_start = 0.0
        self._inflight = [deque([0.0] * int(m), maxlen=int(m)) for m in self.m]
        self._inflight_sum = np.zeros(self.n_ch)
        #: what the commands that acted over each channel's last delay should have made, and its
        #: force a delay ago: the delivery against the plan's (module docstring)
        self._acted = [deque([0.0] * int(m), maxlen=int(m)) for m in self.m]
        self._acted_sum = np.zeros(self.n_ch)
        self._forces = [deque(maxlen=int(m)) for m in self.m]
        self.delivery = np.ones(self.n_ch)
        self.predicted_kgf = np.full(self.n_ch, np.nan)
        self.record = PacingRecord()
        #: the time waited heading to each load case, by its sample
        self.paced_by_turning: dict[int, float] = {}

    @property
    def gate(self) -> RigGate | None:
        return self.gates[self.next_gate] if self.next_gate < len(self.gates) else None

    def short_kgf(self, gate: RigGate) -> np.ndarray:
        """How far each channel's predicted force is short of the gate's level (along its way;
        either side for a channel that holds its level)."""
        d = gate.levels_kgf - self.predicted_kgf
        return np.where(gate.way != 0, gate.way * d, np.abs(d))

    def advance(self, y) -> int:
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
        step = 1
        gate = self.gate
        if gate is not None and self.position + 1 >= gate.position:
            limit = (RELEASE_SHARE if self.waiting else 1.0) * self.tol
            if np.any(self.short_kgf(gate) > limit):
                if not self.waiting:
                    self.waiting = self.wait_began = True
                    self._wait_start = self.cycles * self.T
                    self.record.waits += 1
                step = max(gate.position - self.position, 0)
            else:
                if self.waiting:           # every force is there: the planned motion leaves
                    waited = self.cycles * self.T - self._wait_start
                    self.record.longest_wait_s = max(self.record.longest_wait_s, waited)
                self.waiting = False
                self.next_gate += 1
        if self.waiting:
            self.record.wait_s += self.T
        if step < 1 and gate is not None:
            self.paced_by_turning[gate.case] = self.paced_by_turning.get(gate.case, 0.0) + self.T
            self.record.pacing_s += self.T
        self.position = min(self.position + step, self.n - 1)
        self._step = step
        return self.position

    @property
    def step_taken(self) -> int:
        """1 while the programme runs, 0 while it waits: the feedforward's share this cycle."""
        return self._step

    def waited_too_long(self) -> bool:
        return self.waiting and self.cycles * self.T - self._wait_start > self.options.timeout_s

    def sent(self, command_pct: np.ndarray, feedforward_pct: np.ndarray) -> None:
        """Every command that went out this cycle and its feedforward share (module docstring)."""
        p = self.position
        for i, q in enumerate(self._inflight):
            k = min(p + int(self.m[i]), self.n - 2)
            planned = self._step * (self.r[i, k + 1] - self.r[i, k])
            delta = planned + self.gT[i] * (float(command_pct[i]) - float(feedforward_pct[i]))
            oldest = q[0]                  # it acts from now on: over the channel's next delay
            self._inflight_sum[i] += delta - oldest
            q.append(delta)
            acted = self._acted[i]
            self._acted_sum[i] += oldest - acted[0]
            acted.append(oldest)

    @property
    def finished(self) -> bool:
        return self.position >= self.n - 1
