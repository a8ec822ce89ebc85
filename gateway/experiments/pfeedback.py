"""Proportional feedback with a harmonic reference: the paper's Figs. 13-18, estimator eq. 3."""
from __future__ import annotations

import math
from typing import Any

from .base import check_range
from .phases import PhasedExperiment


class PFeedback(PhasedExperiment):
    r"""Proportional feedback ``u = k·(r − y)`` with ``r = r0 + A_r·sin(ωt)`` (paper Fig. 13).

    For ``dy/dt = g·u(t−τ)`` the loop is stable for ``k·g·τ < π/2`` (the paper's k = 0.005 %/kgf
    with g ≈ 120 kgf/(%·s) gives a loop bandwidth k·g ≈ 0.6 rad/s); after a transient of a few
    ``1/(k·g)`` u and y are harmonics at ω and ``A_y = g·A_u/ω`` (eq. 3, see
    :mod:`analysis.estimators.pfeedback`). The main phase lasts ``transient_s`` plus ``periods`` periods of
    the reference.

    Before the sine the force is brought to r0 by a short proportional loop (skipped when it is
    already there); the command is clamped to ±``command_limit_pct``; the run stops itself when
    |y| reaches ``guard_fraction`` of the force limit.

    :param gain: k, %/kgf
    :param amplitude_kgf: A_r, kgf
    :param omega_rad_s: ω, rad/s
    :param periods: reference periods to record after the transient
    :param transient_s: time allowed for the loop's transient, s
    :param offset_kgf: r0, the force the sine is centred on, kgf
    :param command_limit_pct: clamp of the command, %
    :param settle_gain: gain of the approach loop, %/kgf
    :param settle_limit_pct: command limit of the approach loop, %
    :param settle_tolerance_kgf: r0 is reached within ± this, kgf
    :param settle_max_s: longest approach, s (0: no approach)
    :param guard_fraction: stop when |y| reaches this fraction of the force limit
    """

    name = "pfeedback"

    def __init__(self, gain: float = 0.005, amplitude_kgf: float = 2000.0, omega_rad_s: float = 0.6283,
                 periods: float = 2.0, transient_s: float = 8.0, offset_kgf: float = 0.0,
                 command_limit_pct: float = 50.0, settle_gain: float = 0.02,
                 settle_limit_pct: float = 20.0, settle_tolerance_kgf: float = 20.0,
                 settle_max_s: float = 10.0, guard_fraction: float = 0.9) -> None:
        self.gain = check_range("gain", gain, 1e-6, 10.0, "%/kgf")
        self.amplitude_kgf = check_range("amplitude_kgf", amplitude_kgf, 0.0, 1e5, "kgf")
        self.omega_rad_s = check_range("omega_rad_s", omega_rad_s, 1e-3, 1000.0, "rad/s")
        self.periods = check_range("periods", periods, 0.1, 10000.0)
        self.transient_s = check_range("transient_s", transient_s, 0.0, 3600.0, "s")
        self.offset_kgf = check_range("offset_kgf", offset_kgf, -1e5, 1e5, "kgf")
        self.command_limit_pct = check_range("command_limit_pct", command_limit_pct, 0.01, 100.0, "%")
        self.max_command_pct = max(self.command_limit_pct, settle_limit_pct)
        self._init_phases(offset_kgf, settle_gain, settle_limit_pct, settle_tolerance_kgf,
                          settle_max_s, guard_fraction)

    @property
    def period_of_reference_s(self) -> float:
        return 2 * math.pi / self.omega_rad_s

    @property
    def main_duration_s(self) -> float:
        return self.transient_s + self.periods * self.period_of_reference_s

    def params(self) -> dict[str, Any]:
        return {"gain": self.gain, "amplitude_kgf": self.amplitude_kgf, "omega_rad_s": self.omega_rad_s,
                "periods": self.periods, "transient_s": self.transient_s, "offset_kgf": self.offset_kgf,
                "command_limit_pct": self.command_limit_pct, **self.phase_params()}

    def main_step(self, tm: float, y: float) -> tuple[float, float]:
        r = self.offset_kgf + self.amplitude_kgf * math.sin(self.omega_rad_s * tm)
        u = self.gain * (r - y)
        return max(-self.command_limit_pct, min(self.command_limit_pct, u)), r
