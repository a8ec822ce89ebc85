"""Built-in effect: the valve's null drifting as it warms (VALVE stage)."""
from __future__ import annotations

from typing import Any, Mapping


from plant.contract import Effect, Stage
from plant.params import Param
from plant.signals import WARMING_TIME_CONSTANT, warming
from plant.start_grids import warming_starts


class NullDrift(Effect):
    r"""The valve's null drifts during a run: the spool's zero-flow position moves as the valve
    warms up.

    Physics: a servo-valve's null (the command at which no oil flows) shifts with the
    temperature of its torque motor and of the oil, and with the supply pressure; from the
    start of a run it moves toward its warm value with the thermal time constant ``T``. The
    constant part of the null offset is the base model's trend Δ; the drift adds to the spool
    a command offset that grows from zero, with ``b`` its initial rate and ``t`` the time
    since the run began (a record's first sample):

    .. math::  q = u(t-\tau) + b\,T\,(1 - e^{-t/T}),

    averaged exactly over each step (for ``T`` much longer than the run, ``b·t``). Seen in
    data as a force trend that changes during every run the same way: the same extra kgf/s
    at every command level, in both directions and at a held zero command (a drifting gain
    scales with |u| and changes sign with the direction).
    """

    name = "null_drift"
    stage = Stage.VALVE
    summary = "valve null drifting during a run (warming): q = u + b·T·(1 − exp(−t/T))"
    look_alikes = {
        "gain_drift": (
            "the meander at two amplitudes (e.g. 5 and 20 %), or holds at zero command early and "
            "late in a run: a drifting null adds the same kgf/s at every command and at zero, a "
            "drifting gain scales with |u|"),
        "trend": (
            "one long run, or holds at zero command at its start and its end: the trend Δ is the "
            "same throughout, a drifting null moves it during the run"),
    }
    reads_time = True
    params = (Param("rate", 0.002, -0.1, 0.1, "%/s",
                    "initial rate b of the null's drift (command % per second)"),
              WARMING_TIME_CONSTANT)

    def shape(self, q, dt, state, t=None):
        return q + self.rate * warming(t, dt, self.time_constant)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """The null moving by 0.05-0.5 % command over a run."""
        return warming_starts(cls.name, (-0.5, -0.1, -0.03, 0.03, 0.1, 0.5), 0.1, s)


