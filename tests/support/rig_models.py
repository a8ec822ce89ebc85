"""Rigs with a known answer for the rig identification's tests: a chain of attachment points,
neighbours coupled 30 %, each channel with its own g, τ, trend and reversal boost."""
from __future__ import annotations

import numpy as np

from plant import PlantModel
from plant.rig import RigModel

#: the structure's stiffness at the attachment points (kgf/mm): neighbours coupled 30 %
K3 = np.array([[10.0, -3.0, 0.0], [-3.0, 10.0, -3.0], [0.0, -3.0, 10.0]])
#: each actuator's flow gain over its piston area, mm/(%·s)
FLOW3 = np.array([12.0, 10.0, 14.0])
#: τ (s), Δ (kgf/s), reversal boost per channel
CHANNELS3 = [(0.040, 8.0, 1.5), (0.050, -5.0, 2.0), (0.060, 3.0, 3.0)]
NAMES3 = ["left", "mid", "right"]


def chain_rig(boost: bool = True) -> RigModel:
    """Three channels in a chain, G = K·diag(c/A) (physical), g = 120, 100, 140."""
    models = [PlantModel.from_spec("base+reversal" if boost else "base",
                                   {"tau": tau, "delta": delta,
                                    **({"reversal.boost": b} if boost else {})})
              for tau, delta, b in CHANNELS3]
    return RigModel(models, K3 * FLOW3[None, :], NAMES3)


def two_channel_rig(a: PlantModel, b: PlantModel) -> RigModel:
    """Two channels coupled 30/36 %: G = [[120, -30], [-36, 100]] (physical)."""
    return RigModel([a, b], np.array([[120.0, -30.0], [-36.0, 100.0]]), ["a", "b"])


def within(est, truth: np.ndarray, widen: float = 1.0) -> np.ndarray:
    """Which entries of an estimate's G lie within their intervals (widened by ``widen``)."""
    mid = est.G
    lo = mid + widen * (est.G_ci[..., 0] - mid)
    hi = mid + widen * (est.G_ci[..., 1] - mid)
    return (lo <= truth) & (truth <= hi)
