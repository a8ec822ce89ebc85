"""Built-in effect: a leakage across the piston that bleeds the force (FORCE stage)."""
from __future__ import annotations

from typing import Any, Mapping


from plant.contract import Effect, Stage, separating_experiment
from plant.evidence import Ambiguity, Evidence
from plant.params import Param


class Leakage(Effect):
    r"""Leakage across the piston (and the valve's internal leakage).

    Physics: oil leaks from the loaded chamber to the other through the piston seal at a rate
    proportional to the pressure difference, i.e. to the load force, so the force drifts toward
    zero even at a zero command:

    .. math::  \dot y \mathrel{+}= -\lambda\, y .

    Seen as a drift that grows with |y|, toward zero, and a relay/feedback offset that depends on
    the force level.
    """

    name = "leakage"
    stage = Stage.FORCE
    summary = "drift toward zero force proportional to the load (-λ·y)"
    look_alikes = {
        "load_pressure": (
            "meanders at two amplitudes, or a hold at zero command away from zero force: leakage "
            "drifts toward zero at any command, the load-pressure effect scales with |u|"),
        "trend": (
            "runs around two different force levels (e.g. meanders centred at +2000 and −2000 "
            "kgf): leakage drifts toward zero, the trend Δ does not depend on the force"),
    }
    depends_on_force = True
    params = (Param("rate", 0.05, 0.0, 20.0, "1/s", "leak coefficient λ"),)

    def force_rate(self, y):
        return -self.rate * y

    def decay_rate(self):
        return self.rate

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        return [{"leakage.rate": lam} for lam in (0.0, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0)]

    @classmethod
    def ambiguities(cls, ev: Evidence) -> list[Ambiguity]:
        pair = {"leakage", "load_pressure"}
        if not ev.excitation.single_amplitude or not (pair <= ev.tried or ev.best in pair):
            return []
        return [Ambiguity(["leakage", "load_pressure"],
                          "at a single command amplitude the orifice law's slow-down "
                          "(∝ sign(u)·y) acts like a leak toward zero force.",
                          separating_experiment("leakage", "load_pressure"))]


