"""Built-in effect: a different gain extending and retracting (FLOW stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from plant.contract import Effect, Stage, separating_experiment
from plant.evidence import Ambiguity, Evidence
from plant.params import Param


class Asymmetry(Effect):
    r"""Different gain when extending and retracting.

    Physics: a single-rod cylinder has different piston areas on its two sides (and valves have
    unequal port gains), so the same command moves the load faster one way:

    .. math::  G = 1 + a\,\operatorname{sign}(q)

    i.e. ``g·(1+a)`` for q > 0 (extend, force rising) and ``g·(1−a)`` for q < 0 (retract).
    """

    name = "asymmetry"
    stage = Stage.FLOW
    summary = "different gain for extend (1+a) and retract (1-a)"
    look_alikes = {
        "trend": (
            "the meander at two amplitudes, or a hold at zero command: the trend Δ is the same at "
            "every |u|, an extend/retract asymmetry grows with |u|"),
    }
    params = (Param("ratio", 0.1, -0.8, 0.8, "1", "relative gain difference a"),)

    def gain(self, q, aux, y):
        return 1.0 + self.ratio * np.sign(q)

    def largest_gain_factor(self) -> float:
        """1 + |a|: the faster direction."""
        return 1.0 + abs(self.ratio)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        return [{"asymmetry.ratio": a} for a in (-0.3, -0.1, 0.0, 0.1, 0.3)]

    @classmethod
    def ambiguities(cls, ev: Evidence) -> list[Ambiguity]:
        ex = ev.excitation
        if not (ex.single_amplitude and cls.name in ev.tried and not ex.has_zero_hold):
            return []
        lv = f"{ex.levels[0]:g} %"
        d = ev.base["delta"]
        ramp = ev.base["g"] * ex.levels[0]
        hint = (f" The fitted trend Δ = {d:.3g} kgf/s is {abs(d) / ramp * 100:.1f} % of the "
                f"ramp rate g·|u|; if the valve's null offset is known to be small, read it as "
                f"an asymmetry a ≈ {d / ramp:+.3f} (retract {'slower' if d > 0 else 'faster'}).") \
            if ramp > 0 else ""
        return [Ambiguity(["asymmetry", "trend"],
                          f"with the command always ±{lv}, a gain that differs between extend "
                          f"and retract adds the same force rate as the trend Δ.{hint}",
                          separating_experiment("asymmetry", "trend"))]


