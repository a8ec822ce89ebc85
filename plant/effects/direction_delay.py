"""Built-in effect: a longer delay for command steps one way than the other (VALVE stage)."""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from scipy.ndimage import maximum_filter1d, minimum_filter1d

from plant.contract import Effect, Stage
from plant.params import Param
from plant.start_grids import and_less_delay


class DirectionDelay(Effect):
    r"""The valve answers a rising command later than a falling one (or the other way round).

    Physics: the transport delay need not be the same both ways. A two-stage servo-valve whose
    pilot stage drives the spool harder one way (unequal nozzle gaps, a worn jet, a null bias), a
    proportional valve whose solenoids differ, or a drive that ramps one direction slower: a
    command step up reaches the flow ``δ`` after a step down would (``δ < 0``: a step down is
    the late one). With the base delay ``τ`` the shorter of the two, the flow is the smallest
    (``δ > 0``) or largest (``δ < 0``) delayed command of the last ``|δ|``:

    .. math::  q'(t) = \min_{t-\delta \le s \le t} q(s)\quad(\delta > 0),\qquad
               q'(t) = \max_{t-|\delta| \le s \le t} q(s)\quad(\delta < 0),

    so a rise arrives ``τ + δ`` late and a fall ``τ`` late (a fraction of a step is
    interpolated, as for ``τ``). Seen in a meander as ramps that start later after the command
    steps one way than the other, with a trend: the flow stays ``δ`` longer at the low command
    every period, which the base model can only fit with a Δ.
    """

    name = "direction_delay"
    stage = Stage.VALVE
    summary = "a rising command reaches the flow δ later than a falling one (δ < 0: falling later)"
    look_alikes = {
        "trend": (
            "meanders at two periods (e.g. 4 and 12 s): a trend Δ is the same at both, the flow's "
            "extra time at one command each period shrinks with a longer period"),
    }
    params = (Param("extra", 0.02, -0.5, 0.5, "s",
                    "extra delay δ of a command rise over a fall (< 0: a fall is the late one)"),)

    def init_state(self, n, u0):
        return {"hist": np.array(u0, float)[:, None]}

    def shape(self, q, dt, state):
        steps = abs(self.extra) / dt
        m = int(math.floor(steps + 1e-12))
        f = steps - m
        need = m + 1                           # the window of m + 2 samples: m + 1 before
        h = state["hist"]
        if h.shape[1] < need:                  # fill with the oldest (the command held before)
            h = np.concatenate([np.repeat(h[:, :1], need - h.shape[1], axis=1), h], axis=1)
        ext = np.concatenate([h[:, -need:], q], axis=1)
        state["hist"] = ext[:, -need:].copy()
        if m == 0 and f == 0.0:
            return q
        run = minimum_filter1d if self.extra > 0 else maximum_filter1d
        # trailing windows (origin (size − 1) // 2): the last m + 1, and m + 2, samples
        out = run(ext, m + 1, axis=1, origin=m // 2, mode="nearest")[:, need:]
        if f:
            wider = run(ext, m + 2, axis=1, origin=(m + 1) // 2, mode="nearest")[:, need:]
            out = (1.0 - f) * out + f * wider
        return out

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Either direction late by 10-80 ms; the base fit's τ is about the mean of the two
        delays, so each also starts with τ shortened by half the difference."""
        out = []
        for d in (-0.08, -0.03, -0.01, 0.01, 0.03, 0.08):
            out += and_less_delay({"direction_delay.extra": d}, base, abs(d) / 2)
        return out


