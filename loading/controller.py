r"""The designed controller's law, one call per control cycle.

.. math::  u_k = \operatorname{clip}\big(u^{ff}_k + K_p\,e_k + i_k,\ \pm u_{max}\big),\qquad
           e_k = r_k - y_k,\qquad i_k = i_{k-1} + K_p\,\frac{T}{T_i}\,e_k

with ``u^ff`` the feedforward precomputed for the whole programme (:mod:`loading.feedforward`)
and conditional integration as anti-windup: while the command sits at its limit the integral
does not grow further in that direction. Where the model predicts a stand's gain above the one
the design's margins hold at (right after a reversal, see
:func:`loading.feedforward.feedback_scale`), ``K_p`` and the integral's growth are scaled down
by ``s_k ≤ 1``, precomputed with the feedforward. With a ``way`` (±1) the command may move the
rod only that way or hold it (0), the integral not growing against it (the load experiment
keeps the feedforward's sign where the model's gain is above ρ: no reversal it does not plan).
Plain floats: a cycle costs a few operations.

While the programme waits for the force at a turning point (null pacing,
:mod:`loading.pacing`), :meth:`PIFeedforward.wait_step` is a P law on the force predicted past
the delay, ``u = u_hold + K_p·(L − ŷ)``, moving the rod only toward the level; the integral
is cleared when a wait begins (it wound up while the force lagged) and left alone during it,
and while the programme runs slowed for a lagging force it does not grow either.
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

    def step(self, r_kgf: float, y_kgf: float, u_ff_pct: float, scale: float = 1.0,
             way: float = 0.0, integrate: bool = True) -> float:
        """One cycle's command (%); ``integrate=False`` leaves the integral as it is (while the
        programme slows for a lagging force, the lag is the pacing's to take up)."""
        e = r_kgf - y_kgf
        integral = self.integral + scale * self.ki * e if integrate else self.integral
        u = u_ff_pct + scale * self.kp * e + integral
        if way * u < 0:
            if way * e > 0:
                self.integral = integral
            return 0.0
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

    def wait_step(self, error_kgf: float, u_hold_pct: float, way: float) -> float:
        """The command while the programme waits (module docstring): ``error_kgf`` is the level
        minus the predicted force, ``way`` (±1) the only way the rod may move."""
        u = u_hold_pct + self.kp * error_kgf
        if way * u < 0:
            return 0.0
        return max(-self.limit, min(self.limit, u))
