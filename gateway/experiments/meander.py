"""Open loop, square-wave command ("meander"): the paper's Figs. 3-10, estimator eq. 2."""
from __future__ import annotations

import math
from typing import Any

from .base import Experiment, check_range


class Meander(Experiment):
    """``u(t) = ±u0`` switching every half period, open loop.

    The first segment lasts a quarter period, so the force ramps symmetrically around its
    starting value (up g·u0·P/4, down g·u0·P/2, ...) instead of drifting away by g·u0·P/2.

    :param amplitude_pct: u0, 0 < u0 <= 100 %
    :param period_s: full period P of the square wave, 0.02..600 s
    :param cycles: number of periods, 1..10000
    """

    name = "meander"

    def __init__(self, amplitude_pct: float = 5.0, period_s: float = 4.0, cycles: float = 5) -> None:
        self.amplitude_pct = check_range("amplitude_pct", amplitude_pct, 1e-3, 100.0, "%")
        self.period_s = check_range("period_s", period_s, 0.02, 600.0, "s")
        self.cycles = check_range("cycles", cycles, 1, 10000, integer=True)
        self.max_command_pct = self.amplitude_pct

    @property
    def duration_s(self) -> float:
        return self.cycles * self.period_s

    def params(self) -> dict[str, Any]:
        return {"amplitude_pct": self.amplitude_pct, "period_s": self.period_s, "cycles": self.cycles}

    def step(self, t: float, y: float) -> tuple[float, float]:
        half = self.period_s / 2
        segment = math.floor((t + self.period_s / 4) / half + 1e-9)
        return (self.amplitude_pct if segment % 2 == 0 else -self.amplitude_pct), math.nan
