"""A candidate: the starting model plus one catalogue effect, fitted and judged against the noise.

Which effects are candidates (:func:`diagnosable_effects`: the catalogue's diagnosable effects
not yet in the model), how one is judged against its reference fit of the starting model on the
same windows (:func:`judge`, by the criteria of :mod:`.significance`), and how the candidates
are ranked (:func:`rank_candidates`: BIC on the fit's objective; a law with more parameters that
does not help over a simpler one, by the same criteria, is its equivalent and ranked after it;
ties of equal parameter counts in catalogue order).
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
    free_params: int = 0          #: parameters fitted (the starting model's and the effect's)
    #: candidates with more parameters that leave no less error than this one without helping
    #: over it (:func:`rank_candidates`): its equivalents, ranked after it
    equivalents: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    fit: FitResult | None = field(default=None, repr=False)
    #: the objective's squared error per window on all windows (what ties are judged on)
    window_sse: np.ndarray | None = field(default=None, repr=False)
    #: its fitted values show what only it can do (:meth:`plant.Effect.own_evidence`); if not,
    #: it neither helps nor earns
    own: bool = True
    #: what they show, or why they do not
    evidence: str = ""

    def to_dict(self) -> dict:
        d = {k: v for k, v in asdict(self).items() if k not in ("fit", "window_sse")}
        d["improvement_percent"] = 100.0 * self.improvement
        if self.fit is not None:
            d["intervals"] = {k: e.to_dict() for k, e in self.fit.estimates.items()}
        return d


def diagnosable_effects(model: PlantModel) -> list[str]:
    have = {e.name for e in model.effects}
    return [n for n, c in CATALOGUE.items() if c.diagnosable and n not in have]


def judge(name: str, f: FitResult, w: np.ndarray, rmse: float, base_w: np.ndarray,
          base_rmse: float, floor: float, n: int, refit: str) -> Candidate:
    """Judge one candidate against its reference fit of the starting model (same windows). An
    effect whose fitted values do not show its own evidence (:meth:`plant.Effect.own_evidence`:
    an overdamped resonance is a lag with a spare parameter) neither helps nor earns."""
    c = error_cut(w, base_w, floor, n, len(f.free) - 3)
    own, evidence = CATALOGUE[name].own_evidence(f.model.params())
    warnings = list(f.warnings) + ([] if own else [f"+{name} is not let in: {evidence}"])
    return Candidate(effect=name, spec=f.model.spec, params=f.model.params(), rmse=rmse,
                     objective_rmse=c.objective_rmse, improvement=c.improvement,
                     rmse_reduction=1.0 - rmse / base_rmse if base_rmse > 0 else 0.0,
                     excess_share=c.excess_share, z=c.z, lr=c.lr, earns=c.earns and own,
                     helps=c.helps and own, bic=bic(c.objective_rmse, len(f.free), n),
                     refit_on=refit, free_params=len(f.free), warnings=warnings, fit=f,
                     window_sse=w, own=own, evidence=evidence)


def bic(objective_rmse: float, free_params: int, n: int) -> float:
    """``N·ln(MSE) + k·ln(N)`` on the objective (``n`` samples, ``free_params`` parameters)."""
    return n * math.log(max(objective_rmse, 1e-300) ** 2) + free_params * math.log(n)


def tied(a: Candidate, b: Candidate, floor: float, n: int) -> bool:
    """Neither candidate lowers the error the other leaves by more than its extra parameters
    can: both ways judged by :func:`.significance.error_cut` (the criteria a candidate is
    judged by against the starting model; k = the difference in parameters, at least one) on
    their window errors, ``n`` samples at the objective's noise floor ``floor``."""
    k = max(1, abs(a.free_params - b.free_params))
    return not (error_cut(a.window_sse, b.window_sse, floor, n, k).helps
                or error_cut(b.window_sse, a.window_sse, floor, n, k).helps)


def rank_candidates(cands: Sequence[Candidate], floor: float, n: int) -> list[Candidate]:
    """Rank by the error penalized for the parameters it costs (BIC on the objective), and let
    ties go to the simpler law.

    BIC charges a parameter ``ln N`` against ``N·ln MSE`` over all ``N`` samples: at 0.25 %
    less error a law with a spare parameter gains about ``N/200``, far more than ``ln N`` on
    long records, though the data cannot tell the two apart (an overdamped resonance is a lag
    with a spare parameter). So a candidate with fewer parameters comes before the best-ranked
    one whenever the two are :func:`tied` (the criteria of :mod:`.significance`, ``n`` samples
    at the objective's noise floor ``floor``): the richer one does not help over it. Richer
    candidates tied with a candidate that helps are its :attr:`Candidate.equivalents`. Runs of candidates within
    :data:`BIC_TIE` of the first of the run are the data's tie (a dead zone and a play under
    square waves are the same model): they keep the catalogue's order, which lists the common
    valve effects first."""
    order = list(CATALOGUE)
    ranked = sorted(cands, key=lambda c: c.bic)
    by_bic: list[Candidate] = []
    i = 0
    while i < len(ranked):
        j = i + 1
        while j < len(ranked) and ranked[j].bic - ranked[i].bic < BIC_TIE:
            j += 1
        by_bic += sorted(ranked[i:j], key=lambda c: order.index(c.effect) if c.effect in order
                         else len(order))
        i = j
    out: list[Candidate] = []
    rest = by_bic
    while rest:
        first = rest[0]
        while True:
            simpler = next((c for c in rest if c.free_params < first.free_params
                            and tied(first, c, floor, n)), None)
            if simpler is None:
                break
            first = simpler
        first.equivalents = [c.effect for c in rest if c.free_params > first.free_params
                             and tied(c, first, floor, n)] if first.helps else []
        out.append(first)
        rest = [c for c in rest if c is not first]
    return out
