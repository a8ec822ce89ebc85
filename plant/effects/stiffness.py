"""Built-in effect: a specimen whose stiffness changes with the load (FLOW stage)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from core.jit import njit
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
        y = np.asarray(y, float)
        flat = _stiffness_gain(np.ascontiguousarray(y).reshape(-1), self.FULL_SCALE, self.k_abs,
                               self.k_sgn)
        return flat.reshape(y.shape)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Gain changes at the data's largest force: −20, 0, +20, +60 % for both signs of force,
        −20, 0, +20 % between tension and compression."""
        r = 1e4 / max(s.y_abs_max, 100.0)
        return [{"stiffness.k_abs": min(50.0, a * r), "stiffness.k_sgn": max(-20.0, min(20.0, b * r))}
                for a in (-0.2, 0.0, 0.2, 0.6) for b in (-0.2, 0.0, 0.2)]


@njit
def _stiffness_gain(y, full_scale, k_abs, k_sgn):
    """``max(1 + k_abs·|x| + k_sgn·x, 0)``, ``x = y / full_scale``, in one pass, bit for bit
    what numpy gives (NaN stays NaN): the fit calls it on every Newton pass of every simulation
    (120,000 calls in a stepwise diagnosis), where numpy's four temporaries took 14× as long."""
    out = np.empty_like(y)
    for i in range(y.size):
        x = y[i] / full_scale
        v = 1.0 + k_abs * abs(x) + k_sgn * x
        out[i] = 0.0 if v < 0.0 else v
    return out
