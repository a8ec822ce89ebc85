"""Built-in effect: a dead zone around the valve's null (VALVE stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from plant.contract import Effect, Stage
from plant.params import Param


class DeadZone(Effect):
    r"""Valve overlap (dead zone) around the null position.

    Physics: an overlapped spool covers its ports for small openings, so no flow passes until
    the command exceeds the overlap ``d``:

    .. math::  q' = \operatorname{sign}(q)\,\max(|q| - d,\ 0).

    From one command amplitude it looks exactly like a lower gain (the slope is g·(|u| − d));
    two or more amplitudes (the meander at 5, 10, 15, 20 %) separate them.
    """

    name = "deadzone"
    stage = Stage.VALVE
    summary = "valve overlap: no flow for |u| below d"
    at_one_amplitude = ("gain", "a dead zone d only lowers the slope to g·(|u| − d)")
    look_alikes = {
        "gain": (
            "the meander at several amplitudes (e.g. 5, 10, 15, 20 %): a dead zone lowers the "
            "slope by g·d at every amplitude, a lower gain in proportion to |u|"),
        "backlash": (
            "P-feedback with a harmonic reference (a command that turns smoothly): a play delays "
            "the valve at every turning point of the command, a dead zone only cuts the flow near "
            "zero; square waves (meander, relay) cannot tell them apart"),
        "flow_curve": (
            "the meander at three or more amplitudes (e.g. 5, 10, 15, 20 %): two amplitudes fit "
            "both exactly; a dead zone lowers every slope by g·d, a flow curve bends the slopes "
            "as |u|^p"),
    }
    params = (Param("width", 1.0, 0.0, 30.0, "%", "overlap d (command below which no flow)"),)

    def shape(self, q, dt, state):
        return np.sign(q) * np.maximum(np.abs(q) - self.width, 0.0)

    def invert(self, q, dt):
        """u = q + d·sign(q): the command just beyond the overlap."""
        return np.where(q > 0, q + self.width, np.where(q < 0, q - self.width, 0.0))

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        ref = float(np.median(s.u_abs_levels))
        return [{"deadzone.width": min(29.0, f * ref)} for f in (0.0, 0.05, 0.15, 0.3, 0.5, 0.8)]


