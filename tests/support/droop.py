"""A plug-in effect the catalogue lacks, for the tests: a valve whose flow droops linearly with
the load it pushes against (a pressure-compensated valve's droop), where the catalogue's
``load_pressure`` is the orifice law's square root."""
import numpy as np

from plant import Effect, Param, Stage


class Droop(Effect):
    r"""The flow falls in proportion to the load pushed against:

    .. math::  G = \max\!\left(1 - \operatorname{sign}(q)\,\frac{y}{F_d},\ 0.05\right)

    ``F_d`` the force at which the valve would pass no flow pushing."""

    name = "droop"
    stage = Stage.FLOW
    summary = "flow droops linearly with the load pushed against: 1 - sign(u)·y/F_d"
    depends_on_force = True
    params = (Param("force", 20000.0, 2000.0, 1e7, "kgf", "force F_d of no flow", log=True),)

    def gain(self, q, aux, y):
        return np.maximum(1.0 - np.sign(q) * y / self.force, 0.05)
