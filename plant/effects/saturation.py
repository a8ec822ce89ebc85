"""Built-in effect: the valve's flow limit (VALVE stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from plant.contract import Effect, Stage
from plant.evidence import Ambiguity, Evidence
from plant.params import Param


class Saturation(Effect):
    r"""Flow limit: the valve (or pump) cannot deliver more than a maximum flow.

    .. math::  q' = \operatorname{clip}(q,\ -q_{max},\ q_{max})

    Seen as ramps whose slope stops growing with the command beyond ``q_max``; invisible if the
    data never exceed it.
    """

    name = "saturation"
    stage = Stage.VALVE
    summary = "flow limit: |q| capped at q_max"
    at_one_amplitude = ("gain", "a flow limit below it caps the slope")
    look_alikes = {
        "gain": (
            "the meander at several amplitudes, some beyond the suspected flow limit: the slope "
            "stops growing with |u|"),
        "flow_curve": (
            "the meander at amplitudes below and beyond the suspected limit: a flow limit leaves "
            "the small amplitudes' slopes in proportion and flattens only above it, a flow curve "
            "bends them all"),
    }
    params = (Param("limit", 50.0, 0.5, 100.0, "%", "largest effective flow command q_max"),)

    def shape(self, q, dt, state):
        return np.clip(q, -self.limit, self.limit)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        top = s.u_abs_max
        return [{"saturation.limit": min(100.0, max(0.5, f * top))} for f in (0.3, 0.5, 0.7, 0.9, 1.2)]

    @classmethod
    def ambiguities(cls, ev: Evidence) -> list[Ambiguity]:
        out = super().ambiguities(ev)
        top = ev.excitation.top_command_pct
        if cls.name in ev.tried and ev.best is None and top < 100.0:
            out.append(Ambiguity(["saturation"],
                                 f"the command never exceeds {top:.3g} %: a flow limit above that "
                                 f"cannot show in these data.",
                                 "runs at larger command amplitudes"))
        return out


