"""Built-in effect: the gain drifting as the oil warms (FLOW stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from plant.contract import Effect, Stage
from plant.params import Param
from plant.signals import WARMING_TIME_CONSTANT, warming
from plant.start_grids import warming_starts


class GainDrift(Effect):
    r"""The gain drifts during a run: the oil warms up (or the supply settles after start-up).

    Physics: the pump and the valve's throttling turn the hydraulic power into heat, so the oil
    warms from the start of a run toward its running temperature, with the circuit's thermal
    time constant ``T`` (minutes). Its viscosity falls, the spool's and the piston's leakages
    rise and the pump's delivery changes, so the flow per % command (the gain) changes with the
    temperature. With ``r`` the gain's relative rate of change at the start of the run and
    ``t`` the time since the run began (a record's first sample):

    .. math::  G(t) = \max\big(1 + r\,T\,(1 - e^{-t/T}),\ 0\big),

    averaged exactly over each step. For ``T`` much longer than the run it is the linear drift
    ``G = 1 + r·t``; ``g`` is the gain at the start of the run. Seen in data as a slope error
    along the motion that grows with time (the model too slow at the end of every run and right
    at its start, or the other way), the same in every run, at every command level and in both
    directions. In the emulator the clock restarts when the master starts the nodes.
    """

    name = "gain_drift"
    stage = Stage.FLOW
    summary = "gain drifting during a run (oil warming): G = 1 + r·T·(1 − exp(−t/T))"
    look_alikes = {
        "supply": (
            "a long run at one small command amplitude: a warming oil changes the gain whatever "
            "the flow drawn, a sagging supply hardly sags at small openings and recovers in every "
            "pause"),
        "gain": (
            "two runs, one after the other, or one long run: a drifting gain differs between the "
            "starts and the ends of the runs, a wrong gain is wrong everywhere alike"),
    }
    reads_time = True
    params = (Param("rate", 0.002, -0.05, 0.05, "1/s",
                    "relative rate of change r of the gain at the start of a run"),
              WARMING_TIME_CONSTANT)

    def prepare(self, q, dt, state, command=None, t=None):
        return np.maximum(1.0 + self.rate * warming(t, dt, self.time_constant), 0.0)

    def gain(self, q, aux, y):
        return aux

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """The gain rising or falling by 5-50 % over a run."""
        return warming_starts(cls.name, (-0.3, -0.05, 0.05, 0.2, 0.5), 0.05, s)


