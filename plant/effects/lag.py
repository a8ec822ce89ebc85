"""Built-in effect: a first-order lag of the spool/actuator (VALVE stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from plant.contract import Effect, Stage, separating_experiment
from plant.evidence import AMBIGUITY_RATIO, Ambiguity, Evidence
from plant.params import Param
from plant.signals import first_order_step_average
from plant.start_grids import and_less_delay


class Lag(Effect):
    r"""First-order lag of the spool/actuator, in series with the transport delay.

    Physics: the spool of a servo-valve (and the oil column) does not follow the command
    instantly; a first-order approximation of the spool position loop gives

    .. math::  T_v\,\dot q = u(t-\tau) - q .

    Discretized exactly for a command held over each step; the flow command used over the step
    is the step average of ``q`` (exact for the integrator that follows). Seen in data as a
    rounded corner after each command step that a pure delay cannot produce; from one excitation
    frequency, lag and delay are hard to tell apart (both are a phase lag).
    """

    name = "lag"
    stage = Stage.VALVE
    summary = "first-order valve/actuator lag T_v (besides the delay)"
    look_alikes = {
        "delay": (
            "a meander (step commands) or P-feedback at several reference frequencies: a lag "
            "rounds the corners and its phase grows less than linearly with frequency; a delay "
            "only shifts"),
        "sensor_lag": (
            "the dynamometer's own filter setting (its configuration or data sheet) or a second "
            "force measurement; in a linear plant nothing on the command side separates them, "
            "behind a valve nonlinearity (dead zone, flow limit, reversal boost) meanders at "
            "amplitudes near it can"),
    }
    params = (Param("time_constant", 0.03, 1e-4, 2.0, "s", "spool/actuator time constant T_v",
                    log=True),)

    def init_state(self, n, u0):
        return {"x": np.array(u0, float)}

    def shape(self, q, dt, state):
        return first_order_step_average(q, dt, self.time_constant, state)

    def invert(self, q, dt):
        """u = q + T_v·dq/dt: the lag's inverse (a lead)."""
        return q + self.time_constant * np.gradient(q, dt)

    @classmethod
    def ambiguities(cls, ev: Evidence) -> list[Ambiguity]:
        ex = ev.excitation
        out = []
        if ex.continuous and not ex.has_steps and cls.name in ev.tried and ev.best != "lag":
            what = ("a smooth single-frequency signal" if ex.single_frequency
                    else "smooth, without steps")
            out.append(Ambiguity(["lag", "delay"],
                                 f"the command is {what}: a valve lag T shifts a slow command "
                                 f"like extra delay, so mainly τ + T is determined (fitted τ = "
                                 f"{ev.base['tau'] * 1e3:.1f} ms may include a lag).",
                                 separating_experiment("lag", "delay")))
        if ev.best in ("lag", "sensor_lag"):
            other = "sensor_lag" if ev.best == "lag" else "lag"
            alt = ev.errors.get(other)
            if alt is None or alt <= AMBIGUITY_RATIO * ev.errors[ev.best]:
                out.append(Ambiguity(
                    [ev.best, other],
                    "a first-order filter in the dynamometer acts on the measured force exactly "
                    "like a valve lag on an integrating plant (the two commute), in open and "
                    "closed loop alike, unless a valve nonlinearity sits between them: these "
                    "data cannot tell where the lag is.", separating_experiment("lag", "sensor_lag")))
        return out

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        out = []
        for T in (1e-4, 2 * s.dt, 0.01, 0.03, 0.1, 0.3):
            T = max(T, 1.1e-4)
            out += and_less_delay({"lag.time_constant": T}, base, T)
        return out


