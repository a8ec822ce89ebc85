r"""The designed controller's law, one call per control cycle for every channel of the station.

.. math::  u_k = \operatorname{clip}\big(u^{ff}_k + S_k\,M\,K_p\,e_k + i_k,\ \pm u_{max}\big),
           \qquad e_k = r_k - y_k,\qquad i_k = i_{k-1} + S_k\,M\,K_i\,e_k,

with ``u^ff`` the feedforward precomputed for the whole programme (:mod:`loading.feedforward`),
``K_p = diag(K_{p,i})``, ``K_i = K_p·diag(T/T_{i,i})``, ``M`` the feedback's mixing matrix
(:mod:`loading.design`: ``Ĝ⁻¹·diag(ĝ)`` decoupled, ``I`` independent; 1 for one channel) and
``S_k`` the per-valve share of the feedback where the model predicts a gain above the one the
design's margins hold at (right after a reversal, see
:func:`loading.feedforward.feedback_scale`), precomputed with the feedforward. The integral lives
at the valves, each with conditional integration as anti-windup: while a command sits at its
limit its integral does not grow further in that direction. With a ``way`` (±1) a valve may
move its rod only that way or hold it (0), its integral not growing against it (the load
experiment keeps the feedforward's sign where the model's gain is above ρ: no reversal it does
not plan). For one channel it is the SIMC PI around the feedforward,
``u = clip(u_ff + s·K_p·e + i)``, a few float operations a cycle.

With ``share_integral`` (a rig's feedforward through G⁻¹, which holds every valve's sign) the
integral's output is scaled by the share too, ``u = u_ff + S·(M·K_p·e + i)``: a valve held at 0
keeps the integral it had, and where the plan then reverses it, right after the reversal at the
boosted gain, that integral would be sent at once (an integral of −2.7 % wound up on a
neighbour-driven stretch threw a channel 140 kgf off at a load case its correction had turned
into a small planned reversal).

While the programme waits for the forces at a load case (null pacing, :mod:`loading.pacing`),
:meth:`PIFeedforward.wait_step` is a P law through M on the forces predicted past the delay,
``u = u_hold + M·K_p·(L − ŷ)``, each valve moving only toward its level; the integral is cleared
when a wait begins (it wound up while the force lagged) and left alone during it, and while the
programme runs slowed for a lagging force it does not grow either.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np


class PIFeedforward:
    """PI feedback per channel around a precomputed feedforward (module docstring); gains and
    forces are per channel (a number for one channel)."""

    def __init__(self, kp_pct_per_kgf: Sequence[float] | float, ti_s: Sequence[float] | float, period_s: float,
                 command_limit_pct: float, M: np.ndarray | None = None, share_integral: bool = False) -> None:
        kp = np.atleast_1d(np.asarray(kp_pct_per_kgf, float))
        ti = np.atleast_1d(np.asarray(ti_s, float))
        ki = np.array([k * period_s / t if math.isfinite(t) and t > 0 else 0.0 for k, t in zip(kp, ti)])
        M = np.eye(len(kp)) if M is None else np.asarray(M, float)
        self.Mkp = M * kp[None, :]
        self.Mki = M * ki[None, :]
        self.limit = float(command_limit_pct)
        self.integral = np.zeros(len(kp))
        self.share_integral = share_integral

    def reset(self, integral_pct: Sequence[float] | None = None) -> None:
        self.integral = (np.zeros(len(self.integral)) if integral_pct is None
                         else np.atleast_1d(np.asarray(integral_pct, float)))

    def step(self, r_kgf, y_kgf, u_ff_pct, scale=1.0, way=0.0, integrate: bool = True) -> np.ndarray:
        """One cycle's commands (%), one per channel (module docstring); ``integrate=False``
        leaves the integral as it is (while the programme slows for a lagging force, the lag is
        the pacing's to take up)."""
        e = np.atleast_1d(np.asarray(r_kgf, float) - np.asarray(y_kgf, float))
        share = np.broadcast_to(np.asarray(scale, float), e.shape)[:, None]
        p = (share * self.Mkp) @ e
        di = (share * self.Mki) @ e if integrate else np.zeros_like(e)
        integral = self.integral + di
        u = np.asarray(u_ff_pct, float) + p + (share[:, 0] * integral if self.share_integral else integral)
        way = np.broadcast_to(np.asarray(way, float), u.shape)
        keep = np.ones(len(u), bool)
        against = way * u < 0                       # a held sign: hold the valve instead
        keep[against] = way[against] * di[against] > 0
        u = np.where(against, 0.0, u)
        over, under = u > self.limit, u < -self.limit
        keep[over] = di[over] < 0
        keep[under] = di[under] > 0
        self.integral = np.where(keep, integral, self.integral)
        return np.clip(u, -self.limit, self.limit)

    def wait_step(self, error_kgf, u_hold_pct, way) -> np.ndarray:
        """Every command while the programme waits at a load case (module docstring):
        ``error_kgf`` each level minus its predicted force, a P law through M around the flows
        that hold the forces, each valve with a ``way`` (±1) moving only that way (0: free);
        the integral is left alone."""
        u = np.asarray(u_hold_pct, float) + self.Mkp @ np.atleast_1d(np.asarray(error_kgf, float))
        way = np.asarray(way, float)
        u = np.where(way * u < 0, 0.0, u)
        return np.clip(u, -self.limit, self.limit)
