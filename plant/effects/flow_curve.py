"""Built-in effect: a power-law flow characteristic (VALVE stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from plant.contract import Effect, Stage
from plant.params import Param


class FlowCurve(Effect):
    r"""A flow characteristic that is not a straight line: flow grows as a power of the opening.

    Physics: the valve's flow versus command is linear only for a critically lapped spool with
    rectangular ports at a constant pressure drop. Port shape (round or notched ports), lap
    (underlap raises the gain near null) and flow forces at large openings bend it; a power law
    through the point ``u_ref = 10 %`` describes the bend with one number:

    .. math::  q' = \operatorname{sign}(q)\,u_{ref}\left(\frac{|q|}{u_{ref}}\right)^{p}.

    ``p < 1``: degressive (slopes grow less than in proportion to |u|), ``p > 1``: progressive.
    ``g`` stays the gain at 10 %. One amplitude cannot show it (it is then a gain change); the
    meander at several amplitudes does: the ramp slopes go as ``|u0|^p``.
    """

    name = "flow_curve"
    stage = Stage.VALVE
    summary = "power-law flow characteristic q = sign(u)·u_ref·(|u|/u_ref)^p"
    at_one_amplitude = ("gain", "a bent flow curve only changes the slope")
    look_alikes = {
        "gain": (
            "the meander at several amplitudes: the ramp slopes grow as |u|^p instead of in "
            "proportion to |u|"),
    }
    U_REF = 10.0
    params = (Param("exponent", 1.0, 0.3, 3.0, "1", "power p of the flow curve (1: linear)"),)

    def shape(self, q, dt, state):
        p = self.exponent
        if p == 1.0:
            return q
        return np.sign(q) * self.U_REF * (np.abs(q) / self.U_REF) ** p

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        return [{"flow_curve.exponent": p} for p in (0.84, 1.0, 1.92)]


