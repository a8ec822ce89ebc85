r"""A rig controller's law, one call per control cycle for every channel at once.

.. math::  u_k = \operatorname{clip}\big(u^{ff}_k + S_k\,M\,K_p\,e_k + i_k,\ \pm u_{max}\big),
           \qquad e_k = r_k - y_k,\qquad i_k = i_{k-1} + S_k\,M\,K_i\,e_k,

with ``K_p = diag(K_{p,i})``, ``K_i = K_p·diag(T/T_{i,i})``, ``M`` the feedback's mixing matrix
(:mod:`loading.rig_design`: ``Ĝ⁻¹·diag(ĝ)`` decoupled, ``I`` independent) and ``S_k`` the
per-valve share of the feedback where the model's gain exceeds its channel's ρ. The integral
lives at the valves, so each valve keeps the one-channel law's rules (:mod:`loading.controller`):
conditional integration as anti-windup (a valve at its limit stops integrating in that
direction), and with a ``way`` (±1) the valve moves only that way or holds (0), its integral not
growing against it. With ``M = I`` and one channel this is :class:`~loading.controller.PIFeedforward`
exactly.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np


class RigPIFeedforward:
    """The rig's PI feedback around a precomputed feedforward (module docstring)."""

    def __init__(self, kp_pct_per_kgf: Sequence[float], ti_s: Sequence[float], period_s: float,
                 command_limit_pct: float, M: np.ndarray | None = None) -> None:
        kp = np.asarray(kp_pct_per_kgf, float)
        ki = np.array([k * period_s / t if math.isfinite(t) and t > 0 else 0.0 for k, t in zip(kp, ti_s)])
        M = np.eye(len(kp)) if M is None else np.asarray(M, float)
        self.Mkp = M * kp[None, :]
        self.Mki = M * ki[None, :]
        self.limit = float(command_limit_pct)
        self.integral = np.zeros(len(kp))

    def reset(self, integral_pct: Sequence[float] | None = None) -> None:
        self.integral = np.zeros(len(self.integral)) if integral_pct is None else np.asarray(integral_pct, float)

    def step(self, r_kgf: np.ndarray, y_kgf: np.ndarray, u_ff_pct: np.ndarray,
             scale: np.ndarray | float = 1.0, way: np.ndarray | float = 0.0,
             integrate: bool = True) -> np.ndarray:
        """One cycle's commands (%), one per channel (module docstring)."""
        e = np.asarray(r_kgf, float) - np.asarray(y_kgf, float)
        p = scale * (self.Mkp @ e)
        di = scale * (self.Mki @ e) if integrate else np.zeros_like(e)
        integral = self.integral + di
        u = np.asarray(u_ff_pct, float) + p + integral
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

    def wait_step(self, error_kgf: np.ndarray, u_hold_pct: np.ndarray, way: np.ndarray) -> np.ndarray:
        """Every command while the programme waits at a load case (:mod:`loading.rig_pacing`):
        ``error_kgf`` each level minus its predicted force, a P law through M around the flows
        that hold the forces, each valve with a ``way`` (±1) moving only that way (0: free);
        the integral is left alone."""
        u = np.asarray(u_hold_pct, float) + self.Mkp @ np.asarray(error_kgf, float)
        way = np.asarray(way, float)
        u = np.where(way * u < 0, 0.0, u)
        return np.clip(u, -self.limit, self.limit)
