"""Built-in effect: a specimen stiffer on the way back to zero load (FLOW stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from plant.contract import Effect, Stage
from plant.params import Param


class Unloading(Effect):
    r"""The loaded structure is stiffer on the way back to zero load than on the way up.

    Physics: loading a built-up structure, its joints and fasteners micro-slip and contacts
    settle, and a composite or an elastomer bearing in the loading chain creeps; unloading, the
    joints stay locked and the structure springs back along a stiffer line (the loading and
    unloading branches of its force-displacement loop). With ``g`` proportional to the stiffness
    (``ẏ = K·v``, see :class:`Stiffness`), the flow drives the force away from zero (loading,
    ``sign(q) = sign(y)``) with ``g·(1−h)`` and toward zero (unloading) with ``g·(1+h)``:

    .. math::  G = 1 - h\,\operatorname{sign}(q)\,\operatorname{sign}(y)

    ``h > 0``: stiffer unloading. Unlike :class:`Asymmetry` (extend against retract, whatever
    the force) the fast direction swaps with the sign of the force; unlike
    :class:`LoadPressure` and :class:`Stiffness`, the difference does not grow with the load,
    it switches at zero force.
    """

    name = "unloading"
    stage = Stage.FLOW
    summary = "gain g·(1-h) loading, g·(1+h) unloading (specimen hysteresis)"
    look_alikes = {
        "asymmetry": (
            "runs at both positive and negative force levels: an asymmetry keeps its fast "
            "direction, a specimen stiffer unloading swaps it with the sign of the force"),
        "load_pressure": (
            "runs at two force levels of the same sign (e.g. meanders centred at 2000 and 6000 "
            "kgf): the load-pressure effect grows with the force, the unloading stiffness only "
            "switches at zero force"),
    }
    depends_on_force = True
    params = (Param("ratio", 0.1, -0.8, 0.8, "1",
                    "relative gain difference h between unloading and loading (>0: stiffer unloading)"),)

    def gain(self, q, aux, y):
        return 1.0 - self.ratio * np.sign(q) * np.sign(y)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        return [{"unloading.ratio": h} for h in (-0.3, -0.1, 0.0, 0.1, 0.3)]


# ------------------------------------------------------------------------------------------
# DISTURBANCE stage (not plant physics: never offered as a diagnosis)
# ------------------------------------------------------------------------------------------


