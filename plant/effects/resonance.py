"""Built-in effect: a second-order valve/actuator that rings at f_n (VALVE stage)."""
from __future__ import annotations

import functools
import math
from typing import Any, Mapping

import numpy as np
from scipy.linalg import expm
from scipy.signal import lfilter, ss2tf

from plant.contract import Effect, Stage
from plant.params import Param
from plant.start_grids import and_less_delay


@functools.lru_cache(maxsize=256)
def second_order_step_average_filter(frequency: float, damping: float,
                                     dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(b, a)`` of the discrete filter from a command held over each step to the step
    average of ``x`` in ``ẍ + 2ζω ẋ + ω² x = ω² v`` (ω = 2π·frequency): the exact zero-order
    hold discretization, with the running integral of ``x`` as a third state (Van Loan).
    Cached: it costs ~0.7 ms (expm, ss2tf), and the emulator asks for it every control period
    with the same values; callers must not modify the arrays."""
    w = 2 * math.pi * frequency
    m = np.zeros((4, 4))
    m[0, 1] = 1.0
    m[1, 0], m[1, 1], m[1, 3] = -w * w, -2 * damping * w, w * w
    m[2, 0] = 1.0                            # the integral of x
    e = expm(m * dt)
    phi, gam = e[:2, :2], e[:2, 3]
    c, d = e[2, :2] / dt, e[2, 3] / dt       # step average = (∫ over the step) / dt
    b, a = ss2tf(phi, gam[:, None], c[None, :], np.array([[d]]))
    return np.ravel(b), np.ravel(a)

class Resonance(Effect):
    r"""A second-order valve/actuator: the flow rings after a command step.

    Physics: the oil column in the cylinder is a spring (bulk modulus over the chamber volume)
    that carries the piston, rod and fixture; with the servo-valve's own spool dynamics it makes
    the hydraulic natural frequency ``f_n`` (a few Hz to some tens of Hz on a loading stand),
    lightly damped by leakage and friction. A servo-valve data sheet gives its response the
    same way (the frequency at 90° phase, and a damping). The flow command follows the delayed
    command through

    .. math::  \ddot q + 2\zeta\omega_n \dot q + \omega_n^2 q = \omega_n^2\,u(t-\tau),
               \qquad \omega_n = 2\pi f_n,

    discretized exactly for a command held over each step (the flow used over a step is its
    step average). Seen in data as a force rate that overshoots after each command step and
    rings at about ``f_n·√(1−ζ²)`` (a relay loop oscillates faster and with bumps, a harmonic
    reference shows a resonant peak); a lag cannot overshoot. Well damped (ζ ≳ 1) it is a lag
    of ``2ζ/ω_n``, and far above the excitation only a delay of ``2ζ/ω_n``. The valve starts
    settled on the command held before.
    """

    name = "resonance"
    stage = Stage.VALVE
    summary = "second-order valve/actuator: natural frequency f_n, damping ζ (the flow rings)"
    look_alikes = {
        "lag": (
            "a meander (command steps) at a small amplitude, or P-feedback at reference "
            "frequencies up to the suspected f_n: a lag never overshoots, a resonance rings after "
            "each step and peaks near f_n"),
        "delay": (
            "P-feedback at several reference frequencies, up to a third of the sample rate: far "
            "below f_n a resonance only adds the delay 2ζ/ω_n, near it the phase and gain change "
            "fast"),
        "sensor_lag": (
            "a meander (command steps) at a small amplitude: a filter in the dynamometer never "
            "overshoots, a resonance rings after each step"),
    }
    #: below this damping the response peaks (by 1/(2ζ√(1−ζ²))) and a step overshoots by
    #: e^(−πζ/√(1−ζ²)) ≥ 4.3 %: what no lag does; above it the law is a lag's with a spare parameter
    RINGS_BELOW = 1 / math.sqrt(2)
    params = (Param("frequency", 10.0, 0.3, 200.0, "Hz", "natural frequency f_n", log=True),
              Param("damping", 0.5, 0.05, 5.0, "1",
                    "damping ratio ζ (a hydraulic actuator 0.05-0.3, a servo-valve 0.5-1)", log=True))

    @classmethod
    def own_evidence(cls, values: Mapping[str, float]) -> tuple[bool, str]:
        """Only an underdamped resonance (ζ < 1/√2) shows what a lag cannot: a peak and
        ringing. Well damped it is two lags in series (ζ ≥ 1) or a lag with a spare parameter,
        not a resonance in the data."""
        f, z = values[f"{cls.name}.frequency"], values[f"{cls.name}.damping"]
        if z >= cls.RINGS_BELOW:
            return False, (f"overdamped (ζ {z:.2g} at {f:.3g} Hz): no peak and no ringing, a lag of "
                           f"2ζ/ω = {1e3 * 2 * z / (2 * math.pi * f):.3g} ms with a spare parameter")
        peak = 1 / (2 * z * math.sqrt(1 - z * z))
        overshoot = math.exp(-math.pi * z / math.sqrt(1 - z * z))
        return True, (f"it rings (ζ {z:.2g} at {f:.3g} Hz: a peak of {peak:.2g}× and "
                      f"{100 * overshoot:.0f} % overshoot after a step), which a lag cannot make")

    def init_state(self, n, u0):
        past = np.repeat(np.array(u0, float)[:, None], 2, axis=1)
        return {"v": past, "q": past.copy()}       # the last two inputs and outputs, oldest first

    def shape(self, q, dt, state):
        b, a = second_order_step_average_filter(self.frequency, self.damping, dt)
        v1, v2 = state["v"][:, 1], state["v"][:, 0]   # x[-1], x[-2]
        y1, y2 = state["q"][:, 1], state["q"][:, 0]
        zi = np.stack([b[1] * v1 + b[2] * v2 - a[1] * y1 - a[2] * y2,
                       b[2] * v1 - a[2] * y1], axis=1)       # scipy.signal.lfiltic, per row
        out, _ = lfilter(b, a, q, axis=1, zi=zi)
        state["v"] = np.concatenate([state["v"], q], axis=1)[:, -2:].copy()
        state["q"] = np.concatenate([state["q"], out], axis=1)[:, -2:].copy()
        return out

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Natural frequencies of 2-30 Hz (below Nyquist), lightly to well damped; the step
        response's mean lag 2ζ/ω has gone into the base fit's τ, so each also starts without it."""
        out = []
        nyquist = 0.5 / s.dt
        for f in (2.0, 6.0, 15.0, 30.0):
            for zeta in (0.15, 0.4, 1.0):
                if f < nyquist:
                    out += and_less_delay({"resonance.frequency": f, "resonance.damping": zeta},
                                           base, 2 * zeta / (2 * math.pi * f))
        return out


