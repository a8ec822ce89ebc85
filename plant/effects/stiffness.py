"""Built-in effect: a specimen whose stiffness changes with the load (FLOW stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from plant.contract import Effect, Stage
from plant.params import Param


class Stiffness(Effect):
    r"""The loaded structure's stiffness changes with the load.

    Physics: the cylinder moves the rod at ``v = Q/A``; the force follows through the stiffness
    of the specimen and the loading chain, ``ẏ = K·v``, so the gain ``g`` is proportional to
    ``K``. An aircraft structure is rarely a linear spring: contacts close and joints take up
    their play as the load grows (stiffening), skins buckle (softening), and a structure can be
    stiffer in compression than in tension. To first order in the force, with ``F_fs = 10⁴ kgf``
    (the dynamometer's full scale):

    .. math::  G = \max\!\left(1 + k_{abs}\,\frac{|y|}{F_{fs}} + k_{sgn}\,\frac{y}{F_{fs}},\ 0\right)

    Seen as ramps that steepen (or flatten) away from zero force in both directions of motion,
    unlike :class:`LoadPressure` and :class:`Leakage`, which slow the motion away from zero and
    speed the way back.
    """

    name = "stiffness"
    stage = Stage.FLOW
    summary = "gain changes with the load: 1 + k_abs·|y|/10⁴ + k_sgn·y/10⁴ (non-linear specimen)"
    depends_on_force = True
    params = (Param("k_abs", 0.0, -1.0, 50.0, "1",
                    "relative gain change at |y| = 10⁴ kgf, both signs of force (>0: stiffening)"),
              Param("k_sgn", 0.0, -20.0, 20.0, "1",
                    "relative gain change per +10⁴ kgf of signed force (tension/compression)"))

    #: the force the coefficients refer to (the dynamometer's full scale), kgf
    FULL_SCALE = 1e4

    def gain(self, q, aux, y):
        x = y / self.FULL_SCALE
        return np.maximum(1.0 + self.k_abs * np.abs(x) + self.k_sgn * x, 0.0)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Gain changes at the data's largest force: −20, 0, +20, +60 % for both signs of force,
        −20, 0, +20 % between tension and compression."""
        r = 1e4 / max(s.y_abs_max, 100.0)
        return [{"stiffness.k_abs": min(50.0, a * r), "stiffness.k_sgn": max(-20.0, min(20.0, b * r))}
                for a in (-0.2, 0.0, 0.2, 0.6) for b in (-0.2, 0.0, 0.2)]


