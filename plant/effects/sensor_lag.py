"""Built-in effect: the dynamometer's filter: the reading lags the force (SENSOR stage)."""
from __future__ import annotations

from typing import Any, Mapping


from plant.contract import Effect, Stage
from plant.params import Param
from plant.signals import first_order_states, first_order_step_average
from plant.start_grids import renamed
from plant.effects.lag import Lag


class SensorLag(Effect):
    r"""A first-order filter in the dynamometer: its reading lags the force.

    Physics: a strain-gauge amplifier's anti-aliasing or noise filter (CiA 404 devices have a
    configurable digital filter) reports

    .. math::  T_s\,\dot y_m = y - y_m ,

    computed here on the rate (``ẏ_m`` is ``ẏ`` through the same filter), so the force itself,
    which force-dependent effects see, is unfiltered. For a linear plant it acts like a valve
    :class:`Lag` (the two commute on an integrator); behind a valve nonlinearity (dead zone, flow
    limit, reversal boost) it does not: the filter smooths what the nonlinearity made. A window
    of the analysis starts from a reading: the filter's state there is taken from the rate along
    the measured force, and the force under the reading is ``y_m + T_s·ẏ_m``.
    """

    name = "sensor_lag"
    stage = Stage.SENSOR
    summary = "dynamometer filter: the reading lags the force by T_s (first order)"
    params = (Param("time_constant", 0.01, 1e-4, 1.0, "s", "filter time constant T_s", log=True),)

    def filter_rate(self, rate, dt, state):
        return first_order_step_average(rate, dt, self.time_constant, state)

    def filter_states(self, rate, dt, steps):
        x_start, _ = first_order_states(rate, dt, self.time_constant, rate[:, 0].copy())
        return {"x": x_start[0, steps]}

    def force_minus_reading(self, state):
        return self.time_constant * state["x"]      # y − y_m = T_s·ẏ_m

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Starts like a valve lag (same parameters)."""
        return renamed(Lag.start_grid(s, base), "lag", cls.name)


