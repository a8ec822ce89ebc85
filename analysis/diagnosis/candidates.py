"""A candidate: the starting model plus one catalogue effect, fitted and judged against the noise.

Which effects are candidates (:func:`diagnosable_effects`: the catalogue's diagnosable effects
not yet in the model), how one is judged against its reference fit of the starting model on the
same windows (:func:`judge`, by the criteria of :mod:`.significance`), and how the candidates
are ranked (:func:`rank_candidates`: BIC on the fit's objective, ties in catalogue order).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Sequence

import numpy as np

from plant import CATALOGUE, PlantModel

from ..identification.fit import FitResult
from .significance import error_cut

#: BIC differences below this are a tie (Kass & Raftery: under 2 is "not worth more than a bare
#: mention"); tied candidates are ranked in catalogue order
BIC_TIE = 2.0


@dataclass
class Candidate:
    """``model + effect`` fitted and judged."""

    effect: str
    spec: str
    params: dict[str, float]
    rmse: float                   #: windowed RMSE from the measured start (as reported), kgf
    objective_rmse: float         #: windowed RMSE, window starts re-estimated (decisions), kgf
    improvement: float            #: 1 − objective_rmse/base objective_rmse (fraction)
    rmse_reduction: float         #: 1 − rmse/base rmse (fraction, the reported metric)
    excess_share: float           #: share of the base's error above the noise floor removed
    z: float                      #: paired z over windows of the squared-error reduction
    lr: float                     #: likelihood-ratio statistic N·ΔMSE/floor² (χ²(k) under "noise only")
    bic: float                    #: N·ln(MSE) + k·ln(N) on the objective (ranking)
    earns: bool                   #: earns its extra parameters (see module docstring)
    helps: bool                   #: lowers the error significantly and consistently, maybe only
                                  #: part of it (``earns`` without the excess-share criterion)
    refit_on: str                 #: "final" (refitted on all windows, tight tolerance, intervals)
                                  #: or "screening" (screening fit only)
    warnings: list[str] = field(default_factory=list)
    fit: FitResult | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        d = {k: v for k, v in asdict(self).items() if k != "fit"}
        d["improvement_percent"] = 100.0 * self.improvement
        if self.fit is not None:
            d["intervals"] = {k: e.to_dict() for k, e in self.fit.estimates.items()}
        return d


def diagnosable_effects(model: PlantModel) -> list[str]:
    have = {e.name for e in model.effects}
    return [n for n, c in CATALOGUE.items() if c.diagnosable and n not in have]


def judge(name: str, f: FitResult, w: np.ndarray, rmse: float, base_w: np.ndarray,
          base_rmse: float, floor: float, n: int, refit: str) -> Candidate:
    """Judge one candidate against its reference fit of the starting model (same windows)."""
    c = error_cut(w, base_w, floor, n, len(f.free) - 3)
    return Candidate(effect=name, spec=f.model.spec, params=f.model.params(), rmse=rmse,
                     objective_rmse=c.objective_rmse, improvement=c.improvement,
                     rmse_reduction=1.0 - rmse / base_rmse if base_rmse > 0 else 0.0,
                     excess_share=c.excess_share, z=c.z, lr=c.lr, earns=c.earns, helps=c.helps,
                     bic=n * math.log(max(c.objective_rmse, 1e-300) ** 2) + len(f.free) * math.log(n),
                     refit_on=refit, warnings=list(f.warnings), fit=f)


def rank_candidates(cands: Sequence[Candidate]) -> list[Candidate]:
    """Rank by the error penalized for the parameters it costs (BIC on the objective): among
    candidates that remove the same error within the noise, the simpler one comes first. Runs
    of candidates within :data:`BIC_TIE` of the first of the run are the data's tie (a dead zone
    and a play under square waves are the same model): they keep the catalogue's order, which
    lists the common valve effects first."""
    order = list(CATALOGUE)
    ranked = sorted(cands, key=lambda c: c.bic)
    out: list[Candidate] = []
    i = 0
    while i < len(ranked):
        j = i + 1
        while j < len(ranked) and ranked[j].bic - ranked[i].bic < BIC_TIE:
            j += 1
        out += sorted(ranked[i:j], key=lambda c: order.index(c.effect) if c.effect in order
                      else len(order))
        i = j
    return out
