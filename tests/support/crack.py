"""crack: an effect plug-in for the tests (plant/ has no step change of the gain).

Loaded as a plug-in (``plant.plugins.load_plugins([this file])``, ``stand emulate --effects``);
not imported by the tests directly."""
import numpy as np

from plant import Effect, Param, Stage


class Crack(Effect):
    r"""A crack opens at ``t_c`` after the run began: the specimen softens at once, so the force
    the valve's flow makes falls by the share ``s`` from then on:

    .. math::  G = 1 - s\\,[t \\ge t_c]

    (averaged over the step in which it opens)."""

    name = "crack"
    stage = Stage.FLOW
    summary = "a crack opens at t_c: the gain falls by s at once"
    reads_time = True
    params = (Param("share", 0.05, 0.0, 0.9, "1", "relative fall s of the gain"),
              Param("time", 10.0, 0.0, 1e5, "s", "time t_c the crack opens, from the run's start"))

    def prepare(self, q, dt, state, command=None, t=None):
        return 1.0 - self.share * np.clip((t + dt - self.time) / dt, 0.0, 1.0)

    def gain(self, q, aux, y):
        return aux
