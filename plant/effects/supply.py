"""Built-in effect: the supply pressure sagging while much flow is drawn (FLOW stage)."""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from plant.contract import Effect, Stage, separating_experiment
from plant.evidence import Ambiguity, Evidence
from plant.params import Param
from plant.signals import first_order_step_average


class Supply(Effect):
    r"""The supply pressure sags while the valve draws much flow, and recovers.

    Physics: the pump (and its accumulator) deliver a limited flow through a supply line with
    its own losses; a large valve opening draws more than that, so the supply pressure ``P_s``
    falls, over the accumulator's time constant, and recovers at small openings. The flow
    through the valve goes as the square root of its pressure drop, so the gain falls with it.
    With ``s`` the relative sag of ``P_s``, ``k`` the sag a full opening would settle at and
    ``T`` its time constant:

    .. math::  T\,\dot s = k\,\frac{|q|}{100\,\%} - s,\qquad G = \sqrt{\max(1 - s,\ 0)}.

    Seen in data as ramps that start at the full slope after a quiet stretch and bend down
    over ``T`` while the command stays large, more at larger amplitudes (a flow curve or limit
    bends the slopes at every instant alike, without a memory). The sag starts settled on the
    command held before.
    """

    name = "supply"
    stage = Stage.FLOW
    summary = "supply pressure sags with the flow drawn (k at full opening, time constant T)"
    look_alikes = {
        "flow_curve": (
            "a large command held for several seconds after a hold at zero: a sagging supply "
            "starts at the full slope and bends it down over its time constant, a flow curve has "
            "the lower slope from the first instant"),
        "saturation": (
            "a large command held for several seconds after a hold at zero: a flow limit caps the "
            "slope at once, a sagging supply lowers it over its time constant"),
    }
    params = (Param("sag", 0.3, 0.0, 5.0, "1", "relative supply-pressure sag k a full opening settles at"),
              Param("time_constant", 1.0, 1e-3, 100.0, "s", "time constant T of the sag", log=True))

    def init_state(self, n, u0):
        return {"x": self.sag * np.abs(np.array(u0, float)) / 100.0}

    def prepare(self, q, dt, state, command=None, t=None):
        sag = first_order_step_average(self.sag * np.abs(q) / 100.0, dt, self.time_constant, state)
        return np.sqrt(np.maximum(1.0 - sag, 0.0))

    def gain(self, q, aux, y):
        return aux

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Sags of 5-40 % at the largest command in the data, settling in 0.1-3 s."""
        top = max(s.u_abs_max, 1e-3) / 100.0
        return [{"supply.sag": min(5.0, f / top), "supply.time_constant": T}
                for f in (0.05, 0.15, 0.4) for T in (0.1, 0.5, 3.0)]

    @classmethod
    def ambiguities(cls, ev: Evidence) -> list[Ambiguity]:
        if ev.best != cls.name:
            return []
        T = ev.best_params.get("supply.time_constant", math.nan)
        return [Ambiguity(
            ["supply", "flow_curve"],
            f"at a held command the supply's sag settles at k·|u| and the gain at "
            f"√(1 − k·|u|/100), a degressive flow characteristic of its own: only the sag's "
            f"build-up over T (fitted {T:.3g} s) after |u| changes tells a sagging supply from a "
            f"bent flow curve (or a dead zone with one).",
            separating_experiment("supply", "flow_curve"))]


