"""Built-in effects: the gain boost after each reversal, the paper's transitional portion, timed
from the rod (``reversal``), from the command (``command_reversal``) or dying out over the
rod's travel (``travel_reversal``) (FLOW stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from core.jit import njit
from core.kept import Kept
from plant.contract import Effect, Stage
from plant.params import Param
from plant.start_grids import renamed


class Reversal(Effect):
    r"""Gain boost decaying after each reversal of the rod's direction (the paper's
    "transitional portion", Figs. 4, 11, 12).

    Physics: when the rod reverses, the compressed oil volume and the elastic loading chain
    release stored energy and take up play, so for a short time the force changes much faster
    than the steady gain predicts. The direction is the sign of the flow command; ``s`` is the
    time since it last changed sign:

    .. math::  G = 1 + b\,\left(\frac{u_{ref}}{\max(|q|,\ 0.5\,\%)}\right)^{p} e^{-s/T_r},
               \qquad u_{ref} = 10\ \%.

    With ``p = 0`` the boost is a pure gain factor; with ``p = 1`` it is a fixed extra force
    rate ``g·b·u_ref·e^{-s/T_r}`` (a fixed extra force ``g·b·u_ref·T_r`` per reversal), whose
    relative size shrinks as the command amplitude grows, which is what the paper found
    (Fig. 12: the transitional gain falls as u0 rises). ``p`` is identifiable only from data
    with several amplitudes.
    """

    name = "reversal"
    stage = Stage.FLOW
    summary = "gain boost decaying after each change of the rod's direction"
    look_alikes = {
        "lag": (
            "the meander at several amplitudes and periods"),
        "command_reversal": (
            "the meander with a delay comparable to the boost's decay: a boost timed from the "
            "command already pushes the old direction during the delay, one timed from the rod "
            "starts after it"),
        "travel_reversal": (
            "the meander at several amplitudes (e.g. 5 and 20 %): a boost timed from the reversal "
            "lasts T_r at every amplitude, one that dies out over the travel lasts V_r/|u|, four "
            "times shorter at four times the command"),
    }
    U_REF = 10.0
    params = (
        Param("boost", 2.0, 0.0, 50.0, "1", "boost b right at the reversal (at |q| = u_ref)"),
        Param("decay", 0.15, 0.005, 3.0, "s", "decay time T_r of the boost", log=True),
        Param("exponent", 0.7, 0.0, 1.0, "1", "amplitude exponent p (0: gain factor, 1: fixed extra force)"),
    )
    #: the decaying factor e^(−s/T_r) is prepared from the history; b and p only scale it
    prepared_from = ("decay",)

    def init_state(self, n, u0):
        return reversal_state(n, u0)

    def prepare(self, q, dt, state, command=None, t=None):
        return np.exp(-since_reversal(q, dt, state) / self.decay)

    def gain(self, q, aux, y):
        return 1.0 + self.boost * _command_scale(q, self.U_REF, self.exponent) * aux

    def largest_gain_factor(self) -> float:
        """1 + b: right after a reversal, at |q| = u_ref."""
        return 1.0 + self.boost

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        return [{"reversal.boost": b, "reversal.decay": T, "reversal.exponent": p}
                for b in (0.5, 2.0, 8.0) for T in (0.03, 0.1, 0.3) for p in (0.0, 0.7)] + [
            {"reversal.boost": 0.0, "reversal.decay": 0.1, "reversal.exponent": 0.5}]


class CommandReversal(Reversal):
    r"""The reversal boost timed from the valve command's reversal, not the rod's.

    Physics: as :class:`Reversal`, but the stored energy is released when the *spool* reverses
    (the chambers swap pressure at the valve), which leads the rod's reversal by the transport
    delay when the delay sits downstream of the valve (lines, loading chain). ``s`` is the time
    since the undelayed command changed sign; the boost acts on the flow that is still arriving
    from before, then on the new one:

    .. math::  G = 1 + b\,\left(\frac{u_{ref}}{\max(|q|,\ 0.5\,\%)}\right)^{p}
               e^{-s_u/T_r}.

    With a decay much longer than the delay it looks like :class:`Reversal`; the difference is
    the push in the old direction during the delay after each command reversal.
    """

    name = "command_reversal"
    summary = "reversal boost timed from the command's sign change (before the delay)"
    look_alikes = {
        "travel_reversal": (
            "the meander at several amplitudes: a boost timed from the command lasts T_r at every "
            "amplitude and starts during the delay, one that dies out over the travel lasts "
            "V_r/|u| from the rod's reversal"),
    }
    reads_command = True

    def prepare(self, q, dt, state, command=None, t=None):
        return np.exp(-since_reversal(q if command is None else command, dt, state) / self.decay)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Starts like the rod-timed reversal (same parameters)."""
        return renamed(Reversal.start_grid(s, base), "reversal", cls.name)


class TravelReversal(Effect):
    r"""Gain boost after each reversal that dies out over the rod's *travel*, not over time.

    Physics: what changes at a reversal (seal friction turning round, play in the joints taken
    up, a contact settling) is completed over a distance moved: friction in the pre-sliding
    regime (Dahl's law) evolves with displacement. The rod's travel since the reversal is the
    flow passed since then, ``V = ∫|q| dt`` (command-%·s); the boost decays with the force
    travelled, ``Δy ≈ g·V``:

    .. math::  \dot y = g\,q\,\big(1 + b\,e^{-|y - y_r|/F}\big),\qquad
               G = 1 + \frac{b}{(1+b)\,e^{V/V_r} - b},\quad F = g\,V_r,

    the second form being the first solved in closed form along the travel (exact for the base
    model; averaged exactly over each step). Every reversal adds the same extra force,
    ``F·ln(1 + b)``, at any amplitude, and the transition lasts ``V_r/|u|``: four times shorter
    at four times the command. A time-timed boost (:class:`Reversal`) lasts ``T_r`` at any
    amplitude: meanders at several amplitudes separate the two.
    """

    name = "travel_reversal"
    stage = Stage.FLOW
    summary = "reversal boost that dies out over the rod's travel since the reversal, not over time"
    params = (
        Param("boost", 2.0, 0.0, 50.0, "1", "boost b right at the reversal"),
        Param("travel", 1.0, 0.005, 50.0, "%·s",
              "travel V_r (flow passed, command % × s) over which the boost falls by e "
              "(force travelled F = g·V_r)", log=True),
    )

    def init_state(self, n, u0):
        return reversal_state(n, u0)

    def prepare(self, q, dt, state, command=None, t=None):
        move = np.abs(q) * dt
        v0 = since_reversal(q, move, state) / self.travel      # travel at each step's start
        b, a = self.boost, 1.0 + self.boost
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            e0 = np.exp(-v0)
            at_start = b * e0 / (a - b * e0)
            dv = move / self.travel
            # the step average: (V_r / move)·ln((a − b·e^−v1) / (a − b·e^−v0))
            mean = np.log1p(b * e0 * -np.expm1(-dv) / (a - b * e0)) / dv
        return np.where(dv > 1e-9, mean, at_start)

    def gain(self, q, aux, y):
        return 1.0 + aux

    def largest_gain_factor(self) -> float:
        """1 + b: right at the reversal."""
        return 1.0 + self.boost

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Boosts that die out within 0.03-0.3 s at the middle command level (travel = |u|·time)."""
        ref = max(float(np.median(s.u_abs_levels)), 1e-3)
        return [{"travel_reversal.boost": b, "travel_reversal.travel": min(50.0, max(0.005, ref * T))}
                for b in (0.5, 2.0, 8.0) for T in (0.03, 0.1, 0.3)] + [
            {"travel_reversal.boost": 0.0, "travel_reversal.travel": max(0.005, ref * 0.1)}]


#: the boost's scale by flow command and exponent (:func:`_command_scale`)
_SCALES = Kept(16)


def _command_scale(q: np.ndarray, u_ref: float, exponent: float) -> np.ndarray:
    """``(u_ref / max(|q|, 0.5 %))^p``, kept for a read-only ``q`` (a fit's cached drive) and
    ``p``: numpy's power is the boost's whole cost, and most of a fit's Jacobian columns (g, Δ,
    the boost's size and decay, a force law) leave ``q`` and ``p`` as they were."""
    return _SCALES.get((q,), (u_ref, exponent),
                       lambda: (u_ref / np.maximum(np.abs(q), 0.5)) ** exponent)


def reversal_state(n: int, u0: np.ndarray) -> dict[str, np.ndarray]:
    """The state :func:`since_reversal` carries, at rest on the command ``u0`` (n,): the
    direction of the last motion (0: at rest) and no reversal yet."""
    return {"direction": np.sign(u0).astype(float), "since": np.full(n, np.inf)}


def since_reversal(q: np.ndarray, inc: float | np.ndarray, state: dict) -> np.ndarray:
    """How much of ``inc`` (per step: the step's length for a time, its travel for a distance)
    has passed since the sign of ``q`` (n, K) last changed, at each step's start (a zero keeps
    the last direction; inf before the first reversal). ``state`` carries ``direction`` and
    ``since`` across blocks. A recursion along the steps, compiled (:func:`_since_steps`)."""
    n, K = q.shape
    q = np.ascontiguousarray(q, dtype=float)
    direction = np.array(state["direction"], dtype=float)
    since0 = np.array(state["since"], dtype=float)
    out = np.empty((n, K))
    last_inc = np.empty(n)
    if np.ndim(inc) == 0:
        _since_steps(q, np.full((1, 1), float(inc)), True, direction, since0, out, last_inc)
    else:
        _since_steps(q, np.ascontiguousarray(inc, dtype=float), False, direction, since0, out,
                     last_inc)
    state["direction"] = direction
    state["since"] = out[:, -1] + last_inc
    return out


@njit
def _since_steps(q, inc, equal, direction, since0, out, last_inc):
    """Row by row: the held direction (a zero command keeps the last one), a reversal where it
    changes from a direction, and the increments summed since (from ``since0`` before the
    first). ``equal``: every step's increment is ``inc[0, 0]`` (then ``k·inc`` exactly, as a
    time is); else ``inc`` (n, K). ``direction`` is left at each row's last held direction."""
    n, K = q.shape
    for i in range(n):
        d = direction[i]
        last = -1                       # the last reversal's step in this block
        c = 0.0                         # the increments up to and including step k
        c_last = 0.0                    # ... before the last reversal's step
        for k in range(K):
            step = inc[0, 0] if equal else inc[i, k]
            v = q[i, k]
            held = d if v == 0.0 else (1.0 if v > 0.0 else -1.0)
            if v != v:                  # NaN: its sign, as numpy's
                held = v
            if held != d and d != 0.0:
                last = k
                c_last = c if equal else (c + step) - step
            d = held
            if equal:
                before = k * step
                out[i, k] = (k - last) * step if last >= 0 else since0[i] + before
            else:
                c = c + step
                before = c - step
                out[i, k] = before - c_last if last >= 0 else since0[i] + before
        direction[i] = d
        last_inc[i] = inc[0, 0] if equal else inc[i, K - 1]
