"""A plug-in effect the catalogue lacks, for the tests (tests/test_rig_unseen_effects.py): a
second load path that engages at a force level (a gap closing, a stop taking load), so the
structure is stiffer above it. The gain depends on the force level, as a smooth step, not the
catalogue's straight line in the force (``stiffness``) or its orifice law (``load_pressure``)."""
import numpy as np

from plant import Effect, Param, Stage


class Contact(Effect):
    r"""Above the force ``y_c`` a second load path carries part of the load: the force answers
    the flow ``1 + a`` times as strongly, the step smoothed over ``w``:

    .. math::  G = 1 + \frac{a}{1 + e^{-(y - y_c)/w}}."""

    name = "contact"
    stage = Stage.FLOW
    summary = "a second load path engages above y_c: gain 1 + a/(1 + exp(-(y - y_c)/w))"
    depends_on_force = True
    params = (Param("stiffening", 0.5, 0.0, 5.0, "1", "relative gain a added above the level"),
              Param("level", 3000.0, -1e5, 1e5, "kgf", "force y_c where the path engages"),
              Param("width", 100.0, 1.0, 1e4, "kgf", "force over which it engages"))

    def gain(self, q, aux, y):
        x = np.clip((np.asarray(y, float) - self.level) / self.width, -60.0, 60.0)
        return 1.0 + self.stiffening / (1.0 + np.exp(-x))
