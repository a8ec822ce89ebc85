"""The rig estimate as a result: G with its intervals, each channel's τ and Δ, and the physical
check noted with its figures (never a refusal: an identified G carries its uncertainty).

Physical check of an identified G (:func:`plant.rig.physical_check` with the intervals as
bounds): is there a physical G within the entries' intervals? As all the entries are asked at
once, the intervals are widened to the Bonferroni level ``1 − α/(N(N−1))`` for this question
(with 95 % intervals one of twelve uncoupled entries of a 4-channel rig would otherwise look
coupled about every other time, and the check call G unphysical by chance). Within them a pair
whose two intervals hold zero is uncoupled (both taken as zero); a pair where only one holds
zero is coupled weakly both ways, with the other's sign (taking that one as zero alone made a
structure that couples one way only: a short campaign's G[inner,tip] = 0 ± 0.006 beside
G[tip,inner] = 0.016 was called unphysical so); the signs of each pair, the flow-gain ratios
that make ``G·diag(A/c)`` symmetric (so the products around every loop of channels) and the
stiffness's positive definiteness are all asked within the intervals, and the asymmetry left
beyond them is compared with what they allow the stiffness as a whole.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from plant.rig import PhysicalCheck, RigModel, physical_check


@dataclass
class PhysicalNote:
    """The physical check of an identified G, with what its intervals allow."""

    checked: bool                       #: False: a column is unknown
    physical: bool
    text: str
    asymmetry: float = math.nan
    asymmetry_allowed: float = math.nan
    min_eigenvalue_ratio: float = math.nan
    #: off-diagonal entries taken as zero (their interval holds it), as (row, column) names
    zeroed: list[tuple[str, str]] = field(default_factory=list)
    reason: str = ""
    check: PhysicalCheck | None = field(default=None, repr=False)

    def to_dict(self) -> dict[str, Any]:
        return {"checked": self.checked, "physical": self.physical, "text": self.text,
                "reason": self.reason, "asymmetry": _num(self.asymmetry),
                "asymmetry_allowed": _num(self.asymmetry_allowed),
                "min_eigenvalue_ratio": _num(self.min_eigenvalue_ratio),
                "zeroed": [list(p) for p in self.zeroed],
                "flow_gain_ratios": None if self.check is None else self.check.scales.tolist()}


def physical_note(G: np.ndarray, G_ci: np.ndarray, names: list[str],
                  level: float = 0.95) -> PhysicalNote:
    """See the module docstring (``level``: the intervals' level)."""
    N = len(names)
    if not np.all(np.isfinite(G)):
        missing = [names[j] for j in range(N) if not np.all(np.isfinite(G[:, j]))]
        return PhysicalNote(False, False, f"not checked: column(s) {', '.join(missing)} unknown")
    alpha = 1.0 - level
    widen = stats.norm.ppf(1 - alpha / (2 * max(1, N * (N - 1)))) / stats.norm.ppf(1 - alpha / 2)
    ci = np.asarray(G_ci, float)
    lo = G + widen * (ci[..., 0] - G)
    hi = G + widen * (ci[..., 1] - G)
    check = physical_check(G, lo=lo, hi=hi)
    zeroed = [(names[i], names[j]) for i, j in check.zeroed]
    allowed = check.allowed
    level_all = 100 * (1 - alpha / max(1, N * (N - 1)))
    head = "physical" if check.physical else f"not physical: {check.reason}"
    text = (f"{head} (entries judged within their intervals at the {level_all:.3g} % level: "
            f"asymmetry {100 * check.asymmetry:.2g} % after scaling beyond them, "
            f"{100 * allowed:.2g} % allowed; smallest eigenvalue of the stiffness "
            f"{check.min_eigenvalue_ratio:.3g} of the largest)")
    if zeroed:
        text += (f"; {len(zeroed)} entr{'y' if len(zeroed) == 1 else 'ies'} taken as zero (both "
                 "intervals of the pair hold 0)")
    return PhysicalNote(True, check.physical, text, check.asymmetry, allowed,
                        check.min_eigenvalue_ratio, zeroed, check.reason, check)


def _num(v: float) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None


@dataclass
class RigEstimate:
    """G (kgf/(%·s), row i: channel i's force, column j: channel j's valve), its intervals,
    each channel's delay and trend, and how they were found (:mod:`.estimate`)."""

    names: list[str]
    G: np.ndarray                       #: (N, N); NaN for a column no run moved
    G_ci: np.ndarray                    #: (N, N, 2)
    delta_kgf_s: np.ndarray             #: (N,)
    delta_ci: np.ndarray                #: (N, 2)
    tau_s: np.ndarray                   #: (N,); NaN for a channel that never moved
    tau_ci_s: np.ndarray                #: (N, 2)
    transitional_s: np.ndarray          #: (N,) each channel's reversal-boost window
    transitional_detected: list[bool]
    #: (N,) the reversal boost's extra force per reversal over the steady rate ``G_jj·u_j``, s
    #: (the paper's transitional portion: 0 when none was found)
    boost_extra_s: np.ndarray
    amplitude_pct: np.ndarray           #: (N,) the meander's |u| at the reversals, %
    reversals: list[int]                #: reversals whose turn gave τ, per channel
    design: str                         #: "per-column" | "simultaneous" | "mixed" | "one-run"
    moving: dict[str, list[str]]        #: per run: the channels that moved
    inflation: np.ndarray               #: (N,) each column's variance inflation
    stretches: list[int]                #: steady stretches per row
    residual_kgf: np.ndarray            #: (N,) rms about the fitted lines per row
    physical: PhysicalNote
    notes: list[str]
    sources: list[str]
    level: float = 0.95

    @property
    def n(self) -> int:
        return len(self.names)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (schema ``hydrostand-rig-estimate/1``; NaN as null)."""
        def rows(a: np.ndarray) -> list:
            return [[_num(v) for v in r] if np.ndim(r) else _num(r) for r in a]
        return {
            "schema": "hydrostand-rig-estimate/1",
            "channels": list(self.names),
            "G": rows(self.G),
            "G_ci": [[[_num(lo), _num(hi)] for lo, hi in r] for r in self.G_ci],
            "level": self.level,
            "tau_s": rows(self.tau_s),
            "tau_ci_s": [[_num(lo), _num(hi)] for lo, hi in self.tau_ci_s],
            "delta_kgf_s": rows(self.delta_kgf_s),
            "delta_ci_kgf_s": [[_num(lo), _num(hi)] for lo, hi in self.delta_ci],
            "transitional_s": rows(self.transitional_s),
            "transitional_detected": list(self.transitional_detected),
            "boost_extra_s": rows(self.boost_extra_s),
            "amplitude_pct": rows(self.amplitude_pct),
            "reversals": list(self.reversals),
            "physical": self.physical.to_dict(),
            "design": self.design,
            "moving": self.moving,
            "inflation": rows(self.inflation),
            "stretches": list(self.stretches),
            "residual_kgf": rows(self.residual_kgf),
            "notes": list(self.notes),
            "sources": list(self.sources),
        }


def starting_models(est: RigEstimate) -> RigModel:
    """The rig model an estimate gives, to start the channels' diagnoses from (``stand estimate
    --save``): G, and per channel the paper's base model (``g = G_ii``, τ, Δ), with the
    reversal boost where the estimate found a transitional portion. An exponential boost
    ``b·(10 %/|u|)^p·e^{−s/T_r}`` adds ``b·(10/|u|)^p·T_r`` times the steady rate per reversal
    and 90 % of it within ``ln(10)·T_r``: so ``T_r`` = window/ln 10 and ``b`` from the extra at
    the catalogue's ``p`` (one amplitude cannot tell ``p``; at that amplitude any ``p`` with
    its ``b`` is the same flow). The diagnoses refine all of it."""
    from plant import PlantModel
    from plant.effects.reversal import Reversal
    models = []
    for j in range(est.n):
        values = {"tau": float(est.tau_s[j]) if math.isfinite(est.tau_s[j]) else 0.05,
                  "delta": float(est.delta_kgf_s[j])}
        extra, window = float(est.boost_extra_s[j]), float(est.transitional_s[j])
        if est.transitional_detected[j] and extra > 0 and window > 0:
            p = Reversal.params[2].default
            decay = window / math.log(10.0)
            scale = (Reversal.U_REF / max(float(est.amplitude_pct[j]), 0.5)) ** p
            boost = min(Reversal.params[0].upper, extra / (scale * decay))
            values.update({"reversal.boost": boost, "reversal.decay": decay,
                           "reversal.exponent": p})
            models.append(PlantModel.from_spec("base+reversal", values))
        else:
            models.append(PlantModel.from_spec("base", values))
    return RigModel(models, est.G, est.names)
