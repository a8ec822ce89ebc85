"""Signal helpers the effects share: first-order lags held over each step, and the warm-up
of a run (the time law of the effects that drift from a run's start).

Every helper works on blocks of shape ``(n, K)`` (``n`` trajectories by ``K`` steps of ``dt``),
with the command held over each step, as the plant model does.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from .params import Param


def warming(t: np.ndarray, dt: float, T: float) -> np.ndarray:
    r"""The step average of :math:`W(t) = T\,(1 - e^{-t/T})` over ``[t, t + dt]``: how far a
    first-order warm-up with time constant ``T`` has gone, in units of its initial rate (``t``
    for ``T`` much longer than ``t``)."""
    mean_decay = np.exp(-t / T) * (-math.expm1(-dt / T) * T / dt)
    return T * (1.0 - mean_decay)


#: the thermal time constant of the effects that drift from the start of a run
WARMING_TIME_CONSTANT = Param("time_constant", 600.0, 1.0, 1e5, "s",
                              "thermal time constant T (much longer than a run: a linear drift)",
                              log=True)


def first_order_step_average(v: np.ndarray, dt: float, T: float, state: dict) -> np.ndarray:
    """A first-order lag ``T·ẋ = v − x`` driven by ``v`` (n, K) held over each step: the step
    average of ``x`` (exact for an integrator that follows). ``state["x"]`` (n,) is ``x`` at the
    block's start, and is advanced to its end; without it ``x`` starts settled on ``v[:, 0]``."""
    x0 = state.get("x")
    x_start, x_end = first_order_states(v, dt, T, v[:, 0].copy() if x0 is None else x0)
    state["x"] = x_end
    c = T / dt * (1.0 - math.exp(-dt / T))  # step-average weight of the initial deviation
    return v + (x_start - v) * c


def first_order_states(v: np.ndarray, dt: float, T: float,
                       x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The state of ``T·ẋ = v − x`` at the start of each step (n, K), from ``x0`` (n,), with
    ``v`` held over each step; and the state at the end of the last step (n,)."""
    a = math.exp(-dt / T)
    # x_{k+1} = a x_k + (1-a) v_k  (x_k is the state at the step start)
    x_next, _ = lfilter([1.0 - a], [1.0, -a], v, axis=1, zi=(a * x0)[:, None])
    return np.concatenate([x0[:, None], x_next[:, :-1]], axis=1), x_next[:, -1].copy()
