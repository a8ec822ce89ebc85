r"""Does the stand differ from one record to the next? A gain or a trend of its own per record.

The plant model has one gain g and one trend Δ for all the data. A stand whose oil keeps
warming over a campaign, whose supply pressure is set anew for every run, or whose drive is
re-zeroed between runs has a gain (or a null offset) that changes *between* records while each
record, on its own, follows the model. No catalogue effect describes that: the effects act
within a run. The fit then bends to the average and leaves an error in every record, in
opposite directions in different records, which the candidates cannot remove (or only partly,
by accident of the records' command levels).

The check: with the other parameters of the fitted model held, g and Δ enter the windowed
objective (affinely, exactly for every effect that does not make the rate depend on the force,
to first order otherwise; :func:`analysis.identification.projection.gain_trend_columns`), so a g
or a Δ of its own for every record is one small linear least-squares problem, solved from each
record's 2×2 Gram matrix:

.. math::  \min_{\delta}\ \sum_i \lVert s_i + A_i\,\delta_i \rVert^2, \qquad
           \delta_i = (\delta g_i, \delta\Delta_i),

with ``δg_i`` (or ``δΔ_i``) either shared by all records or free per record. Of the three
per-record designs (gain, trend, both) the one with the lowest BIC is judged against the
shared fit the same way a catalogue candidate is (:mod:`.significance`: a big enough,
significant, consistent cut of the error above the noise).

What the records' values follow decides what it means: their order (Spearman ρ with the
record index: a drift across the campaign) or no order (set anew in every run) is the runs' own
variation; their command level means a gain that depends on the command (a dead zone, a flow
curve, a limit, or several such effects at once), not on the run; both at once (records at
rising levels, run in that order), or too few records at different levels, cannot be told
apart, and the separating experiment is named (the first run again at the end).

The model's other parameters were fitted with one g for all records, so a change between the
runs may have bent them too (a valve play's width soaks up part of a gain that grows run after
run). When the per-record values with those parameters held leave more than
:data:`~.significance.UNEXPLAINED_RATIO` of the noise floor but help, the chosen design
is fitted once more with the other parameters free as well, g and Δ projected per record at
every trial of them (variable projection, :func:`refit_per_record`); the better of the two
is judged. The parameter count is the same: the other parameters were free in the shared fit
too.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
from scipy import optimize, stats

from plant import PlantModel

from ..identification.fit import DIFF_STEP, Parameterization
from ..identification.projection import gain_trend_columns
from ..identification.windows import Piece, fresh_solutions, window_sse
from ..records.record import Record
from .significance import UNEXPLAINED_RATIO, ErrorCut, error_cut

#: |Spearman ρ| from which the records' gains (or trends) are said to follow their order or
#: their command level
FOLLOWS_RHO = 0.8
#: a ρ needs at least this many records to mean anything
MIN_RECORDS_FOR_RHO = 4
#: the designs: which of (g, Δ) are free per record
DESIGNS = {"gain": (True, False), "trend": (False, True), "gain and trend": (True, True)}


@dataclass
class RecordShift:
    """One record's own gain and trend."""

    source: str
    g: float                      #: this record's gain, kgf/s per %
    gain: float                   #: g of this record / the shared g
    delta: float                  #: Δ of this record, kgf/s
    level: float                  #: mean |u| where the command is not zero, %


@dataclass
class BetweenRecords:
    """The best per-record design, judged against the shared g and Δ."""

    model: str                    #: the model whose g and Δ were freed per record
    varies: str                   #: "gain" | "trend" | "gain and trend"
    g: float                      #: the shared gain
    delta: float                  #: the shared trend, kgf/s
    records: list[RecordShift]
    stats: ErrorCut
    #: Spearman ρ of what varies (the gain if it does, else Δ) with the records' order, and
    #: with their command level (NaN: under MIN_RECORDS_FOR_RHO records, or no spread)
    order_rho: float
    level_rho: float
    #: what the values follow: "order" (a drift across the runs), "scatter" (run to run, in no
    #: order), "level" (the command level: a gain that depends on |u|, not on the run) or
    #: "order or level" (both: these records cannot tell)
    follows: str
    extra_params: int = 0         #: parameters beyond the shared g and Δ
    floor: float = math.nan       #: the noise floor it was judged on (objective RMSE, kgf)
    #: the model's other parameters, refitted with the per-record values (empty: they were
    #: held at the shared fit's, which explained as well)
    refit: dict[str, float] = field(default_factory=dict)
    text: str = ""

    @property
    def explains(self) -> bool:
        """With the records' own values the error is down to UNEXPLAINED_RATIO of the noise
        floor."""
        return bool(self.stats.objective_rmse <= UNEXPLAINED_RATIO * self.floor)

    @property
    def refit_text(self) -> str:
        """The refitted parameters as ``name = value, ...`` (empty if none were refitted)."""
        return ", ".join(f"{k} = {v:.4g}" for k, v in self.refit.items())

    @property
    def between_runs(self) -> bool:
        """The variation is the runs' own, not the command level's."""
        return self.follows in ("order", "scatter")

    def to_dict(self) -> dict:
        return {"model": self.model, "varies": self.varies, "g": self.g, "delta": self.delta,
                "records": [vars(r) for r in self.records], **vars(self.stats),
                "order_rho": self.order_rho, "level_rho": self.level_rho,
                "follows": self.follows, "between_runs": self.between_runs,
                "extra_params": self.extra_params, "explains": self.explains,
                "refit": dict(self.refit), "text": self.text}


def _solve(gram: np.ndarray, rhs: np.ndarray, free: tuple[bool, bool]) -> np.ndarray:
    """δ (records × 2) minimizing Σ‖s_i + A_i δ_i‖² with component c free per record where
    ``free[c]``, shared otherwise; ``gram`` (records × 2 × 2) = A_iᵀA_i, ``rhs`` = −A_iᵀs_i."""
    n_rec = len(gram)
    index = np.zeros((n_rec, 2), dtype=int)
    k = 0
    for c in range(2):
        if free[c]:
            index[:, c] = np.arange(k, k + n_rec)
            k += n_rec
        else:
            index[:, c] = k
            k += 1
    M = np.zeros((k, k))
    b = np.zeros(k)
    for i in range(n_rec):
        for a in range(2):
            b[index[i, a]] += rhs[i, a]
            for c in range(2):
                M[index[i, a], index[i, c]] += gram[i, a, c]
    x, *_ = np.linalg.lstsq(M, b, rcond=None)
    return x[index]


def _rho(a: Sequence[float], b: Sequence[float]) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) < MIN_RECORDS_FOR_RHO or np.ptp(a) == 0 or np.ptp(b) == 0:
        return math.nan
    return float(stats.spearmanr(a, b).statistic)


def record_level(rec: Record) -> float:
    """The record's command level: mean |u| where the command is not zero, %."""
    a = np.abs(rec.u[rec.u != 0])
    return float(a.mean()) if len(a) else 0.0


def _systems(spec: str, values: Mapping[str, float], pieces: Sequence[Piece],
             rec_of: np.ndarray, n_rec: int) -> tuple[np.ndarray, ...]:
    """The objective's residual, affine in g and Δ at ``values``
    (:func:`analysis.identification.projection.gain_trend_columns`: ``s1``, ``A``, ``β0``), and
    each record's 2×2 Gram matrix AᵢᵀAᵢ and right-hand side −Aᵢᵀsᵢ."""
    s1, A, beta0 = gain_trend_columns(spec, values, pieces)
    gram = np.zeros((n_rec, 2, 2))
    rhs = np.zeros((n_rec, 2))
    for i in range(n_rec):
        sel = rec_of == i
        gram[i] = A[sel].T @ A[sel]
        rhs[i] = -(A[sel].T @ s1[sel])
    return s1, A, beta0, gram, rhs


def _design(s1: np.ndarray, A: np.ndarray, gram: np.ndarray, rhs: np.ndarray,
            rec_of: np.ndarray, free: tuple[bool, bool]) -> tuple[np.ndarray, np.ndarray]:
    """δ per record of one design (``free``, see :func:`_solve`) and the residual with it."""
    delta = _solve(gram, rhs, free)
    return delta, s1 + (A * delta[rec_of]).sum(axis=1)


#: the refit's relative tolerance (cost and step): ranking against the floor needs ~0.1 %
REFIT_TOL = 1e-5


def refit_per_record(model: PlantModel, pieces: Sequence[Piece], rec_of: np.ndarray,
                     n_rec: int, free: tuple[bool, bool], max_nfev: int | None = None
                     ) -> dict[str, float]:
    """Fit ``model``'s parameters other than g and Δ with g and Δ free per record where
    ``free`` says so (shared otherwise), projected at every trial. Returns the parameters'
    values (g and Δ as they were)."""
    spec, values = model.spec, model.params()
    others = [n for n in values if n not in ("g", "delta")]
    par = Parameterization(spec, values, others)
    fresh_solutions()                # the same answer whatever this process simulated before
    if not par.free:
        return values

    def fun(x):
        s1, A, _, gram, rhs = _systems(spec, par.to_values(x), pieces, rec_of, n_rec)
        return _design(s1, A, gram, rhs, rec_of, free)[1]

    lo, hi = par.bounds()
    eps = 1e-9 * np.maximum(1.0, np.abs(hi - lo))
    x0 = np.clip(par.to_x(values), lo + eps, hi - eps)
    res = optimize.least_squares(fun, x0, bounds=(lo, hi), method="trf", x_scale="jac",
                                 diff_step=DIFF_STEP, ftol=REFIT_TOL, xtol=REFIT_TOL,
                                 max_nfev=max_nfev or 20 * (len(x0) + 1))
    return par.to_values(res.x)


def _best_design(s1: np.ndarray, A: np.ndarray, gram: np.ndarray, rhs: np.ndarray,
                 rec_of: np.ndarray) -> tuple[str, np.ndarray, np.ndarray, int]:
    """The per-record design (:data:`DESIGNS`) with the lowest BIC. Returns its name, δ per
    record, the residual and its parameters beyond the shared g and Δ."""
    n, n_rec = len(s1), len(gram)
    best = None
    for varies, free in DESIGNS.items():
        delta, r = _design(s1, A, gram, rhs, rec_of, free)
        k = sum(n_rec - 1 for c in free if c)
        bic = n * math.log(max(float(r @ r) / n, 1e-300)) + k * math.log(n)
        if best is None or bic < best[0]:
            best = (bic, varies, delta, r, k)
    return best[1:]


def between_records(model: PlantModel, pieces: Sequence[Piece], records: Sequence[Record],
                    floor: float, refit: bool = True) -> BetweenRecords | None:
    """Free fitted ``model``'s g, Δ or both per record (the design with the lowest BIC) and
    judge it against them shared (:func:`.significance.error_cut`) on the noise floor
    ``floor`` (objective RMSE, kgf). ``refit``: when the per-record values with the other
    parameters held help but leave more than UNEXPLAINED_RATIO of the floor, refit those too
    (:func:`refit_per_record`). None for fewer than two records with evaluated samples."""
    used = sorted({p.record for p in pieces if p.n_eval > 0})
    if len(used) < 2:
        return None
    n_rec = len(used)
    values = model.params()
    rec_of = np.concatenate([np.full(p.n_eval, used.index(p.record)) for p in pieces])
    s1, A, beta0, gram, rhs = _systems(model.spec, values, pieces, rec_of, n_rec)
    n = len(s1)
    shared = _solve(gram, rhs, (False, False))[0]
    varies, delta, r, k = _best_design(s1, A, gram, rhs, rec_of)
    # the reference from the same linearization, g and Δ shared: the fitted model's own error
    # (exactly so for a model linear in g and Δ, whose fit projects them)
    r0 = s1 + A @ shared
    ref_w = window_sse(r0, pieces)
    st = error_cut(window_sse(r, pieces), ref_w, floor, n, k)
    g0, d0 = beta0 + shared
    refitted: dict[str, float] = {}
    if refit and st.helps and st.objective_rmse > UNEXPLAINED_RATIO * floor \
            and len(values) > 2:
        vals2 = refit_per_record(model, pieces, rec_of, n_rec, DESIGNS[varies])
        s1b, Ab, beta_b, gram_b, rhs_b = _systems(model.spec, vals2, pieces, rec_of, n_rec)
        _, r2 = _design(s1b, Ab, gram_b, rhs_b, rec_of, DESIGNS[varies])
        if float(r2 @ r2) < float(r @ r):
            refitted = {n_: v for n_, v in vals2.items() if n_ not in ("g", "delta")}
            # the design chosen anew at the refitted parameters (a trend per record that
            # helped with them held may be needless now)
            beta0 = beta_b
            varies, delta, r, k = _best_design(s1b, Ab, gram_b, rhs_b, rec_of)
            st = error_cut(window_sse(r, pieces), ref_w, floor, n, k)
    shifts = [RecordShift(source=records[j].source, g=float(beta0[0] + delta[i, 0]),
                          gain=float((beta0[0] + delta[i, 0]) / g0) if g0 else math.nan,
                          delta=float(beta0[1] + delta[i, 1]), level=record_level(records[j]))
              for i, j in enumerate(used)]
    varied = [s.gain if "gain" in varies else s.delta for s in shifts]
    levels = [s.level for s in shifts]
    order_rho, level_rho = _rho(range(len(varied)), varied), _rho(levels, varied)
    out = BetweenRecords(model=model.spec, varies=varies, g=float(g0), delta=float(d0),
                         records=shifts, stats=st, order_rho=order_rho, level_rho=level_rho,
                         follows=_follows(order_rho, level_rho, levels), extra_params=k,
                         floor=float(floor), refit=refitted)
    out.text = describe(out)
    return out


#: records whose command levels differ by more than this factor are "at different levels"
LEVELS_DIFFER = 1.25


def _follows(order_rho: float, level_rho: float, levels: Sequence[float]) -> str:
    """What the records' values follow (see :attr:`BetweenRecords.follows`). With too few
    records for a ρ, records at different command levels cannot tell a run's own gain from one
    that depends on the command."""
    by_order, by_level = abs(order_rho) >= FOLLOWS_RHO, abs(level_rho) >= FOLLOWS_RHO
    if math.isnan(level_rho) and min(levels) > 0 and max(levels) / min(levels) > LEVELS_DIFFER:
        return "order or level"
    if by_order and by_level:
        return "order or level"
    return "level" if by_level else "order" if by_order else "scatter"


def _extremes(shifts: Sequence[RecordShift], key, fmt) -> str:
    lo = min(shifts, key=key)
    hi = max(shifts, key=key)
    return f"from {fmt(key(lo))} ('{lo.source}') to {fmt(key(hi))} ('{hi.source}')"


def describe(b: BetweenRecords) -> str:
    """The variation in words: what differs, how much, what it follows, what to do."""
    parts = []
    if "gain" in b.varies:
        parts.append(f"the gain differs between records, "
                     f"{_extremes(b.records, lambda s: s.gain, lambda x: f'{x:.3f}×')} of the "
                     f"shared g = {b.g:.4g} kgf/s per %")
    if "trend" in b.varies:
        parts.append(f"the trend Δ differs between records, "
                     f"{_extremes(b.records, lambda s: s.delta, lambda x: f'{x:+.3g}')} kgf/s "
                     f"(shared: {b.delta:+.3g})")
    if b.refit:
        parts[-1] += f" (the model's other parameters refitted with them: {b.refit_text})"
    what = "gain" if "gain" in b.varies else "trend"
    cause = ("the stand changed between the runs (oil warming over the campaign, the supply "
             "pressure or the valve's zero set anew)" if what == "gain" else
             "the valve's null moved between the runs (drive re-zeroed, warming)")
    if not b.explains:   # they leave much: a missing effect may weigh differently per record
        cause = (f"{cause}, or a missing effect that weighs differently in each record (the "
                 f"records' own values leave {b.stats.objective_rmse / b.floor:.2f}× the noise "
                 f"floor)")
    if b.follows == "order":
        follows = (f", {'growing' if b.order_rho > 0 else 'falling'} with the records' order "
                   f"(Spearman ρ = {b.order_rho:.2f}): {cause}")
    elif b.follows == "scatter":
        follows = f", from run to run in no order: {cause}"
    elif b.follows == "level":
        follows = (f", {'higher' if b.level_rho > 0 else 'lower'} in records at larger commands "
                   f"(Spearman ρ = {b.level_rho:.2f}): a {what} that depends on the command "
                   f"level more than on the run (a dead zone, a flow curve, a flow limit, or "
                   f"several effects at once: try --stepwise)")
    else:
        follows = (f": these records cannot tell a {what} that depends on the command level "
                   f"from one that changed between the runs (their levels "
                   + ("are few and differ" if math.isnan(b.level_rho) else "rise with their order")
                   + "); repeat the first run at the end of the campaign (the same command, "
                     "later) to tell them apart")
    st = b.stats
    text = ("; ".join(parts) + follows
            + f". A {b.varies} of its own per record lowers the objective error by "
              f"{100 * st.improvement:.0f} % ({100 * max(st.excess_share, 0):.0f} % of the error "
              f"above the noise)")
    if b.between_runs:
        text += (f". Fit a record alone (`stand fit --model {b.model} RECORD`) to see its own "
                 f"values, or measure with the stand in one state (warmed up, the same supply "
                 f"pressure and valve zero in every run)")
    return text
