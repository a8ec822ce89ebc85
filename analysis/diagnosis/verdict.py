r"""Find what the model is missing: fit it, add each catalogue effect in turn, rank them.

``diagnose(records, model="base")``:

1. fits the starting model (default: the paper's base model) — on a screening subset of windows
   when the data are long (see :meth:`Windows.of`), then
   polished on all data;
2. for every *diagnosable* effect of the catalogue not yet in the model, fits ``model + effect``
   (start grids for the new effect, warm start for the rest) on the screening windows, evaluates
   it on all windows, and refits the best :data:`REFIT_TOP` on all data;
3. ranks the candidates by their error, penalized for their parameters (BIC; ties go to the
   simpler law: a richer candidate that does not help over a simpler one is ranked after it,
   as its equivalent, :func:`.candidates.rank_candidates`), and judges each against
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
import time
from dataclasses import asdict, dataclass, field
from typing import Callable, Sequence

import numpy as np

from plant import PlantModel
from plant.catalogue import effect_class

from ..identification.fit import FTOL, REFIT_TOL, SCREEN_TOL, FitOptions, FitResult, fit_model
from ..identification.metrics import Evaluation, evaluate
from ..identification.windows import (WINDOW_S, Piece, errors, pieces_from_records, residual,
                                      subset_pieces, window_sse)
from ..parallel import one_blas_thread, run_each, workers_for
from ..records.record import Record
from .ambiguity import AMBIGUITY_RATIO, Ambiguity, ambiguities, drift_or_level
from .between_records import BetweenRecords, between_records
from .candidates import Candidate, diagnosable_effects, judge, rank_candidates
from .observations import (Unexplained, describe_residual, describe_unexplained, pct,
                           residual_is_noise)
from .significance import MIN_EXCESS_SHARE, MIN_IMPROVEMENT, MIN_Z, UNEXPLAINED_RATIO

#: up to this many windows the candidates are screened on all of them; with more, on about
#: half (the best is refitted on all): a candidate's screening fit is most of a diagnosis
SCREEN_ALL_UP_TO = 40
#: windows per screening chunk below 100 screening windows (each chunk brings 1 s of command
#: history before it)
SCREEN_CHUNK = 4
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

# ------------------------------------------------------------------------------------------
# what passes between the steps of the diagnosis
# ------------------------------------------------------------------------------------------
@dataclass
class Windows:
    """The data set cut for the diagnosis: all its windows, and those the candidates are
    screened on (all of them when the data are short)."""

    full: list[Piece]
    screen: list[Piece]
    subset: bool                  #: the screening windows are a subset of all

    @classmethod
    def of(cls, records: Sequence[Record], window_s: float, max_screen_windows: int) -> "Windows":
        """All the windows, and the screening ones: about half of them (in chunks of
        :data:`SCREEN_CHUNK` windows spread over every record) when there are more than
        :data:`SCREEN_ALL_UP_TO`, at most ``max_screen_windows``."""
        full = pieces_from_records(records, window_s)
        total = sum(p.n_windows for p in full)
        if total > SCREEN_ALL_UP_TO:
            target = min(max_screen_windows, total // 2)
            screen, subset = subset_pieces(full, target, SCREEN_CHUNK if target < 100 else 10)
        else:
            screen, subset = full, False
        return cls(full, screen, subset)

    @property
    def n_full(self) -> int:
        return sum(p.n_windows for p in self.full)

    @property
    def n_screen(self) -> int:
        return sum(p.n_windows for p in self.screen)


@dataclass
class Errors:
    """A model's errors on all windows: the objective's squared error per window (window
    starts re-estimated) and the RMSE from the measured starts."""

    window_sse: np.ndarray
    rmse: float


@dataclass
class StartFit:
    """The starting model fitted, and what the candidates are judged against."""

    fit: FitResult                #: fitted on all windows
    evaluation: Evaluation
    errors: Errors                #: the reference of candidates refitted on all windows
    #: the starting model fitted on the screening windows only, evaluated on all: the reference
    #: of candidates fitted there only (nested models, like with like); None: no subset
    screen_errors: Errors | None
    objective_rmse: float         #: the fit's objective on all windows, kgf
    floor: float                  #: the objective's white-noise floor, kgf

    @property
    def model(self) -> PlantModel:
        return self.fit.model


@dataclass
class Fitted:
    """A candidate fitted: on the screening windows only, or refitted on all of them."""

    effect: str
    fit: FitResult
    errors: Errors                #: on all windows
    refit_on: str                 #: "final" (refitted on all windows) or "screening"


@dataclass
class NoiseFloor:
    """The objective's noise floor the candidates are judged against: the white-noise floor,
    or the level of what the best model leaves when that looks like noise correlated in time."""

    value: float
    warning: str | None = None    #: why the floor was raised (None: it was not)


@dataclass
class Conclusion:
    """The verdict and what it adds to the diagnosis."""

    verdict: str                  #: see :attr:`Diagnosis.verdict`
    summary: str
    best: Candidate | None        #: the effect found missing (verdict "missing_effect")
    observations: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    unexplained: Unexplained | None = None


# ------------------------------------------------------------------------------------------
# the diagnosis
# ------------------------------------------------------------------------------------------
@one_blas_thread
def diagnose(records: Sequence[Record], model: PlantModel | str = "base",
             window_s: float = WINDOW_S, effects: Sequence[str] | None = None,
             max_screen_windows: int = 150, refit_top: int = REFIT_TOP,
             progress: Callable[[str], None] | None = None, jobs: int | None = None,
             fitted: bool = False, afresh: bool = False) -> Diagnosis:
    """Diagnose what ``model`` misses in ``records`` (one data set). See the module docstring.

    ``jobs``: worker processes for the candidates' screening fits (1: none; default: one per
    CPU when the data are large enough to gain, :func:`analysis.parallel.workers_for`).
    ``fitted``: ``model``'s values were fitted to these records already (a candidate of the
    step before, in a build-up): they are polished, not searched for again. ``afresh``: each
    candidate is fitted afresh, every parameter searched from its start grid and the delay
    too, not only the new effect's from the model's values (several times the work: for a
    model whose effects may have settled where a missing one should be)."""
    say = progress or (lambda msg: None)
    start = PlantModel.from_spec(model) if isinstance(model, str) else model
    effects = list(effects) if effects is not None else diagnosable_effects(start)
    for name in effects:
        effect_class(name)
    windows = Windows.of(records, window_s, max_screen_windows)
    screening = {"subset": windows.subset, "windows_total": windows.n_full,
                 "windows_screened": windows.n_screen, "refit_on_all": ["base"]}
    base = fit_start(start, windows, records, window_s, say, fitted)
    work = screening_seconds(base.model, windows, len(effects)) * (AFRESH_WORK if afresh else 1)
    workers = workers_for(len(effects), work, jobs)
    screening["workers"] = workers
    screening["afresh"] = afresh
    fitted = refit_best(screen_candidates(base.model, effects, windows, workers, say, afresh),
                        windows, refit_top, say, base)
    screening["refit_on_all"] += [c.effect for c in fitted if c.refit_on == "final"]
    cands = judge_all(fitted, base, base.floor)
    floor = judging_floor(cands, base, records, window_s)
    if floor.warning is not None:
        cands = judge_all(fitted, base, floor.value)
    earning = [c for c in cands if c.earns]
    best = earning[0] if earning else None
    ratio = base.objective_rmse / floor.value if floor.value > 0 else math.inf
    observations = describe_residual(base.evaluation)
    found = ambiguities(records, base.fit, cands, best)
    between = None
    if ratio > UNEXPLAINED_RATIO:
        say("freeing g and Δ per record")
        between = between_records(base.model, windows.full, records, floor.value)
    if between is not None and between.stats.earns and between.follows == "order or level":
        found.append(drift_or_level(best, between))
    end = conclude(best, between, base, floor.value, ratio, windows, records)
    return Diagnosis(verdict=end.verdict, model=start.spec,
                     best=end.best.effect if end.best else None, base_fit=base.fit,
                     base_eval=base.evaluation, candidates=cands,
                     noise_sigma=base.evaluation.noise_sigma, objective_floor=floor.value,
                     observations=observations + end.observations
                     + partial_explanations(cands, end.verdict),
                     ambiguities=found, unexplained=end.unexplained, summary=end.summary,
                     screening=screening,
                     warnings=list(base.fit.warnings) + ([floor.warning] if floor.warning else [])
                     + end.warnings,
                     between=between)


def fit_start(start: PlantModel, windows: Windows, records: Sequence[Record], window_s: float,
              say: Callable[[str], None], fitted: bool = False) -> StartFit:
    """Step 1: the starting model fitted (on the screening windows, then polished on all when
    they are a subset) and evaluated, with the noise floor of the objective. ``fitted``: its
    values are a fit to these records already: polished from there, no search for starts."""
    if fitted:   # fitted to all windows already: polished there, then on the screening ones
        say(f"polishing {start.spec}")
        fit = fit_model(windows.full, start, options=FitOptions.refit())
        screen_model = fit.model if not windows.subset else fit_model(
            windows.screen, fit.model, options=FitOptions.refit(covariance=False)).model
    else:
        say(f"fitting {start.spec}"
            + (f" on {windows.n_screen} of {windows.n_full} windows" if windows.subset else ""))
        fit = fit_model(windows.screen, start, options=FitOptions(covariance=not windows.subset))
        screen_model = fit.model
        if windows.subset:
            fit = fit_model(windows.full, fit.model, options=FitOptions.refit())
    w = _window_sse(fit.model, windows.full)
    screen_errors = Errors(*errors(screen_model, windows.full)) if windows.subset else None
    ev = evaluate(fit.model, records, window_s)
    return StartFit(fit=fit, evaluation=ev, errors=Errors(w, ev.rmse), screen_errors=screen_errors,
                    objective_rmse=math.sqrt(w.sum() / _n_eval(windows.full)),
                    floor=objective_floor(windows.full, ev.noise_sigma))


#: evaluations of the model a candidate's screening fit takes, about (its start grid with g and
#: Δ projected, two polishes with their Jacobians)
EVALS_PER_CANDIDATE = 100


def screening_seconds(model: PlantModel, windows: Windows, candidates: int) -> float:
    """The candidates' screening fits' time on one core, estimated from one evaluation of the
    starting model on the screening windows (a force-dependent model costs several times more
    per sample than one whose force is a running sum)."""
    t0 = time.perf_counter()
    residual(model, windows.screen)
    return (time.perf_counter() - t0) * EVALS_PER_CANDIDATE * candidates


#: a candidate fitted afresh (every start grid, the delay searched) costs about this many times
#: a screening fit from the model's values
AFRESH_WORK = 3


def _screen_candidate(shared: tuple, name: str) -> FitResult | None:
    """``base + name`` fitted on the screening windows (a grid for the new effect, the rest
    warm; or afresh: every effect's grid and the delay searched, the model's values one start
    among them), or None if the effect cannot start from the base model's values."""
    base_model, screen, afresh = shared
    try:
        m0 = PlantModel.from_spec(f"{base_model.spec}+{name}", base_model.params())
    except Exception:  # noqa: BLE001 - an effect that cannot start from here is skipped
        return None
    return fit_model(screen, m0, options=FitOptions(covariance=False, tol=SCREEN_TOL) if afresh
                     else FitOptions.add_effect(name))


def screen_candidates(base_model: PlantModel, effects: Sequence[str], windows: Windows,
                      workers: int, say: Callable[[str], None],
                      afresh: bool = False) -> dict[str, FitResult]:
    """Step 2: ``base_model + effect`` fitted on the screening windows for every effect (in
    ``workers`` processes), in the order of ``effects`` whatever order the workers finished in;
    effects that cannot start from the base model's values are left out. ``afresh``: see
    :func:`diagnose`."""
    done: dict[str, FitResult | None] = {}
    for name, fit in run_each(_screen_candidate, effects, (base_model, windows.screen, afresh),
                              workers):
        say(f"tried +{name}" if workers > 1 else f"trying +{name}")
        done[name] = fit
    return {n: done[n] for n in effects if done[n] is not None}


def refit_best(fits: dict[str, FitResult], windows: Windows, refit_top: int,
               say: Callable[[str], None], base: StartFit) -> list[Fitted]:
    """Step 3: the screened candidates judged and ranked on all windows with their screening
    parameters (:func:`.candidates.rank_candidates`, as the final ranking: a law tied with a
    richer one comes first), the best ``refit_top`` (two at least when the screening windows
    are all of them) refitted on all data. In the order of that ranking."""
    screened = [Fitted(name, f, Errors(*errors(f.model, windows.full)), "screening")
                for name, f in fits.items()]
    out = []
    for rank, c in enumerate(judge_all(screened, base, base.floor)):
        fitted = next(s for s in screened if s.effect == c.effect)
        if rank < (refit_top if windows.subset else max(refit_top, 2)):
            say(f"refitting +{c.effect} on all windows")
            f = fit_model(windows.full, fitted.fit.model,
                          options=FitOptions.refit(tol=FTOL if not windows.subset else REFIT_TOL))
            fitted = Fitted(c.effect, f, Errors(*errors(f.model, windows.full)), "final")
        out.append(fitted)
    return out


def judge_all(fitted: Sequence[Fitted], base: StartFit, floor: float) -> list[Candidate]:
    """Step 4: every candidate judged against the starting model fitted on the same windows,
    at the noise floor ``floor``, and ranked (:func:`.candidates.rank_candidates`)."""
    out = []
    for c in fitted:
        if c.refit_on == "screening" and base.screen_errors is not None:
            ref = base.screen_errors
        else:
            ref = base.errors
        out.append(judge(c.effect, c.fit, c.errors.window_sse, c.errors.rmse, ref.window_sse,
                         ref.rmse, floor, base.evaluation.n, c.refit_on))
    return rank_candidates(out, floor, base.evaluation.n)


def judging_floor(cands: Sequence[Candidate], base: StartFit, records: Sequence[Record],
                  window_s: float) -> NoiseFloor:
    """Step 5: the noise floor to judge by. With correlated (coloured) measurement noise the
    white-noise floor from second differences is too low: if what the best model leaves is
    noise-like — unrelated to the command, no periodic component — its level is the floor.
    The best model is the one that leaves the least error, not the first ranked: a tie goes to
    the simpler law, whose excess an equivalent may still remove."""
    floor = base.floor
    top = min((c for c in cands if c.improvement >= MIN_IMPROVEMENT),
              key=lambda c: c.objective_rmse, default=None)
    ref_model = top.fit.model if top is not None else base.model
    ref_obj = top.objective_rmse if top is not None else base.objective_rmse
    if ref_obj > COLOURED_RATIO * floor and residual_is_noise(ref_model, records, window_s, floor):
        return NoiseFloor(ref_obj, (
            f"the error left by {ref_model.spec} ({ref_obj:.3g} kgf, objective) is "
            f"{ref_obj / floor:.2f}× the white-noise floor but looks like noise (broadband, "
            f"unrelated to the command): the measurement noise is correlated in time "
            f"(a filtered sensor?); it is taken as the noise floor"))
    return NoiseFloor(floor)


def conclude(best: Candidate | None, between: BetweenRecords | None, base: StartFit,
             floor: float, ratio: float, windows: Windows, records: Sequence[Record]) -> Conclusion:
    """Step 6: the verdict, from the best earning candidate (``best``), the records' own g and
    Δ (``between``) and the starting model's error over the noise floor (``ratio``)."""
    # the stand changed between the runs only if the records' own values explain the data (to
    # the noise): per-record values that earn but leave much also soak up a missing effect
    # whose share differs between records (a force-dependent unloading with each run at its
    # own force level)
    between_explains = (between is not None and between.stats.earns and between.between_runs
                        and between.explains)
    if between_explains and (
            best is None or best.objective_rmse > AMBIGUITY_RATIO * between.stats.objective_rmse):
        end = Conclusion("varies_between_records", f"varies between records: {between.text}", None)
        if best is not None:
            end.observations.append(
                f"+{best.effect} would lower the error by {100 * best.improvement:.0f} %, a "
                f"{between.varies} per record by {100 * between.stats.improvement:.0f} %")
        return end
    if best is not None:
        after = best.objective_rmse / floor if floor > 0 else math.inf
        end = Conclusion("missing_effect",
                         f"missing effect: {best.effect} — adding it lowers the windowed RMSE from "
                         f"{base.evaluation.rmse:.3g} to {best.rmse:.3g} kgf "
                         f"({100 * best.rmse_reduction:.0f} %)"
                         + (f"; as little error with more parameters: "
                            f"{', '.join('+' + e for e in best.equivalents)} (its equivalent)"
                            if best.equivalents else ""), best)
        if after > UNEXPLAINED_RATIO:
            end.warnings.append(f"with {best.effect} the error is still {after:.2f}× the noise "
                                f"floor: diagnose again with --model {best.spec}")
            left = between_records(best.fit.model, windows.full, records, floor)
            if left is not None and left.stats.helps and left.follows != "level":
                end.observations.append(f"what {best.spec} leaves differs between records: "
                                        f"{left.text}")
        return end
    if ratio > UNEXPLAINED_RATIO:
        observations = []
        if between is not None and between.stats.helps:
            observations.append(between.text + ("" if between.stats.earns else
                                                ": part of the missing behaviour, not all of it"))
        unexplained = describe_unexplained(base.evaluation, floor, ratio, base.fit)
        observations.append(unexplained.next_step)
        return Conclusion("unexplained",
                          f"unexplained: the error is {ratio:.2f}× the noise floor and no effect "
                          f"tried removes it; {unexplained.description}", None,
                          observations=observations, unexplained=unexplained)
    return Conclusion("adequate", f"adequate: {base.model.spec} explains the data to "
                                  f"{ratio:.2f}× the noise floor; no effect earns its parameters",
                      None)


def partial_explanations(cands: Sequence[Candidate], verdict: str) -> list[str]:
    """Step 7: the candidates that lower the error consistently but do not earn their
    parameters, and why not (unless an effect was found missing)."""
    out = []
    for c in cands:
        if not c.earns and c.improvement >= 0.01 and c.z >= MIN_Z and verdict != "missing_effect":
            if not c.own:
                why = f"but it is not let in: {c.evidence}"
            elif c.improvement < MIN_IMPROVEMENT:
                why = f"but below the {100 * MIN_IMPROVEMENT:.0f} % worth reporting"
            elif c.excess_share < MIN_EXCESS_SHARE:
                why = (f"but it removes only {pct(max(c.excess_share, 0.0))} of the error above "
                       "the noise: part of the missing behaviour, not all of it")
            else:
                why = "but not significant against the noise"
            out.append(f"+{c.effect} would lower the error by {100 * c.improvement:.1f} % "
                       f"(consistent over windows, {why})")
    return out


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
