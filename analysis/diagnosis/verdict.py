r"""Find what the model is missing: fit it, add each catalogue effect in turn, rank them.

``diagnose(records, model="base")``:

1. fits the starting model (default: the paper's base model) — on a screening subset of windows
   when the data are long (see :func:`analysis.identification.windows.screening_pieces`), then
   polished on all data;
2. for every *diagnosable* effect of the catalogue not yet in the model, fits ``model + effect``
   (start grids for the new effect, warm start for the rest) on the screening windows, evaluates
   it on all windows, and refits the best :data:`REFIT_TOP` on all data;
3. ranks the candidates by their error, penalized for their parameters (BIC: among effects that
   remove the same error within the noise, the simpler comes first), and judges each against
   the noise, on the objective of the fit (windowed error, window
   starts re-estimated; its noise floor is ``σ²·(1 − 1/W)``, σ from the force's second
   differences):

   * it *earns its parameters* if it removes at least :data:`MIN_EXCESS_SHARE` of the error
     above the noise floor, lowers the RMSE by at least :data:`MIN_IMPROVEMENT`, and does so
     consistently over the windows (paired z over the windows ≥ :data:`MIN_Z`);
   * verdict ``missing_effect`` (the best earning candidate), ``varies_between_records`` (no
     catalogue effect explains the error as well as a gain or a trend of its own for every
     record does, and with them the error is down to :data:`UNEXPLAINED_RATIO` of the noise:
     the stand changed between the runs, :mod:`.between_records`),
     ``unexplained`` (the error stays clearly above the noise, :data:`UNEXPLAINED_RATIO`, and
     nothing removes it: the residual is described — dominant frequency, amplitude, regimes),
     or ``adequate``;

4. describes the residual pattern of the starting model in plain words (reversal transients,
   extend/retract slopes, gain per command level, force dependence, periodic content:
   :mod:`.observations`) and warns when the data cannot separate two explanations, naming the
   experiment that would (:mod:`.ambiguity`).

The candidates and how each is judged are in :mod:`.candidates`; the criteria in
:mod:`.significance`.
"""
from __future__ import annotations
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Callable, Sequence

import numpy as np

from plant import PlantModel
from plant.effects import effect_class

from ..identification.fit import FTOL, REFIT_TOL, FitOptions, FitResult, fit_model
from ..identification.metrics import Evaluation, evaluate
from ..identification.windows import (WINDOW_S, Piece, errors, pieces_from_records, residual,
                                      screening_pieces, window_sse)
from ..parallel import one_blas_thread, run_each, workers_for
from ..records.record import Record
from .ambiguity import AMBIGUITY_RATIO, Ambiguity, drift_or_level
from .ambiguity import ambiguities as find_ambiguities
from .between_records import BetweenRecords, between_records
from .candidates import Candidate, diagnosable_effects, judge, rank_candidates
from .observations import (Unexplained, describe_residual, describe_unexplained, pct,
                           residual_is_noise)
from .significance import MIN_EXCESS_SHARE, MIN_IMPROVEMENT, MIN_Z, UNEXPLAINED_RATIO

#: candidates refitted on all the data after screening (the best; the runner-up too when the
#: data are short enough to be screened whole)
REFIT_TOP = 1
#: below this ratio the model is within the noise: nothing to explain
ADEQUATE_RATIO = 1.03
#: above this ratio to the white-noise floor, the residual is checked for being coloured noise
COLOURED_RATIO = 1.03


@dataclass
class Diagnosis:
    #: "adequate" | "missing_effect" | "varies_between_records" | "unexplained"
    verdict: str
    model: str                    #: the starting model
    best: str | None
    base_fit: FitResult = field(repr=False)
    base_eval: Evaluation = field(repr=False)
    candidates: list[Candidate]
    noise_sigma: float
    objective_floor: float        #: noise floor of the objective RMSE, kgf
    observations: list[str]
    ambiguities: list[Ambiguity]
    unexplained: Unexplained | None
    summary: str
    screening: dict
    warnings: list[str] = field(default_factory=list)
    #: the starting model with a g and/or Δ of its own per record (None: one record, or the
    #: error within the noise)
    between: BetweenRecords | None = None

    @property
    def best_candidate(self) -> Candidate | None:
        return next((c for c in self.candidates if c.effect == self.best), None)

    def to_dict(self) -> dict:
        ev = self.base_eval
        base = {**ev.summary(), "model": self.base_fit.model.spec,
                "params": self.base_fit.model.params(),
                "objective_rmse": self.base_fit.objective_rmse,
                "objective_noise_floor": self.objective_floor,
                "intervals": {k: e.to_dict() for k, e in self.base_fit.estimates.items()},
                "regimes": [asdict(r) for r in ev.regimes],
                "worst_windows": [asdict(w) for w in ev.worst_windows()]}
        return {"verdict": self.verdict, "model": self.model, "best": self.best,
                "summary": self.summary, "base": base,
                "candidates": [c.to_dict() for c in self.candidates],
                "unexplained": asdict(self.unexplained) if self.unexplained else None,
                "observations": self.observations,
                "ambiguities": [{**asdict(a), "text": a.text()} for a in self.ambiguities],
                "noise_sigma": self.noise_sigma, "screening": self.screening,
                "between_records": self.between.to_dict() if self.between else None,
                "warnings": self.warnings}

def _screen_candidate(shared: tuple, name: str) -> FitResult | None:
    """``base + name`` fitted on the screening windows (a grid for the new effect, the rest
    warm), or None if the effect cannot start from the base model's values."""
    base_model, screen = shared
    try:
        m0 = PlantModel.from_spec(f"{base_model.spec}+{name}", base_model.params())
    except Exception:  # noqa: BLE001 - an effect that cannot start from here is skipped
        return None
    return fit_model(screen, m0, options=FitOptions.add_effect(name))


@one_blas_thread
def diagnose(records: Sequence[Record], model: PlantModel | str = "base",
             window_s: float = WINDOW_S, effects: Sequence[str] | None = None,
             max_screen_windows: int = 150, refit_top: int = REFIT_TOP,
             progress: Callable[[str], None] | None = None, jobs: int | None = None) -> Diagnosis:
    """Diagnose what ``model`` misses in ``records`` (one data set). See the module docstring.

    ``jobs``: worker processes for the candidates' screening fits (1: none; default: one per
    CPU when the data are large enough to gain, :func:`analysis.parallel.workers_for`)."""
    say = progress or (lambda msg: None)
    start = PlantModel.from_spec(model) if isinstance(model, str) else model
    effects = list(effects) if effects is not None else diagnosable_effects(start)
    for name in effects:
        effect_class(name)
    full = pieces_from_records(records, window_s)
    screen, subset = screening_pieces(records, window_s, max_windows=max_screen_windows)
    n_full_w = sum(p.n_windows for p in full)
    n_screen_w = sum(p.n_windows for p in screen)
    screening = {"subset": subset, "windows_total": n_full_w, "windows_screened": n_screen_w,
                 "refit_on_all": ["base"]}
    say(f"fitting {start.spec}" + (f" on {n_screen_w} of {n_full_w} windows" if subset else ""))
    base_fit = fit_model(screen, start, options=FitOptions(covariance=not subset))
    screen_base = base_fit.model
    if subset:
        base_fit = fit_model(full, base_fit.model, options=FitOptions.refit())
    base_model = base_fit.model
    base_w = _window_sse(base_model, full)
    # candidates fitted on the screening windows only are compared with the base fitted there
    # too (both evaluated on all windows): nested models, like with like
    screen_ref = errors(screen_base, full) if subset else None
    base_eval = evaluate(base_model, records, window_s)
    sigma = base_eval.noise_sigma
    floor = objective_floor(full, sigma)
    base_obj = math.sqrt(base_w.sum() / _n_eval(full))
    warnings = list(base_fit.warnings)
    judged: list[tuple] = []
    workers = workers_for(len(effects), _n_eval(screen) * len(effects), jobs)
    screening["workers"] = workers
    done: dict[str, FitResult | None] = {}
    for name, fit in run_each(_screen_candidate, effects, (base_model, screen), workers):
        say(f"tried +{name}" if workers > 1 else f"trying +{name}")
        done[name] = fit
    # in the catalogue's order, whatever order the workers finished in
    fits: dict[str, FitResult] = {n: done[n] for n in effects if done[n] is not None}
    # rank on all windows with the screening parameters, refit the best on all data
    scored = []
    for name, f in fits.items():
        w, rmse = errors(f.model, full)
        scored.append((float(w.sum()), name, w, rmse))
    scored.sort(key=lambda x: x[0])
    for rank, (_, name, w, rmse) in enumerate(scored):
        f = fits[name]
        refit = "screening"
        if rank < (refit_top if subset else max(refit_top, 2)):
            say(f"refitting +{name} on all windows")
            f = fit_model(full, f.model,
                          options=FitOptions.refit(tol=FTOL if not subset else REFIT_TOL))
            w, rmse = errors(f.model, full)
            refit = "final"
            screening["refit_on_all"].append(name)
        fits[name] = f
        judged.append((name, f, w, rmse, refit))

    def judge_all(fl: float) -> list[Candidate]:
        out = []
        for name, f, w, rmse, refit in judged:
            if refit == "screening" and screen_ref is not None:
                ref_w, ref_rmse = screen_ref
            else:
                ref_w, ref_rmse = base_w, base_eval.rmse
            out.append(judge(name, f, w, rmse, ref_w, ref_rmse, fl, base_eval.n, refit))
        return rank_candidates(out)

    cands = judge_all(floor)
    # correlated (coloured) measurement noise: the white-noise floor from second differences is
    # then too low. If what the best model leaves is noise-like — unrelated to the command, no
    # periodic component — its level is the floor.
    top = cands[0] if cands and cands[0].improvement >= MIN_IMPROVEMENT else None
    ref_model = top.fit.model if top is not None else base_model
    ref_obj = top.objective_rmse if top is not None else base_obj
    noise_like = None
    if ref_obj > COLOURED_RATIO * floor:
        noise_like = residual_is_noise(ref_model, records, window_s, floor)
        if noise_like:
            warnings.append(
                f"the error left by {ref_model.spec} ({ref_obj:.3g} kgf, objective) is "
                f"{ref_obj / floor:.2f}× the white-noise floor but looks like noise (broadband, "
                f"unrelated to the command): the measurement noise is correlated in time "
                f"(a filtered sensor?); it is taken as the noise floor")
            floor = ref_obj
            cands = judge_all(floor)
    earning = [c for c in cands if c.earns]
    best = earning[0] if earning else None
    ratio = base_obj / floor if floor > 0 else math.inf
    observations = describe_residual(base_eval)
    ambiguities = find_ambiguities(records, base_fit, cands, best)
    unexplained = None
    between = None
    if ratio > UNEXPLAINED_RATIO:
        say("freeing g and Δ per record")
        between = between_records(base_model, full, records, floor)
    if between is not None and between.stats.earns and between.follows == "order or level":
        ambiguities.append(drift_or_level(best, between))
    # the stand changed between the runs only if the records' own values explain the data (to
    # the noise): per-record values that earn but leave much also soak up a missing effect
    # whose share differs between records (a force-dependent unloading with each run at its
    # own force level)
    between_explains = (between is not None and between.stats.earns and between.between_runs
                        and between.explains)
    if between_explains and (
            best is None or best.objective_rmse > AMBIGUITY_RATIO * between.stats.objective_rmse):
        verdict = "varies_between_records"
        summary = f"varies between records: {between.text}"
        if best is not None:
            observations.append(
                f"+{best.effect} would lower the error by {100 * best.improvement:.0f} %, a "
                f"{between.varies} per record by {100 * between.stats.improvement:.0f} %")
        best = None
    elif best is not None:
        verdict = "missing_effect"
        after = best.objective_rmse / floor if floor > 0 else math.inf
        summary = (f"missing effect: {best.effect} — adding it lowers the windowed RMSE from "
                   f"{base_eval.rmse:.3g} to {best.rmse:.3g} kgf ({100 * best.rmse_reduction:.0f} %)")
        if after > UNEXPLAINED_RATIO:
            warnings.append(f"with {best.effect} the error is still {after:.2f}× the noise floor: "
                            f"diagnose again with --model {best.spec}")
            left = between_records(best.fit.model, full, records, floor)
            if left is not None and left.stats.helps and left.follows != "level":
                observations.append(f"what {best.spec} leaves differs between records: "
                                    f"{left.text}")
    elif ratio > UNEXPLAINED_RATIO:
        if between is not None and between.stats.helps:
            observations.append(between.text + ("" if between.stats.earns else
                                                ": part of the missing behaviour, not all of it"))
        verdict = "unexplained"
        unexplained = describe_unexplained(base_eval, floor, ratio, base_fit)
        summary = (f"unexplained: the error is {ratio:.2f}× the noise floor and no catalogue "
                   f"effect removes it; {unexplained.description}")
    else:
        verdict = "adequate"
        summary = (f"adequate: {base_model.spec} explains the data to "
                   f"{ratio:.2f}× the noise floor; no effect earns its parameters")
    for c in cands:
        if not c.earns and c.improvement >= 0.01 and c.z >= MIN_Z and verdict != "missing_effect":
            if c.improvement < MIN_IMPROVEMENT:
                why = f"but below the {100 * MIN_IMPROVEMENT:.0f} % worth reporting"
            elif c.excess_share < MIN_EXCESS_SHARE:
                why = (f"but it removes only {pct(max(c.excess_share, 0.0))} of the error above "
                       "the noise: part of the missing behaviour, not all of it")
            else:
                why = "but not significant against the noise"
            observations.append(f"+{c.effect} would lower the error by {100 * c.improvement:.1f} % "
                                f"(consistent over windows, {why})")
    return Diagnosis(verdict=verdict, model=start.spec, best=best.effect if best else None,
                     base_fit=base_fit, base_eval=base_eval, candidates=cands, noise_sigma=sigma,
                     objective_floor=floor, observations=observations, ambiguities=ambiguities,
                     unexplained=unexplained, summary=summary, screening=screening,
                     warnings=warnings, between=between)


def _n_eval(pieces: Sequence[Piece]) -> int:
    return sum(p.n_eval for p in pieces)


def _window_sse(model: PlantModel, pieces: Sequence[Piece]) -> np.ndarray:
    return window_sse(residual(model, pieces), pieces)


def objective_floor(pieces: Sequence[Piece], sigma: float) -> float:
    """RMSE of the objective for a perfect model: white noise minus its window mean,
    ``σ·sqrt(1 − 1/W)`` averaged over the windows."""
    n = _n_eval(pieces)
    dof = sum(p.n_eval - p.n_windows for p in pieces)
    return sigma * math.sqrt(dof / n) if n else math.nan
