r"""Null pacing: the programme's one clock waits or slows for the forces, so no turning point and
no load case is skipped.

As commercial test controllers do, the programme does not run on the wall clock: its position
``p`` (in samples of the planned references, common to every channel, fractional) advances by a
speed ``s ≤ 1`` a cycle,

.. math::  p_{n+1} = p_n + s_n,

and every reference, feedforward and the feedback's schedule are read at ``p``. At ``s = 1``
(the forces follow) this is the planned programme, sample for sample.

**Slowing (dynamic).** While any channel's force lags its reference in its direction of travel
by more than its tolerance ``ε_i``, ``d_i = ±(r_i(p) − y_i) > ε_i``, the one clock slows for
all, down to ``s_min``:

.. math::  s^* = \operatorname{clip}\big(\min_i\,1 - (d_i - ε_i)/ε_i,\ s_{min},\ 1\big),

and the speed falls at once, rising back over :data:`RECOVERY_S`. The feedforward is that of the
slowed programme: ``s·u_ff + (1 − s)·u_hold`` per valve, ``u_hold`` the flows that hold the
forces (for the base model ``−G⁻¹Δ``; one channel ``−Δ/g``). So the structure sees the planned
load distribution along the way, not only at the load cases: the channels that keep up wait for
the one that lags.

**Waiting at a load case (static and dynamic).** Every channel's feedforward is sent its own
delay ``τ_i = m_i·T`` ahead, so the decision on load case ``k`` (sample ``n_k``) is taken at its
*gate* ``n_k − max_i m_i``, before any channel's command toward the next load case leaves. There
every channel's force is predicted past its own delay from the commands in flight,

.. math::  \hat y_i = y_i + \sum_{\text{in flight}} \Big( s\,\big(r_i(p + m_i + 1) - r_i(p + m_i)\big)
           + G_{ii}\,T\,(u_i - u^{ff}_i) \Big)

(what the feedforward's share of each command in flight delivers by the plan, and the
feedback's share through the channel's own gain), scaled by what the channel delivered of the
plan over its last delay, ``ρ_i = (y_n − y_{n−m}) / Σ_{acted}(…)`` (kept while the plan asked
for more than 2ε, within :data:`DELIVERY_RANGE`): a valve slower than the model (a flow limit it
lacks, a neighbour's flow through a softer structure) delivers less than the plan of the
commands in flight too. The programme waits while any channel is short of its level by more
than ``ε_i`` (``L_i − ŷ_i`` along its way; a channel whose level does not change, either side):
every reference stands, each valve's feedforward holds the forces, and a P law through the
design's mixing matrix drives the predicted forces to the levels (a Smith predictor: no
overshoot from the delay), each valve moving only toward its level
(:meth:`loading.controller.PIFeedforward.wait_step`). Once every channel will be within ``ε_i/2``
(:data:`RELEASE_SHARE`) the clock goes on together and the planned motion toward the next load
case leaves. A wait longer than ``timeout_s`` stops the pass (:data:`PACING_TIMEOUT`), naming the
channel furthest from its level. Gates are the load cases where some channel turns (a peak or a
valley: for one channel its peaks and valleys); a segment shorter than the delay has its gate
right after the load case before it (the decision cannot come earlier).

``static`` waits only; ``dynamic`` slows and waits. The time the programme spent pacing (its
length on the stand minus its planned length) is reported per pass.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from core.errors import ParameterError

PACING_MODES = ("off", "static", "dynamic")
#: the speed rises back to 1 over this long (s)
RECOVERY_S = 0.1
#: a wait ends once the predicted force is within this share of the tolerance of the level,
#: so the force lands inside the tolerance, not on its edge
RELEASE_SHARE = 0.5
#: the stand's delivery against the plan's is taken within this range
DELIVERY_RANGE = (0.1, 1.5)
#: reason a pass ends when a wait lasts longer than the timeout
PACING_TIMEOUT = "pacing_timeout"


@dataclass(frozen=True)
class PacingOptions:
    """How the programme waits for the force (module docstring)."""

    mode: str = "off"
    #: ε, kgf (None: :data:`DEFAULT_TOLERANCE_SHARE` of the programme's range)
    tolerance_kgf: float | None = None
    #: dynamic: the slowest share of the programme's speed
    min_speed: float = 0.2
    #: the longest wait at one turning point, s
    timeout_s: float = 10.0

    def check(self) -> None:
        if self.mode not in PACING_MODES:
            raise ParameterError(f"pacing {self.mode!r}: choose one of {', '.join(PACING_MODES)}")
        if self.tolerance_kgf is not None and not (math.isfinite(self.tolerance_kgf)
                                                   and self.tolerance_kgf > 0):
            raise ParameterError(f"pacing tolerance {self.tolerance_kgf} kgf: it must be a positive number")
        if not (0.01 <= self.min_speed <= 1):
            raise ParameterError(f"pacing min speed {self.min_speed}: give a share from 0.01 to 1")
        if not (math.isfinite(self.timeout_s) and self.timeout_s > 0):
            raise ParameterError(f"pacing timeout {self.timeout_s} s: it must be a positive number")

    @property
    def on(self) -> bool:
        return self.mode != "off"


#: the pacing tolerance unless given: this share of the programme's range (ISO 4965-1's 1 %, halved)
DEFAULT_TOLERANCE_SHARE = 0.005


@dataclass
class Gate:
    """Where the programme decides on one load case (module docstring)."""

    position: int           #: the common sample at which the decision is taken
    turning: int            #: the load case's sample in the references
    levels_kgf: np.ndarray  #: every channel's level there
    way: np.ndarray         #: per channel +1 rising to it, −1 falling, 0 holding its level


@dataclass
class PacingRecord:
    """What pacing did in one pass."""

    pacing_s: float = 0.0              #: time on the stand beyond the planned, s
    waits: int = 0                     #: turning points the programme waited at
    wait_s: float = 0.0                #: of which waiting, s
    slowed_s: float = 0.0              #: time run below full speed (not waiting), s
    longest_wait_s: float = 0.0

    def to_dict(self) -> dict:
        return dict(self.__dict__)


class ProgrammeClock:
    """The programme's common position, advanced once a cycle (module docstring).

    Parameters
    ----------
    reference : (N, K) every channel's planned reference per sample (pre-roll, programme, unload)
    cases : the samples of the load cases it gates, increasing
    delay_samples : (N,) each channel's feedforward lead, whole samples
    gains : (N,) each channel's own gain ``G_ii``, kgf/(%·s)
    period_s : T
    options : static or dynamic pacing (:class:`PacingOptions`)
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
        self.gates: list[Gate] = []
        previous = start
        for c in np.asarray(cases, int):
            before = self.r[:, max(c - 1, 0)]
            self.gates.append(Gate(max(c - lead, previous + 1), int(c), self.r[:, c].copy(),
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

    def _begin_clock(self, n: int, period_s: float, options: PacingOptions) -> None:
        self.n = n
        self.T = period_s
        self.options = options
        self.position = 0.0
        self.speed = 1.0
        self.waiting = False
        self.next_gate = 0
        self._wait_start = 0.0
        self.record = PacingRecord()
        self.cycles = 0
        self._step = 1.0
        #: True in the cycle a wait begins
        self.wait_began = False
        #: the time paced (waiting or slowed) heading to each turning point, by its sample
        self.paced_by_turning: dict[int, float] = {}

    def _wait(self) -> None:
        """The programme waits at its gate this cycle."""
        if not self.waiting:
            self.wait_began = True
            self.waiting = True
            self._wait_start = self.cycles * self.T
            self.record.waits += 1

    def _pass_gate(self, step: float) -> float:
        """The force is there: the planned motion leaves (at full speed after a wait); returns
        this cycle's step."""
        if self.waiting:
            waited = self.cycles * self.T - self._wait_start
            self.record.longest_wait_s = max(self.record.longest_wait_s, waited)
            self.speed = step = 1.0
        self.waiting = False
        self.next_gate += 1
        return step

    def _move(self, step: float) -> float:
        """Advance by ``step`` and keep the record; returns the position."""
        step = float(step)
        if self.waiting:
            self.record.wait_s += self.T
        elif self.speed < 1.0:
            self.record.slowed_s += self.T
        if step < 1.0 and self.next_gate < len(self.gates):
            k = self.gates[self.next_gate].turning
            self.paced_by_turning[k] = self.paced_by_turning.get(k, 0.0) + self.T * (1.0 - step)
        self.record.pacing_s += self.T * (1.0 - step)
        self.position = min(self.position + step, self.n - 1.0)
        self._step = step
        return self.position

    @property
    def step_taken(self) -> float:
        """The speed of this cycle (0 while waiting): the feedforward's share this cycle."""
        return self._step

    def waited_too_long(self) -> bool:
        return self.waiting and self.cycles * self.T - self._wait_start > self.options.timeout_s

    @property
    def gate(self):
        return self.gates[self.next_gate] if self.next_gate < len(self.gates) else None

    @property
    def finished(self) -> bool:
        return self.position >= self.n - 1.0

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

    def short_kgf(self, gate: Gate) -> np.ndarray:
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
