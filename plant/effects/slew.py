"""Built-in effect: a limit on the spool's speed (VALVE stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from plant.contract import Effect, Stage
from plant.params import Param
from plant.start_grids import and_less_delay


class Slew(Effect):
    r"""The spool cannot move faster than a largest speed: large command steps become ramps.

    Physics: the first stage of a two-stage servo-valve drives the spool with a limited flow
    (and a drive amplifier with a limited current or a set ramp), so the spool's speed has a
    ceiling ``R``; a data sheet shows it as a large-signal step response that takes longer than
    the small-signal one (e.g. 0 → 100 % in 25 ms: R = 4000 %/s). The spool position ``x`` is
    the command passed through a rate limit,

    .. math::  \dot x = \operatorname{clip}\big(\ldots,\ -R,\ R\big):\quad
               x \text{ follows } u(t-\tau) \text{ at once, at most at speed } R,

    and the flow over a step is its step average (exact: the ramp ends inside the step where it
    reaches the command). Seen in data as a corner after each large command step that is
    rounded for ``|Δu|/R``, longer for larger steps (a lag rounds every step in the same time
    constant, a delay shifts it): a meander's ramp starts late by ``|Δu|/(2R)``, twice as late at
    twice the amplitude. A command that changes by less than ``R·dt`` a step is reached
    within each step. The spool starts on the command held before.
    """

    name = "slew"
    stage = Stage.VALVE
    summary = "spool speed limit R: a command step of Δu becomes a ramp lasting |Δu|/R"
    look_alikes = {
        "lag": (
            "the meander at several amplitudes (e.g. 5 and 20 %): a speed limit rounds a step for "
            "|Δu|/R, four times as long at four times the step, a lag for the same time constant "
            "at every step"),
        "delay": (
            "the meander at several amplitudes: a speed-limited spool reaches the flow |Δu|/(2R) "
            "late, later for larger steps; a delay is the same at every amplitude"),
    }
    params = (Param("rate", 500.0, 1.0, 1e5, "%/s", "largest spool speed R", log=True),)

    def init_state(self, n, u0):
        return {"x": np.array(u0, float)}

    def shape(self, q, dt, state):
        s = self.rate * dt                     # the largest move in one step
        out = np.empty_like(q)
        x_end = state["x"].astype(float)
        for i in range(q.shape[0]):
            x_end[i] = _slew_row(q[i], float(x_end[i]), s, out[i])
        state["x"] = x_end
        return out

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Spool speeds from a reversal of the middle command level in 5 ms to one in 200 ms; a
        ramped step reaches the flow about |Δu|/(2R) late, which the base fit put into τ."""
        swing = 2 * max(float(np.median(s.u_abs_levels)), 1e-3)     # a reversal ±u
        out = []
        for t_ramp in (0.005, 0.02, 0.06, 0.2):
            R = min(1e5, max(1.0, swing / t_ramp))
            out += and_less_delay({"slew.rate": R}, base, t_ramp / 2)
        return out


def _slew_row(v: np.ndarray, x: float, s: float, out: np.ndarray) -> float:
    """Step averages of the rate-limited spool (moves of at most ``s`` a step) along the held
    commands ``v``, from position ``x``, into ``out``; returns the end position. Where the spool
    sits on the command and no step exceeds ``s`` it tracks (vectorized); a step from off the
    command is walked one by one until the spool is on it again."""
    K = v.shape[0]
    d_all = np.diff(v)
    jumps = np.flatnonzero(np.abs(d_all) > s) + 1     # steps a tracking spool cannot follow
    vals = v.tolist()
    k = 0
    while k < K:
        d = vals[k] - x
        if -s <= d <= s:                      # reaches the command within this step
            out[k] = vals[k] - d * abs(d) / (2 * s)
            k += 1
            j = int(jumps[np.searchsorted(jumps, k)]) if len(jumps) and jumps[-1] >= k else K
            if j > k:                          # tracking until the next jump
                dd = d_all[k - 1:j - 1]
                out[k:j] = v[k:j] - dd * np.abs(dd) / (2 * s)
            x = vals[j - 1]
            k = j
        else:
            step = s if d > 0 else -s
            out[k] = x + step / 2
            x += step
            k += 1
    return x


