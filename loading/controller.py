r"""The designed controller's law, one call per control cycle.

.. math::  u_k = \operatorname{clip}\big(u^{ff}_k + K_p\,e_k + i_k,\ \pm u_{max}\big),\qquad
           e_k = r_k - y_k,\qquad i_k = i_{k-1} + K_p\,\frac{T}{T_i}\,e_k

with ``u^ff`` the feedforward precomputed for the whole programme (:mod:`loading.feedforward`)
and conditional integration as anti-windup: while the command sits at its limit the integral
does not grow further in that direction. Plain floats: a cycle costs a few operations.
"""
from __future__ import annotations

import math


class PIFeedforward:
    """PI feedback around a precomputed feedforward (see the module docstring)."""

    def __init__(self, kp_pct_per_kgf: float, ti_s: float, period_s: float,
                 command_limit_pct: float) -> None:
        self.kp = float(kp_pct_per_kgf)
        self.ki = self.kp * period_s / ti_s if math.isfinite(ti_s) and ti_s > 0 else 0.0
        self.limit = float(command_limit_pct)
        self.integral = 0.0

    def reset(self, integral_pct: float = 0.0) -> None:
        self.integral = integral_pct

    def step(self, r_kgf: float, y_kgf: float, u_ff_pct: float) -> float:
        e = r_kgf - y_kgf
        integral = self.integral + self.ki * e
        u = u_ff_pct + self.kp * e + integral
        if u > self.limit:
            u = self.limit
            if e < 0:
                self.integral = integral
        elif u < -self.limit:
            u = -self.limit
            if e > 0:
                self.integral = integral
        else:
            self.integral = integral
        return u
