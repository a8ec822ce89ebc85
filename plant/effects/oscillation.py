"""Built-in effect: an external periodic disturbance (DISTURBANCE stage, not plant physics)."""
from __future__ import annotations


import numpy as np

from plant.contract import Effect, Stage
from plant.params import Param


class Oscillation(Effect):
    r"""A periodic force disturbance from outside the loading channel (a neighbouring actuator,
    a structural resonance, pump ripple):

    .. math::  y_{dist}(t) = A \sin(2\pi f t),\qquad \dot y \mathrel{+}= 2\pi f A \cos(2\pi f t).

    It is not an effect of the valve/cylinder physics, so ``stand diagnose`` does not offer it;
    its trace in the residual is reported as *unexplained*, with its frequency. Use it in the
    emulator to test that, or add it to a model when the disturbance is known.
    """

    name = "oscillation"
    stage = Stage.DISTURBANCE
    summary = "external periodic force disturbance A·sin(2πft) (not diagnosable)"
    diagnosable = False
    params = (
        Param("amplitude", 50.0, 0.0, 5000.0, "kgf", "disturbance amplitude A"),
        Param("frequency", 3.0, 0.01, 100.0, "Hz", "disturbance frequency f", log=True),
    )

    def disturbance(self, t, dt):
        w = 2 * np.pi * self.frequency  # exact step average of 2πfA·cos(2πft)
        return self.amplitude * (np.sin(w * (t + dt)) - np.sin(w * t)) / dt


