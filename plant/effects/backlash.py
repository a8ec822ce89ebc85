"""Built-in effect: a play on the valve command: hysteresis (VALVE stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from plant.contract import Effect, Stage
from plant.params import Param


class Backlash(Effect):
    r"""Play (backlash) between the command and the spool: hysteresis of the valve.

    Physics: the mechanical feedback wire of a two-stage servo-valve, the torque motor's
    magnetic hysteresis and any linkage between an actuator and the spool leave a play of total
    width ``w``: after the command turns back, it must travel ``w`` before the spool moves (a
    servo-valve data sheet states it as "hysteresis", typically under 3 %). The spool position
    is the play operator of the command,

    .. math::  q'_k = \min\!\big(\max(q'_{k-1},\ q_k - w/2),\ q_k + w/2\big).

    Under a square wave ``±u0`` (meander, relay) it is exactly a dead zone of ``w/2``; under a
    continuous command (P-feedback with a harmonic reference) it delays the valve by the time
    the command takes to cross the play and flattens the turning points, which a dead zone does
    not do. The spool starts centred on the command held before the data.
    """

    name = "backlash"
    stage = Stage.VALVE
    summary = "play of total width w between command and spool (hysteresis)"
    at_one_amplitude = ("gain", "a play of width w lowers the slope to g·(|u| − w/2)")
    look_alikes = {
        "gain": (
            "the meander at several amplitudes, or P-feedback with a harmonic reference"),
    }
    params = (Param("width", 1.0, 0.0, 30.0, "%", "total width w of the play"),)

    def init_state(self, n, u0):
        return {"x": np.array(u0, float)}

    def shape(self, q, dt, state):
        h = 0.5 * self.width
        x0 = state["x"]
        if h == 0.0:
            state["x"] = q[:, -1].copy()
            return q
        out = np.empty_like(q)
        for i in range(q.shape[0]):
            row = q[i]
            # the output moves only where the command changes: walk those samples, hold between
            at = np.flatnonzero(np.diff(row)) + 1
            x = float(x0[i])
            first = row[0]
            x = first - h if x < first - h else (first + h if x > first + h else x)
            moved = [x]
            for v in row[at].tolist():
                lo = v - h
                if x < lo:
                    x = lo
                else:
                    hi = v + h
                    if x > hi:
                        x = hi
                moved.append(x)
            seg = np.zeros(row.shape[0], dtype=np.intp)
            seg[at] = 1
            out[i] = np.asarray(moved)[np.cumsum(seg)]
            x0[i] = x
        state["x"] = x0
        return out

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        return [{"backlash.width": w} for w in (1.0, 6.0, 18.0)]


