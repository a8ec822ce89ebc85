"""Built-in effect: the flow falling as the load pressure rises (FLOW stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from plant.contract import Effect, Stage
from plant.params import Param


class LoadPressure(Effect):
    r"""Load pressure reduces the flow the valve can push against the load (orifice law).

    Physics: flow through a valve orifice goes as the square root of the pressure drop across
    it. Pushing in the direction of the load pressure leaves ``P_s − P_L`` across the valve;
    with the load force proportional to the load pressure, ``F_s = P_s·A`` being the stall force:

    .. math::  G = \sqrt{\max\!\left(1 - \operatorname{sign}(q)\,\frac{y - y_n}{F_s},\ 0\right)}

    ``y_n`` is the force reading at zero load pressure: a dynamometer zero offset or a preload
    of the loading chain (default 0). Seen as ramps that slow down as the force grows in the
    direction of motion and speed up on the way back. At a single command amplitude it is, to
    first order, a leak toward ``y_n`` (``λ = g·|u|/(2F_s)``); several amplitudes separate them.
    """

    name = "load_pressure"
    stage = Stage.FLOW
    summary = "orifice law: gain scales with sqrt(1 - sign(u)·(y - y_n)/F_s)"
    look_alikes = {
        "asymmetry": (
            "runs at both positive and negative force levels: the load-pressure effect swaps "
            "extend/retract with the sign of the force"),
    }
    depends_on_force = True
    params = (Param("stall_force", 30000.0, 2000.0, 1e7, "kgf",
                    "stall force F_s = supply pressure × piston area", log=True),
              Param("offset", 0.0, -1e4, 1e4, "kgf",
                    "force reading y_n at zero load pressure (sensor offset, preload)"))

    def gain(self, q, aux, y):
        return np.sqrt(np.maximum(1.0 - np.sign(q) * (y - self.offset) / self.stall_force, 0.0))

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        ymax = max(s.y_abs_max, 100.0)
        return [{"load_pressure.stall_force": min(1e7, max(2000.0, f * ymax))}
                for f in (1.3, 2.0, 5.0, 20.0, 1000.0)]


