"""Open loop, square-wave command ("meander"): the paper's Figs. 3-10, estimator eq. 2."""
from __future__ import annotations

import math
from typing import Any

from .base import check_range
from .phases import PhasedExperiment


class Meander(PhasedExperiment):
    """``u(t) = ±u0`` switching every half period, open loop (paper Figs. 3-10).

    Before the square wave the force is brought to ``set_point_kgf`` by a short proportional loop
    (skipped when it is already there; the reference r is recorded as the set point during that
    phase and NaN during the open-loop square wave). ``set_point_kgf = None`` (the default)
    starts the square wave wherever the force is. The first segment of the square wave lasts a
    quarter period, so the force ramps symmetrically around the set point (up g·u0·P/4, down
    g·u0·P/2, ...) instead of drifting away by g·u0·P/2. The run stops itself when |y| reaches
    ``guard_fraction`` of the force limit.

    :param amplitude_pct: u0, 0 < u0 <= 100 %
    :param period_s: full period P of the square wave, 0.02..600 s
    :param cycles: number of periods, 1..10000
    :param set_point_kgf: force to start from, kgf (none: start where the force is)
    :param settle_gain: gain of the approach loop, %/kgf
    :param settle_limit_pct: command limit of the approach loop, %
    :param settle_tolerance_kgf: the set point is reached within ± this, kgf
    :param settle_max_s: longest approach, s (0: no approach)
    :param guard_fraction: stop when |y| reaches this fraction of the force limit
    """

    name = "meander"

    def __init__(self, amplitude_pct: float = 5.0, period_s: float = 4.0, cycles: float = 5,
                 set_point_kgf: float | None = None, settle_gain: float = 0.02, settle_limit_pct: float = 20.0,
                 settle_tolerance_kgf: float = 20.0, settle_max_s: float = 10.0,
                 guard_fraction: float = 0.9) -> None:
        self.amplitude_pct = check_range("amplitude_pct", amplitude_pct, 1e-3, 100.0, "%")
        self.period_s = check_range("period_s", period_s, 0.02, 600.0, "s")
        self.cycles = check_range("cycles", cycles, 1, 10000, integer=True)
        self.max_command_pct = max(self.amplitude_pct, settle_limit_pct)
        check_range("settle_max_s", settle_max_s, 0.0, 3600.0, "s")
        self.set_point_kgf = None if set_point_kgf is None else float(set_point_kgf)
        self._init_phases(0.0 if set_point_kgf is None else set_point_kgf, settle_gain, settle_limit_pct,
                          settle_tolerance_kgf, 0.0 if set_point_kgf is None else settle_max_s,
                          guard_fraction)

    @property
    def main_duration_s(self) -> float:
        return self.cycles * self.period_s

    def params(self) -> dict[str, Any]:
        return {"amplitude_pct": self.amplitude_pct, "period_s": self.period_s, "cycles": self.cycles,
                "set_point_kgf": self.set_point_kgf, **self.phase_params()}

    def main_step(self, tm: float, y: float) -> tuple[float, float]:
        half = self.period_s / 2
        segment = math.floor((tm + self.period_s / 4) / half + 1e-9)
        return (self.amplitude_pct if segment % 2 == 0 else -self.amplitude_pct), math.nan
