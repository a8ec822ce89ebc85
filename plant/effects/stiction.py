"""Built-in effect: seal friction: the rod sticks after each reversal (SENSOR stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from core.jit import njit
from plant.contract import Effect, Stage, separating_experiment
from plant.evidence import Ambiguity, Evidence
from plant.params import Param
from plant.start_grids import and_less_delay


class Stiction(Effect):
    r"""Seal friction sticks the rod after each reversal: the measured force holds, then moves on.

    Physics: the rod seals' friction ``F_c`` opposes the rod's motion. When the force's trend
    reverses, the rod stops and stays stuck until the hydraulic force has changed by ``2F_c``;
    meanwhile the force on the specimen, which the dynamometer reads, stays where it was. The
    reading is a *play* of width ``w = 2F_c`` on the hydraulic force ``y``:

    .. math::  y_m(t) = \operatorname{clip}\big(y_m(t^-),\ y(t) - w/2,\ y(t) + w/2\big)

    so after each reversal the reading holds for ``w/|ẏ|`` (longer at small commands) and then
    follows. Force-dependent effects (leakage, load pressure) act on the hydraulic force, as the
    oil does. Seen as a dead time after each reversal that shrinks as ``1/|u|``: at one amplitude
    like more delay, at several not; unlike :class:`Backlash` (a play on the command, which a
    square wave jumps at once) it holds after a meander's reversals too. A window of the
    analysis starts from a reading; where the force sits in the play there comes from running
    the play along the measured force.
    """

    name = "stiction"
    stage = Stage.SENSOR
    summary = "rod sticks after each reversal: the reading is a play of width w on the force"
    look_alikes = {
        "delay": (
            "the meander at two or more amplitudes (e.g. 5 and 20 %): a rod stuck after each "
            "reversal holds the force w/(g·|u|), longer at small amplitudes; a delay is the same "
            "at every amplitude"),
        "backlash": (
            "the meander (square waves): a play on the command is jumped at once by a step, a "
            "stuck rod still holds the force after each reversal"),
    }
    linear_in_gain = False
    params = (Param("width", 100.0, 0.0, 5000.0, "kgf",
                    "play w = 2F_c: the change of hydraulic force that moves a stuck rod"),)

    def filter_rate(self, rate, dt, state):
        if "offset" not in state:
            state["offset"] = self._at_rest(rate.shape[0])
        engaged, _ = self._play(rate, dt, state)
        return rate * engaged

    def filter_states(self, rate, dt, steps):
        state = {"offset": self._at_rest(rate.shape[0])}
        _, offsets = self._play(rate, dt, state, track=True)
        return {"offset": offsets[0, steps].copy()}

    def force_minus_reading(self, state):
        return state["offset"]

    @staticmethod
    def _at_rest(n: int) -> np.ndarray:
        """A stand at rest: the rod stuck with the force in the middle of the play (which side
        it last moved is not known), so the first motion either way crosses half of it."""
        return np.zeros(n)

    def _play(self, rate, dt, state, track=False):
        """Engaged fraction of each step (0 while the play is being crossed), advancing
        ``state["offset"]`` (force minus reading, in [−w/2, w/2]); with ``track``, also the
        offset at each step's start. Each step moves the force by ``m = rate·dt`` and the
        offset to ``clip(offset + m, −w/2, w/2)``; the reading moves by the rest."""
        n, K = rate.shape
        engaged = np.empty((n, K))
        offset = np.array(state["offset"], dtype=float)
        offsets = np.empty((n, K)) if track else np.empty((0, 0))
        _play_steps(np.ascontiguousarray(rate, dtype=float), float(dt), self.width / 2, offset,
                    engaged, offsets, track)
        state["offset"] = offset
        return engaged, (offsets if track else None)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Plays of 0-30 % of the force span; a hold after each reversal looks like more delay, so
        each also starts with τ shortened by the hold at the middle command level."""
        g = abs(base.get("g", 100.0)) or 100.0
        ref = max(float(np.median(s.u_abs_levels)), 1e-3)
        out = []
        for f in (0.0, 0.01, 0.03, 0.1, 0.3):
            w = min(5000.0, f * max(s.y_span, 100.0))
            out += and_less_delay({"stiction.width": w}, base, w / (g * ref))
        return out

    @classmethod
    def ambiguities(cls, ev: Evidence) -> list[Ambiguity]:
        ex = ev.excitation
        if not (ex.single_amplitude and cls.name in ev.tried):
            return []
        return [Ambiguity(["stiction", "delay"],
                          f"at a single command amplitude (|u| = {ex.levels[0]:g} %) a rod that "
                          f"sticks after each reversal holds the force the same w/(g·|u|) every "
                          f"time: it looks like more delay (the fitted τ = "
                          f"{ev.base['tau'] * 1e3:.1f} ms may include such a hold).",
                          separating_experiment("stiction", "delay"))]




@njit
def _play_steps(rate, dt, half, offset, engaged, offsets, track):
    """The play along ``rate`` (n, K), row by row from ``offset`` (n,, advanced in place):
    ``engaged`` the share of each step's force change that reaches the reading, ``offsets``
    (when ``track``) the offset at each step's start."""
    n, K = rate.shape
    for i in range(n):
        o = offset[i]
        for k in range(K):
            if track:
                offsets[i, k] = o
            m = rate[i, k] * dt
            new = o + m
            if new > half:
                new = half
            elif new < -half:
                new = -half
            engaged[i, k] = (m - (new - o)) / m if m != 0.0 else 1.0
            o = new
        offset[i] = o
