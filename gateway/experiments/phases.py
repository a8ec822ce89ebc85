"""The phases every experiment of the paper's program shares (meander, P feedback, relay):

* :class:`SetPointApproach` — before the experiment proper, the force is brought to a set point
  with a short proportional loop, as an operator would do by hand;
* :class:`ForceGuard` — the experiment stops itself safely (``abort``) when |y| approaches the
  supervisor's force limit, before the hard limit trips;
* :class:`PhasedExperiment` — an :class:`~gateway.experiments.base.Experiment` made of the
  optional approach, then the main phase, guarded throughout.
"""
from __future__ import annotations

import math
from typing import Any

from .base import Experiment, check_range

#: reason written into run.json when an experiment stops itself near the force limit
FORCE_NEAR_LIMIT = "force_near_limit"
#: reason written into run.json when the set point could not be reached in time
SET_POINT_NOT_REACHED = "set_point_not_reached"


class Dwell:
    """Whether a condition has held for ``hold_s`` without a break (a force settled within its
    tolerance): called every cycle with the time and the condition."""

    def __init__(self, hold_s: float) -> None:
        self.hold_s = hold_s
        self.since: float | None = None

    def __call__(self, t: float, inside: bool) -> bool:
        if not inside:
            self.since = None
            return False
        if self.since is None:
            self.since = t
        return t - self.since >= self.hold_s - 1e-12


class SetPointApproach:
    r"""A short proportional loop that brings the force to a set point before an experiment.

    .. math::  u = \operatorname{clip}\big(k_s\,(r_s - y),\ -u_{max},\ u_{max}\big)

    with ``r_s`` the set point (kgf), ``k_s`` the gain (%/kgf) and ``u_max`` the command limit (%).
    For the paper's plant ``dy/dt = g·u(t − τ)`` this is a first-order loop of time constant
    ``1/(k_s·g)`` (0.35 s for k_s = 0.02 %/kgf, g = 120 kgf/(%·s)) with a phase margin of
    ``90° − k_s·g·τ`` (83° for τ = 50 ms), so it stays well damped for a gain several times larger
    than expected.

    The approach is done when |r_s − y| <= ``tolerance_kgf`` for ``hold_s``; it is skipped entirely
    when the very first reading is already within the tolerance (no extra cycles). It fails when
    it takes longer than ``max_s``. ``max_s = 0`` switches the approach off.
    """

    def __init__(self, target_kgf: float, gain_pct_per_kgf: float = 0.02, limit_pct: float = 20.0,
                 tolerance_kgf: float = 20.0, hold_s: float = 0.1, max_s: float = 10.0) -> None:
        self.target_kgf = check_range("set point", target_kgf, -1e5, 1e5, "kgf")
        self.gain = check_range("settle_gain", gain_pct_per_kgf, 1e-6, 10.0, "%/kgf")
        self.limit_pct = check_range("settle_limit_pct", limit_pct, 0.01, 100.0, "%")
        self.tolerance_kgf = check_range("settle_tolerance_kgf", tolerance_kgf, 0.0, 1e5, "kgf")
        self.hold_s = check_range("settle_hold_s", hold_s, 0.0, 60.0, "s")
        self.max_s = check_range("settle_max_s", max_s, 0.0, 3600.0, "s")
        self.reset()

    def reset(self) -> None:
        self.done_at: float | None = None       #: time the approach ended (s), None while going
        self.failed = False
        self._settled = Dwell(self.hold_s)

    def params(self) -> dict[str, float]:
        return {"settle_gain": self.gain, "settle_limit_pct": self.limit_pct,
                "settle_tolerance_kgf": self.tolerance_kgf, "settle_hold_s": self.hold_s,
                "settle_max_s": self.max_s}

    def begin(self, y0: float) -> None:
        """Skip the approach when it is off or the force already sits at the set point."""
        self.reset()
        if self.max_s == 0 or abs(self.target_kgf - y0) <= self.tolerance_kgf:
            self.done_at = 0.0

    def step(self, t: float, y: float) -> float | None:
        """The command while approaching (%), or None once the set point is reached (then
        :attr:`done_at` is set) or the time is up (then :attr:`failed` is set)."""
        if self.done_at is not None:
            return None
        error = self.target_kgf - y
        if self._settled(t, abs(error) <= self.tolerance_kgf):
            self.done_at = t
            return None
        if t >= self.max_s:
            self.failed = True
            return None
        return max(-self.limit_pct, min(self.limit_pct, self.gain * error))

    def failure_message(self, y: float) -> str:
        return (f"the force did not reach the set point {self.target_kgf:.0f} ± "
                f"{self.tolerance_kgf:.0f} kgf within {self.max_s:g} s (last reading {y:.0f} kgf); "
                "raise settle_max_s or settle_limit_pct, or check the stand")


class ForceGuard:
    """Stops an experiment before the supervisor's hard limit: |y| >= ``fraction``·limit."""

    def __init__(self, fraction: float = 0.9) -> None:
        self.fraction = check_range("guard_fraction", fraction, 0.05, 1.0)
        self.limit_kgf = math.inf

    def configure(self, force_limit_kgf: float) -> None:
        self.limit_kgf = float(force_limit_kgf)

    @property
    def threshold_kgf(self) -> float:
        return self.fraction * self.limit_kgf

    def check(self, y: float) -> tuple[str, str] | None:
        if math.isfinite(y) and abs(y) >= self.threshold_kgf:
            return (FORCE_NEAR_LIMIT,
                    f"force {y:.0f} kgf reached {self.fraction:.0%} of the force limit "
                    f"±{self.limit_kgf:.0f} kgf; the experiment stopped itself (lower the "
                    "amplitude, the period or the reference)")
        return None


class PhasedExperiment(Experiment):
    """An experiment in two phases: the set-point approach, then the experiment proper.

    Subclasses give :meth:`main_duration_s` and :meth:`main_step` (time ``tm`` counted from the
    start of the main phase); the reference recorded during the approach is the set point.
    :attr:`duration_s` is the main phase's length (the approach, when needed, comes on top and
    lasts at most ``settle_max_s``); the run ends ``main_duration_s`` after the approach ended.
    """

    approach: SetPointApproach
    guard: ForceGuard

    def _init_phases(self, set_point_kgf: float, settle_gain: float, settle_limit_pct: float,
                     settle_tolerance_kgf: float, settle_max_s: float, guard_fraction: float) -> None:
        self.approach = SetPointApproach(set_point_kgf, settle_gain, settle_limit_pct,
                                         settle_tolerance_kgf, max_s=settle_max_s)
        self.guard = ForceGuard(guard_fraction)
        self.main_start_s: float | None = None

    @property
    def main_duration_s(self) -> float:
        raise NotImplementedError

    @property
    def duration_s(self) -> float:
        return self.main_duration_s

    @property
    def max_duration_s(self) -> float:
        """Upper bound of the run's length: approach (at most) plus the main phase."""
        return self.approach.max_s + self.main_duration_s

    def phase_params(self) -> dict[str, Any]:
        return {**self.approach.params(), "guard_fraction": self.guard.fraction}

    def configure(self, period_s: float, force_limit_kgf: float) -> None:
        self.period_s_loop = period_s
        self.guard.configure(force_limit_kgf)

    def begin(self, y0: float) -> None:
        self.approach.begin(y0)
        self.main_start_s = self.approach.done_at
        self.begin_main(y0)

    def begin_main(self, y0: float) -> None:
        """Hook: reset the main phase's state."""

    def finished(self, t: float, y: float) -> bool:
        return self.main_start_s is not None and t - self.main_start_s >= self.main_duration_s - 1e-9

    def step(self, t: float, y: float) -> tuple[float, float]:
        verdict = self.guard.check(y)
        if verdict is not None:
            self.abort = verdict
            return 0.0, math.nan
        if self.main_start_s is None:
            u = self.approach.step(t, y)
            if u is not None:
                return u, self.approach.target_kgf
            if self.approach.failed:
                self.abort = (SET_POINT_NOT_REACHED, self.approach.failure_message(y))
                return 0.0, math.nan
            self.main_start_s = t
        return self.main_step(t - self.main_start_s, y)

    def main_step(self, tm: float, y: float) -> tuple[float, float]:
        raise NotImplementedError
