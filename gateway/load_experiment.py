"""The load experiment: one pass of a loading programme under the designed controller.

A pass is one run of the gateway like any experiment (same supervisor, limits, recorder, run
directory, capture)::

    approach   the force is brought to the pre-roll's start by a short P loop that moves the
               rod one way only (holding rather than reversing it)
    pre-roll   a haversine into the first level (:data:`PRE_ROLL_SHARE` of the range, in
               :data:`PRE_ROLL_S`), moving the way the valve holds the force against the
               model's trend Δ (down for Δ > 0)
    programme  u = feedforward through the model's inverse + PI (loading.controller)
    unload     a haversine from the last level to the unload level, tracked the same way

**No reversal the model does not plan.** With a reversal effect the stand's gain right after
the rod reverses at a small command is many times the steady one (17× at b = 2, p = 0.7, where
the design's margins hold up to ``ρ`` = 3); on the emulated stands a reversal brings 100-200 kgf
of force the steady gain does not predict. The feedforward plans it at every turning point of
the programme; a reversal it does not plan throws the force off by as much, and a feedback that
reverses the valve near a turning point, where the planned command is small, rings (the extra
cycles of the tracking report). So: wherever the model predicts a gain above ``ρ`` (the
feedback is scaled down there, see :func:`loading.feedforward.feedback_scale`) and during the
pre-roll, the command keeps the feedforward's sign or holds (0): the feedback slows the rod, it
does not reverse it, and the rod reverses where and when the feedforward plans.

**The approach and the pre-roll** give the programme a start the model plans. A plain P loop
ends holding the force with small commands of either sign (its noise, and with a reversal
effect a limit cycle), so the way the rod last moved would be unknown. Here the approach moves
the rod one way only, so that way is known, and the feedforward is computed knowing it (both
ways are planned before the run; the one the force starts on is used). The pre-roll moves the
way a held force's command points (against the trend: a held force needs ``q = −Δ/g``), so the
command keeps one sign from the pre-roll into the hold at the first level: the programme's
first motion is a single planned reversal or none, never a brief reversal back and forth at a
small command. The programme's first commands, due a delay before it starts, go out during the
pre-roll: a programme that starts at full rate (a sine) starts on time. A pre-roll that would
cross 0 kgf starts at 0 kgf.

Everything that can be checked is checked before anything moves: the controller's period
against the loop's, the programme against the force limit, the feedforward's peak command
against the command limit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from core.errors import ParameterError
from loading.compensation import Compensation
from loading.controller import PIFeedforward
from loading.design import ControllerDesign
from loading.feedforward import Feedforward, feedback_scale, feedforward
from loading.gain_monitor import GAIN_ALARM, GainMonitor
from loading.minimum_time import FEEDFORWARD_SHARE
from loading.pacing import DEFAULT_TOLERANCE_SHARE, PACING_TIMEOUT, PacingOptions, ProgrammeClock
from loading.programme import Programme, check_programme

from .experiments.phases import PhasedExperiment, SetPointApproach
from .limits import SafetyLimits
from .supervisor import Unloader

#: the pre-roll into the programme's first level: this share of its range (at least three
#: times the approach's tolerance), in this time (s)
PRE_ROLL_SHARE = 0.02
PRE_ROLL_S = 0.6


def _unload_tail(last_kgf: float, unload_kgf: float, rate_kgf_s: float, period_s: float) -> np.ndarray:
    """A haversine from the last level to the unload level at a peak rate (samples after the
    programme's last)."""
    span = unload_kgf - last_kgf
    if abs(span) < 1e-9:
        return np.zeros(0)
    n = max(int(round(math.pi * abs(span) / (2 * rate_kgf_s) / period_s)), 1)
    s = np.arange(1, n + 1) / n
    return last_kgf + span * (1 - np.cos(np.pi * s)) / 2


def _pre_roll(programme: Programme, trend_kgf_s: float, tolerance_kgf: float) -> np.ndarray:
    """The pre-roll's samples before the programme's first (module docstring): a haversine
    into the first level, moving the way a held force's command points (against the trend; the
    programme's first way without one)."""
    r = programme.r_kgf
    if trend_kgf_s:
        way = -math.copysign(1.0, trend_kgf_s)
    else:
        moves = np.flatnonzero(r != r[0])
        way = float(np.sign(r[moves[0]] - r[0])) if len(moves) else 1.0
    start = r[0] - way * max(PRE_ROLL_SHARE * programme.range_kgf, 3 * tolerance_kgf)
    if np.sign(start) != np.sign(r[0]):
        start = 0.0
    n = max(int(round(PRE_ROLL_S / programme.period_s)), 1)
    s = np.arange(n) / n
    return start + (r[0] - start) * (1 - np.cos(np.pi * s)) / 2


@dataclass
class _Plan:
    """What one pass commands, for one way into the programme (module docstring)."""

    reference: np.ndarray     #: pre-roll, programme, unload (kgf per cycle)
    ff: Feedforward
    scale: np.ndarray         #: the share of the feedback gain per cycle
    way: np.ndarray           #: the sign the command must keep per cycle (0: free)


def _plan(controller: ControllerDesign, reference: np.ndarray, lead: int, period_s: float,
          way: float) -> _Plan:
    """The pass's commands when the rod last moved ``way`` before the pre-roll."""
    if controller.feedforward:
        ff = feedforward(controller.model, reference, period_s, direction=way)
    else:
        ff = Feedforward(np.zeros_like(reference), np.zeros_like(reference), [], ["all: feedback alone"])
    # feedback alone (P control) runs as it was given: scale 1, and its sign is never held
    scale = feedback_scale(ff, controller.boost)
    held = scale < 1.0
    held[:lead] = True
    return _Plan(reference, ff, scale, np.where(held, np.sign(ff.u_pct), 0.0))


class OneWayApproach(SetPointApproach):
    """The set-point approach moving the rod one way only (``way``, ±1: toward the set point
    from where the force starts); a command the other way is held at 0."""

    way = 1.0

    def step(self, t: float, y: float) -> float | None:
        u = super().step(t, y)
        return 0.0 if u is not None and self.way * u < 0 else u


class LoadProgramme(PhasedExperiment):
    """One pass of a loading programme under the designed controller (module docstring)."""

    name = "load"

    def __init__(self, programme: Programme, controller: ControllerDesign,
                 compensation: Compensation | None = None, unload_kgf: float = 0.0,
                 settle_gain: float = 0.02, settle_limit_pct: float = 20.0,
                 settle_tolerance_kgf: float = 20.0, settle_max_s: float = 20.0,
                 guard_fraction: float = 0.95, pacing: PacingOptions | None = None,
                 monitor: GainMonitor | None = None, unload_limits: SafetyLimits | None = None) -> None:
        self.programme = programme
        self.controller = controller
        self.compensation = compensation
        self.pacing = pacing or PacingOptions()
        self.pacing.check()
        #: the programme's clock of the pass (None without pacing: the clock is the cycle count)
        self.clock: ProgrammeClock | None = None
        #: with pacing: the clock's position per cycle of the main phase (samples of reference)
        self.positions: list[float] = []
        #: the gain monitor of the test (loading.gain_monitor), shared by its passes
        self.monitor = monitor
        self.unload_limits = unload_limits or SafetyLimits()
        #: a gain alarm's controlled unload, once it began
        self.unloader: Unloader | None = None
        kinds = programme.kinds()
        self.commanded = (programme.with_levels(compensation.levels(programme.levels_kgf, kinds))
                          if compensation is not None else programme)
        peak_rate = float(np.max(np.abs(programme.rate_kgf_s()))) or 1000.0
        tail = _unload_tail(float(self.commanded.r_kgf[-1]), unload_kgf, min(peak_rate, 2500.0),
                            programme.period_s)
        pre = _pre_roll(self.commanded, controller.model.delta, settle_tolerance_kgf)
        #: cycles of the main phase before the programme's start (the pre-roll)
        self.lead = len(pre)
        reference = np.r_[pre, self.commanded.r_kgf, tail]
        #: by the way the approach moves the rod (+1: up to the pre-roll's start)
        self.plans = {way: _plan(controller, reference, self.lead, programme.period_s, way)
                      for way in (1.0, -1.0)}
        self.plan = self.plans[1.0]
        self.unload_kgf = unload_kgf
        self.max_command_pct = controller.command_limit_pct
        self.law = PIFeedforward(controller.kp_pct_per_kgf, controller.ti_s, programme.period_s,
                                 controller.command_limit_pct)
        self._init_phases(float(self.reference[0]), settle_gain, settle_limit_pct,
                          settle_tolerance_kgf, settle_max_s, guard_fraction)
        self.approach = OneWayApproach(float(self.reference[0]), settle_gain, settle_limit_pct,
                                       settle_tolerance_kgf, max_s=settle_max_s)

    @property
    def reference(self) -> np.ndarray:
        return self.plan.reference

    @property
    def ff(self) -> Feedforward:
        return self.plan.ff

    @property
    def main_duration_s(self) -> float:
        return len(self.reference) * self.programme.period_s

    @property
    def max_duration_s(self) -> float:
        slowest = self.pacing.min_speed if self.pacing.mode == "dynamic" else 1.0
        return self.approach.max_s + self.main_duration_s / slowest

    @property
    def pacing_tolerance_kgf(self) -> float:
        p = self.pacing
        return p.tolerance_kgf if p.tolerance_kgf is not None else \
            DEFAULT_TOLERANCE_SHARE * self.programme.range_kgf

    @property
    def programme_start_s(self) -> float | None:
        """The run's time at the programme's start (None before the approach ended)."""
        if self.main_start_s is None:
            return None
        return self.main_start_s + self.lead * self.programme.period_s

    def params(self) -> dict[str, Any]:
        return {"programme": self.programme.source, "turning_points": int(len(self.programme.turning_idx)),
                "range_kgf": self.programme.range_kgf, "controller_model": self.controller.model_spec,
                "kp_pct_per_kgf": self.controller.kp_pct_per_kgf, "ti_s": self.controller.ti_s,
                "feedforward_inverts": self.ff.inverted, "feedforward_does_not_invert": self.ff.not_inverted,
                "feedback_scale_min": float(self.plan.scale.min()),
                "sign_held_share": float(np.mean(self.plan.way != 0)),
                "pre_roll_from_kgf": float(self.reference[0]),
                "compensated": self.compensation is not None, "unload_kgf": self.unload_kgf,
                "pacing": self.pacing.mode,
                **({"pacing_tolerance_kgf": self.pacing_tolerance_kgf, "pacing_min_speed": self.pacing.min_speed,
                    "pacing_timeout_s": self.pacing.timeout_s} if self.pacing.on else {}),
                **({"gain_monitor": {k: v for k, v in vars(self.monitor.options).items()},
                    "feedforward_g": self.monitor.g_follow} if self.monitor is not None else {}),
                **self.phase_params()}

    def check(self, period_s: float, force_limit_kgf: float, command_limit_pct: float) -> None:
        """Refuse what the stand must not be asked for, before anything moves."""
        if abs(self.controller.period_s - period_s) > 1e-9:
            raise ParameterError(
                f"the controller was designed for a period of {self.controller.period_s * 1e3:g} ms but "
                f"the loop runs at {period_s * 1e3:g} ms; design it again with --period-ms "
                f"{period_s * 1e3:g}")
        check_programme(self.programme, force_limit_kgf)
        check_programme(self.commanded, force_limit_kgf)
        limit = min(command_limit_pct, self.controller.command_limit_pct)
        ff = max((plan.ff for plan in self.plans.values()), key=lambda f: f.peak_pct)
        peak = ff.peak_pct
        if peak > FEEDFORWARD_SHARE * limit:
            k = int(np.argmax(np.abs(ff.u_pct)))
            raise ParameterError(
                f"{self.programme.source}: at t = {(k - self.lead) * period_s:.2f} s the programme needs a valve "
                f"command of {peak:.1f} % by the model, over {FEEDFORWARD_SHARE:.0%} of the command "
                f"limit ±{limit:g} %: the valve cannot follow this rate; lower --rate or --frequency")

    def begin(self, y0: float) -> None:
        # the approach moves the rod one way, to the pre-roll's start (module docstring)
        way = 1.0 if y0 <= self.reference[0] else -1.0
        self.plan = self.plans[way]
        self.approach.way = way
        super().begin(y0)

    def begin_main(self, y0: float) -> None:
        self.law.reset()
        self.positions = []
        self.clock = None
        self.unloader = None
        if self.monitor is not None:
            self.monitor.begin_pass()
        if self.pacing.on:
            T = self.programme.period_s
            kinds = self.commanded.kinds()
            turnings = self.lead + self.commanded.turning_idx[[k in ("peak", "valley") for k in kinds]]
            model = self.controller.model
            self.clock = ProgrammeClock(self.reference, turnings, int(round(model.tau / T)), model.g, T,
                                        self.pacing, self.pacing_tolerance_kgf, start=self.lead)
            #: the feedforward that holds a force (the base model's: −Δ/g)
            self.u_hold = -model.delta / model.g if self.controller.feedforward else 0.0

    def finished(self, t: float, y: float) -> bool:
        if self.clock is not None:
            return self.main_start_s is not None and self.clock.finished
        return super().finished(t, y)

    def step(self, t: float, y: float) -> tuple[float, float]:
        u, r = super().step(t, y)
        # during the approach the reference is not recorded: the supervisor's error limit is
        # for tracking the programme, not for the way to its first level
        return (u, r) if self.main_start_s is not None else (u, math.nan)

    def main_step(self, tm: float, y: float) -> tuple[float, float]:
        if self.unloader is not None:
            return self._unload_step(y)
        if self.clock is not None:
            u, r, k = self._paced_step(y)
        else:
            k = min(int(round(tm / self.programme.period_s)), len(self.reference) - 1)
            r = float(self.reference[k])
            plan = self.plan
            u = self.law.step(r, y, self.ff_scale * float(plan.ff.u_pct[k]), float(plan.scale[k]),
                              float(plan.way[k]))
        if self.monitor is not None and self.abort is None:
            self._watch(y, u, k)
        return u, r

    @property
    def ff_scale(self) -> float:
        """The feedforward's factor: 1, or the model's g over the gain monitor's estimate."""
        return self.monitor.ff_scale if self.monitor is not None else 1.0

    def _watch(self, y: float, u: float, k: int) -> None:
        """The gain monitor's cycle (loading.gain_monitor), and its alarm's action."""
        monitor = self.monitor
        factor = self.plan.ff.flow_factor
        before = monitor.alarm
        monitor.add(y, u, float(factor[k]) if factor is not None else 1.0)
        if monitor.alarm is None or before is not None:
            return
        action = monitor.options.action
        if action == "hold":
            self.abort = (GAIN_ALARM, monitor.alarm[1] + "; the valve holds")
        elif action == "unload":
            self.unloader = Unloader(y, self.unload_limits, self.programme.period_s)

    def _unload_step(self, y: float) -> tuple[float, float]:
        """A gain alarm's controlled unload (the supervisor's), then the pass ends in hold."""
        u, r = self.unloader.step(y)
        if self.unloader.done:
            self.abort = (GAIN_ALARM, f"{self.monitor.alarm[1]}; unloaded ({self.unloader.outcome}) to "
                                      f"{y:.0f} kgf in {self.unloader.t:.2f} s, then hold")
        return u, r

    def _paced_step(self, y: float) -> tuple[float, float, int]:
        """One cycle on the programme's clock (loading.pacing): the reference and the
        feedforward at its position, slowed by its speed; while it waits at a turning point the
        feedback drives the predicted force to the level, only toward it."""
        clock = self.clock
        p = clock.advance(y)
        self.positions.append(p)
        r = clock.reference_at(p)
        if clock.waited_too_long():
            gate = clock.gate
            self.abort = (PACING_TIMEOUT,
                          f"the force did not reach the turning point {gate.level_kgf:.0f} kgf within "
                          f"{self.pacing_tolerance_kgf:.0f} kgf in {self.pacing.timeout_s:g} s of waiting "
                          f"(at {y:.0f} kgf): the stand cannot reach it; check the stand, the model "
                          "and the programme's levels")
            return 0.0, r, int(p)
        plan = self.plan
        k = int(p)
        f = p - k
        k1 = min(k + 1, len(self.reference) - 1)
        ff = plan.ff.u_pct
        s = clock.step_taken
        u_ff = self.ff_scale * (s * float(ff[k] + f * (ff[k1] - ff[k])) + (1.0 - s) * self.u_hold)
        if clock.waiting:
            gate = clock.gate
            if clock.wait_began:
                self.law.reset()
            u = self.law.wait_step(gate.level_kgf - clock.predicted_kgf, u_ff, gate.way)
        else:
            u = self.law.step(r, y, u_ff, float(plan.scale[k]), float(plan.way[k]), integrate=s >= 1.0)
        clock.sent(u, u_ff)
        return u, r, k
