r"""Null pacing: the programme's clock waits or slows for the force, so no turning point is skipped.

As commercial test controllers do, the programme does not run on the wall clock: its position
``p`` (in samples of the planned reference, fractional) advances by a speed ``s ≤ 1`` a cycle,

.. math::  p_{n+1} = p_n + s_n,

and the reference, the feedforward and the feedback's schedule are read at ``p``. At ``s = 1``
(the force follows) this is the planned programme, sample for sample.

**Slowing (dynamic).** While the force lags the reference in the direction of travel by more
than the tolerance ``ε``, ``d = ±(r(p) − y) > ε``, the programme slows, down to ``s_min``:

.. math::  s^* = \operatorname{clip}\big(1 - (d - ε)/ε,\ s_{min},\ 1\big),

and the speed falls at once, rising back over :data:`RECOVERY_S`. The feedforward is that of the
slowed programme: for the base model, the flow for the rate ``s·ṙ`` is
``s·u_ff + (1 − s)·u_hold``, with ``u_hold = −Δ/g`` the command that holds a force.

**Waiting at a turning point (static and dynamic).** The feedforward is sent a delay ``τ``
ahead, so the reversal toward the next turning point leaves ``m = τ/T`` samples before the
reference reaches it: that is the point to decide, the turning point's *gate*. The force the
commands in flight will have made when the next one acts is predicted from the plan,

.. math::  \hat y_n = y_n + \sum_{j=n-m}^{n-1} \Big( s_j\,\big(r(p_j + m + 1) - r(p_j + m)\big)
           + g\,T\,(u_j - u^{ff}_j) \Big)

(what the feedforward's share of each command in flight delivers by the plan, and the
feedback's share through the gain), scaled by what the stand delivered of the plan over the
last delay, ``ρ = (y_n − y_{n−m}) / Σ_{acted}(…)`` (kept while the plan asked for less than
2ε, within :data:`DELIVERY_RANGE`): a valve slower than the model (a flow limit it lacks)
delivers less than the plan of the commands in flight too. At the gate, while ``±(L − ŷ) > ε`` the programme waits:
the reference stands, the feedforward holds, and a P law drives the predicted force to the
level ``L`` (a Smith predictor: no overshoot from the delay), moving the rod only toward it
(:meth:`loading.controller.PIFeedforward.wait_step`). Once the force will be within ``ε/2`` of
``L`` (:data:`RELEASE_SHARE`) the programme goes on and the planned reversal leaves. A wait longer than ``timeout_s`` stops the pass (:data:`PACING_TIMEOUT`): the stand
cannot reach the level. A segment shorter than the delay has its gate right after the turning
point before it (the decision cannot come earlier).

``static`` waits only; ``dynamic`` slows and waits. The time the programme spent pacing
(its length on the stand minus its planned length) is reported per pass.
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
    """Where the programme decides on one turning point (module docstring)."""

    position: int      #: sample of the reference at which the reversal toward it would leave
    turning: int       #: the turning point's sample in the reference
    level_kgf: float
    way: float         #: +1 approaching a peak, −1 a valley


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


class PacedClock:
    """What a stand's and a rig's programme clocks share (:class:`ProgrammeClock`,
    :class:`loading.rig_pacing.RigProgrammeClock`): the position and its speed, the waits at
    the gates (each with a ``turning`` sample), and the record of what pacing did."""

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


class ProgrammeClock(PacedClock):
    """The programme's position, advanced once a cycle (module docstring).

    Parameters
    ----------
    reference : (N,) the planned reference per sample (pre-roll, programme, unload), kgf
    turnings : the reference's samples that are peaks or valleys, increasing
    delay_samples : m, the whole samples of the feedforward's lead (τ/T rounded)
    gain : g of the controller's model, kgf/(%·s)
    period_s : T
    options : :class:`PacingOptions` (mode ``off``: the position is the cycle count)
    tolerance_kgf : ε
    start : the first sample gates may lie at (the programme's start after the pre-roll)
    """

    def __init__(self, reference: np.ndarray, turnings: np.ndarray, delay_samples: int,
                 gain: float, period_s: float, options: PacingOptions, tolerance_kgf: float,
                 start: int = 0) -> None:
        self.r = np.asarray(reference, float)
        self._begin_clock(len(self.r), period_s, options)
        self.m = max(int(delay_samples), 1)
        self.gT = gain * period_s
        self.tol = float(tolerance_kgf)
        self.gates: list[Gate] = []
        previous = start
        for i in np.asarray(turnings, int):
            way = math.copysign(1.0, self.r[i] - self.r[max(i - 1, 0)])
            self.gates.append(Gate(max(i - self.m, previous + 1), int(i), float(self.r[i]), way))
            previous = int(i)
        self._inflight: deque[float] = deque([0.0] * self.m, maxlen=self.m)
        self._inflight_sum = 0.0
        #: what the commands that acted over the last delay should have made, and the force
        #: a delay ago: the stand's delivery against the plan's (module docstring)
        self._acted_sum = 0.0
        self._acted: deque[float] = deque([0.0] * self.m, maxlen=self.m)
        self._forces: deque[float] = deque(maxlen=self.m)
        self.delivery = 1.0
        self.predicted_kgf = math.nan

    # -- per cycle ---------------------------------------------------------------------------
    def reference_at(self, p: float) -> float:
        k = int(p)
        if k >= self.n - 1:
            return float(self.r[-1])
        f = p - k
        return float(self.r[k] + f * (self.r[k + 1] - self.r[k]))

    def way_at(self, p: float) -> float:
        """The direction of travel of the planned reference at ``p`` (0 where it stands)."""
        k = min(int(p), self.n - 2)
        d = self.r[k + 1] - self.r[k]
        return 0.0 if d == 0 else math.copysign(1.0, d)

    def advance(self, y: float) -> float:
        """Move the position for this cycle given the force ``y``; returns the position."""
        self.cycles += 1
        if self.cycles == 1:               # the first cycle reads the start
            return self.position
        mode = self.options.mode
        self.wait_began = False
        if len(self._forces) == self.m:
            made = y - self._forces[0]
            planned = self._acted_sum
            if abs(planned) > 2 * self.tol and made * planned > 0:
                self.delivery = min(max(made / planned, DELIVERY_RANGE[0]), DELIVERY_RANGE[1])
        self._forces.append(y)
        self.predicted_kgf = y + self.delivery * self._inflight_sum
        if mode == "dynamic" and not self.waiting:
            lag = self.way_at(self.position) * (self.reference_at(self.position) - y)
            target = min(1.0, max(self.options.min_speed, 1.0 - (lag - self.tol) / self.tol))
            self.speed = target if target < self.speed else min(target, self.speed + self.T / RECOVERY_S)
        step = self.speed
        p = self.position
        if self.next_gate < len(self.gates):
            gate = self.gates[self.next_gate]
            if p + step >= gate.position:
                short = gate.way * (gate.level_kgf - self.predicted_kgf)
                if short > (RELEASE_SHARE * self.tol if self.waiting else self.tol):
                    self._wait()
                    step = max(gate.position - p, 0.0)
                else:                         # the force is there: the reversal leaves as planned
                    step = self._pass_gate(step)
        return self._move(step)

    def sent(self, command_pct: float, feedforward_pct: float) -> None:
        """The command that went out this cycle and its feedforward share: the plan's delivery
        of the command in flight (module docstring)."""
        s = self._step
        p = self.position
        planned = s * (self.reference_at(p + self.m + 1) - self.reference_at(p + self.m)) if s else 0.0
        delta = planned + self.gT * (command_pct - feedforward_pct)
        oldest = self._inflight[0]                 # it acts from now on: over the next delay
        self._inflight_sum += delta - oldest
        self._inflight.append(delta)
        self._acted_sum += oldest - self._acted[0]
        self._acted.append(oldest)
