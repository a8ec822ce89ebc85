"""Relay feedback ``u = u0·sign(r − y)``: the paper's Figs. 19-23, estimator eq. 4."""
from __future__ import annotations

from typing import Any

from .base import check_range
from .phases import PhasedExperiment


class Relay(PhasedExperiment):
    r"""Relay in the feedback loop, constant reference r (paper Fig. 19): a self-oscillation.

    .. math::  u = u_0\,\operatorname{sign}(r - y)

    with optional hysteresis ε: the command goes to −u0 when ``y > r + ε`` and to +u0 when
    ``y < r − ε`` and keeps its sign in between (ε = 0: the ideal relay; the sign is kept when
    y = r exactly). For ``dy/dt = g·u(t−τ)`` the force settles into a triangle of period
    ``P = 4τ`` and peak ``A = g·u0·τ`` about r (see :mod:`analysis.estimators.relay`).

    Before the relay the force is brought to r by a short proportional loop (skipped when it is
    already there); the run stops itself when |y| reaches ``guard_fraction`` of the force limit.

    :param amplitude_pct: relay amplitude u0, %
    :param reference_kgf: constant reference r, kgf
    :param duration_s: length of the relay phase (after the approach), s
    :param hysteresis_kgf: relay hysteresis ε, kgf (0: ideal relay)
    :param settle_gain: gain of the approach loop, %/kgf
    :param settle_limit_pct: command limit of the approach loop, %
    :param settle_tolerance_kgf: r is reached within ± this, kgf
    :param settle_max_s: longest approach, s (0: no approach)
    :param guard_fraction: stop when |y| reaches this fraction of the force limit
    """

    name = "relay"

    def __init__(self, amplitude_pct: float = 10.0, reference_kgf: float = 0.0, duration_s: float = 4.0,
                 hysteresis_kgf: float = 0.0, settle_gain: float = 0.02, settle_limit_pct: float = 20.0,
                 settle_tolerance_kgf: float = 50.0, settle_max_s: float = 10.0,
                 guard_fraction: float = 0.9) -> None:
        self.amplitude_pct = check_range("amplitude_pct", amplitude_pct, 1e-3, 100.0, "%")
        self.reference_kgf = check_range("reference_kgf", reference_kgf, -1e5, 1e5, "kgf")
        self.relay_s = check_range("duration_s", duration_s, 0.01, 36000.0, "s")
        self.hysteresis_kgf = check_range("hysteresis_kgf", hysteresis_kgf, 0.0, 1e4, "kgf")
        self.max_command_pct = max(self.amplitude_pct, settle_limit_pct)
        self._init_phases(reference_kgf, settle_gain, settle_limit_pct, settle_tolerance_kgf,
                          settle_max_s, guard_fraction)
        self._last = self.amplitude_pct

    @property
    def main_duration_s(self) -> float:
        return self.relay_s

    def params(self) -> dict[str, Any]:
        return {"amplitude_pct": self.amplitude_pct, "reference_kgf": self.reference_kgf,
                "duration_s": self.relay_s, "hysteresis_kgf": self.hysteresis_kgf, **self.phase_params()}

    def begin_main(self, y0: float) -> None:
        self._last = self.amplitude_pct if self.reference_kgf >= y0 else -self.amplitude_pct

    def main_step(self, tm: float, y: float) -> tuple[float, float]:
        e = self.reference_kgf - y
        if e > self.hysteresis_kgf:
            self._last = self.amplitude_pct
        elif e < -self.hysteresis_kgf:
            self._last = -self.amplitude_pct
        return self._last, self.reference_kgf
