r"""Find what the model is missing: fit it, add each catalogue effect in turn, rank them.

``diagnose(records, model="base")``:

1. fits the starting model (default: the paper's base model) — on a screening subset of windows
   when the data are long (see :func:`analysis.fit.screening_pieces`), then polished on all data;
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
     the stand changed between the runs, :mod:`analysis.between_records`),
     ``unexplained`` (the error stays clearly above the noise, :data:`UNEXPLAINED_RATIO`, and
     nothing removes it: the residual is described — dominant frequency, amplitude, regimes),
     or ``adequate``;

4. describes the residual pattern of the starting model in plain words (reversal transients,
   extend/retract slopes, gain per command level, force dependence, periodic content) and warns
   when the data cannot separate two explanations, naming the experiment that would.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Callable, Sequence

import numpy as np

from plant import CATALOGUE, PlantModel
from plant.effects import effect_class

from .between_records import BetweenRecords, between_records
from .identification.fit import FTOL, REFIT_TOL, FitOptions, FitResult, fit_model
from .identification.metrics import (AFTER_REVERSAL_S, Evaluation, RecordSimulation,
                                     command_levels, demeaned_residual, evaluate,
                                     input_correlation_test, is_closed_loop, reversal_mask,
                                     simulate_records, window_increments)
from .identification.windows import (WINDOW_S, Piece, errors, pieces_from_records, residual,
                                     screening_pieces, window_sse)
from .parallel import one_blas_thread, run_each, workers_for
from .records.record import Record
from .significance import MIN_EXCESS_SHARE, MIN_IMPROVEMENT, MIN_Z, UNEXPLAINED_RATIO, error_cut
from .timing import jitter_observation

#: candidates refitted on all the data after screening (the best; the runner-up too when the
#: data are short enough to be screened whole)
REFIT_TOP = 1
#: below this ratio the model is within the noise: nothing to explain
ADEQUATE_RATIO = 1.03
#: above this ratio to the white-noise floor, the residual is checked for being coloured noise
COLOURED_RATIO = 1.03
#: p-value below which the residual counts as related to the command (a real model error gives
#: p-values many orders smaller; 0.001 keeps noise from ever being called structure)
NOISE_P = 1e-3
#: a residual whose mean square late in the windows (80-100 % of the horizon) differs from its
#: mean square early on (20-40 %) by more than this factor, either way, changes along the
#: free-run: a model error, not noise (noise, white or coloured, gives n(t) − n(t₀): flat once
#: past its correlation time; filtered noise up to 0.2 s gave 0.70-1.71 on 16 s records)
NOISE_GROWTH_MAX = 2.0
#: a second candidate that leaves at most this times the error the best leaves is "not
#: separable" from it (comparing what is left, not what is removed: 63 % and 93 % removed leave
#: errors five times apart, which the data do separate)
AMBIGUITY_RATIO = 1.1

#: what separates a drift across the runs from an effect of the command level
REPEAT_FIRST_RUN = ("the first run repeated at the end of the campaign (the same command, "
                    "later): an effect of the command level gives it the first run's gain, a "
                    "drift across the runs the last run's")

#: BIC differences below this are a tie (Kass & Raftery: under 2 is "not worth more than a bare
#: mention"); tied candidates are ranked in catalogue order
BIC_TIE = 2.0

#: what separates two explanations (unordered pair -> experiment)
SEPARATING_EXPERIMENT = {
    frozenset({"lag", "delay"}): "a meander (step commands) or P-feedback at several reference "
                                 "frequencies: a lag rounds the corners and its phase grows less "
                                 "than linearly with frequency; a delay only shifts",
    frozenset({"resonance", "lag"}): "a meander (command steps) at a small amplitude, or "
                                      "P-feedback at reference frequencies up to the suspected "
                                      "f_n: a lag never overshoots, a resonance rings after "
                                      "each step and peaks near f_n",
    frozenset({"resonance", "delay"}): "P-feedback at several reference frequencies, up to a "
                                       "third of the sample rate: far below f_n a resonance "
                                       "only adds the delay 2ζ/ω_n, near it the phase and gain "
                                       "change fast",
    frozenset({"slew", "lag"}): "the meander at several amplitudes (e.g. 5 and 20 %): a speed "
                                "limit rounds a step for |Δu|/R, four times as long at four "
                                "times the step, a lag for the same time constant at every step",
    frozenset({"slew", "delay"}): "the meander at several amplitudes: a speed-limited spool "
                                  "reaches the flow |Δu|/(2R) late, later for larger steps; a "
                                  "delay is the same at every amplitude",
    frozenset({"supply", "flow_curve"}): "a large command held for several seconds after a hold "
                                         "at zero: a sagging supply starts at the full slope and "
                                         "bends it down over its time constant, a flow curve "
                                         "has the lower slope from the first instant",
    frozenset({"supply", "saturation"}): "a large command held for several seconds after a "
                                         "hold at zero: a flow limit caps the slope at once, a "
                                         "sagging supply lowers it over its time constant",
    frozenset({"gain_drift", "supply"}): "a long run at one small command amplitude: a "
                                         "warming oil changes the gain whatever the flow drawn, "
                                         "a sagging supply hardly sags at small openings and "
                                         "recovers in every pause",
    frozenset({"null_drift", "gain_drift"}): "the meander at two amplitudes (e.g. 5 and 20 %), "
                                              "or holds at zero command early and late in a "
                                              "run: a drifting null adds the same kgf/s at "
                                              "every command and at zero, a drifting gain "
                                              "scales with |u|",
    frozenset({"null_drift", "trend"}): "one long run, or holds at zero command at its start "
                                        "and its end: the trend Δ is the same throughout, a "
                                        "drifting null moves it during the run",
    frozenset({"gain_drift", "gain"}): "two runs, one after the other, or one long run: a "
                                       "drifting gain differs between the starts and the ends "
                                       "of the runs, a wrong gain is wrong everywhere alike",
    frozenset({"deadzone", "gain"}): "the meander at several amplitudes (e.g. 5, 10, 15, 20 %): "
                                     "a dead zone lowers the slope by g·d at every amplitude, "
                                     "a lower gain in proportion to |u|",
    frozenset({"saturation", "gain"}): "the meander at several amplitudes, some beyond the "
                                       "suspected flow limit: the slope stops growing with |u|",
    frozenset({"asymmetry", "trend"}): "the meander at two amplitudes, or a hold at zero "
                                       "command: the trend Δ is the same at every |u|, an "
                                       "extend/retract asymmetry grows with |u|",
    frozenset({"leakage", "load_pressure"}): "meanders at two amplitudes, or a hold at zero "
                                             "command away from zero force: leakage drifts "
                                             "toward zero at any command, the load-pressure "
                                             "effect scales with |u|",
    frozenset({"leakage", "trend"}): "runs around two different force levels (e.g. meanders "
                                     "centred at +2000 and −2000 kgf): leakage drifts toward "
                                     "zero, the trend Δ does not depend on the force",
    frozenset({"load_pressure", "asymmetry"}): "runs at both positive and negative force "
                                               "levels: the load-pressure effect swaps "
                                               "extend/retract with the sign of the force",
    frozenset({"reversal", "lag"}): "the meander at several amplitudes and periods",
    frozenset({"reversal", "command_reversal"}): "the meander with a delay comparable to the "
                                                 "boost's decay: a boost timed from the command "
                                                 "already pushes the old direction during the "
                                                 "delay, one timed from the rod starts after it",
    frozenset({"reversal", "travel_reversal"}): "the meander at several amplitudes (e.g. 5 and "
                                                "20 %): a boost timed from the reversal lasts "
                                                "T_r at every amplitude, one that dies out over "
                                                "the travel lasts V_r/|u|, four times shorter at "
                                                "four times the command",
    frozenset({"command_reversal", "travel_reversal"}): "the meander at several amplitudes: a "
                                                        "boost timed from the command lasts T_r "
                                                        "at every amplitude and starts during "
                                                        "the delay, one that dies out over the "
                                                        "travel lasts V_r/|u| from the rod's "
                                                        "reversal",
    frozenset({"deadzone", "backlash"}): "P-feedback with a harmonic reference (a command that "
                                         "turns smoothly): a play delays the valve at every "
                                         "turning point of the command, a dead zone only cuts "
                                         "the flow near zero; square waves (meander, relay) "
                                         "cannot tell them apart",
    frozenset({"deadzone", "flow_curve"}): "the meander at three or more amplitudes (e.g. 5, 10, "
                                           "15, 20 %): two amplitudes fit both exactly; a dead "
                                           "zone lowers every slope by g·d, a flow curve bends "
                                           "the slopes as |u|^p",
    frozenset({"saturation", "flow_curve"}): "the meander at amplitudes below and beyond the "
                                             "suspected limit: a flow limit leaves the small "
                                             "amplitudes' slopes in proportion and flattens only "
                                             "above it, a flow curve bends them all",
    frozenset({"flow_curve", "gain"}): "the meander at several amplitudes: the ramp slopes grow "
                                       "as |u|^p instead of in proportion to |u|",
    frozenset({"backlash", "gain"}): "the meander at several amplitudes, or P-feedback with a "
                                     "harmonic reference",
    frozenset({"stiction", "delay"}): "the meander at two or more amplitudes (e.g. 5 and 20 %): a "
                                      "rod stuck after each reversal holds the force w/(g·|u|), longer "
                                      "at small amplitudes; a delay is the same at every amplitude",
    frozenset({"stiction", "backlash"}): "the meander (square waves): a play on the command is "
                                         "jumped at once by a step, a stuck rod still holds the "
                                         "force after each reversal",
    frozenset({"direction_delay", "trend"}): "meanders at two periods (e.g. 4 and 12 s): a "
                                             "trend Δ is the same at both, the flow's extra "
                                             "time at one command each period shrinks with a "
                                             "longer period",
    frozenset({"unloading", "asymmetry"}): "runs at both positive and negative force levels: "
                                           "an asymmetry keeps its fast direction, a specimen "
                                           "stiffer unloading swaps it with the sign of the force",
    frozenset({"unloading", "load_pressure"}): "runs at two force levels of the same sign (e.g. "
                                               "meanders centred at 2000 and 6000 kgf): the "
                                               "load-pressure effect grows with the force, the "
                                               "unloading stiffness only switches at zero force",
    frozenset({"lag", "sensor_lag"}): "the dynamometer's own filter setting (its configuration "
                                      "or data sheet) or a second force measurement; in a "
                                      "linear plant nothing on the command side separates "
                                      "them, behind a valve nonlinearity (dead zone, flow "
                                      "limit, reversal boost) meanders at amplitudes near it "
                                      "can",
}


def separating_experiment(a: str, b: str) -> str:
    return SEPARATING_EXPERIMENT.get(frozenset({a, b}),
                                     "the meander at several amplitudes and periods, plus relay "
                                     "and P-feedback runs (richer excitation)")


# ------------------------------------------------------------------------------------------
# results
# ------------------------------------------------------------------------------------------
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


@dataclass
class Ambiguity:
    effects: list[str]            #: what cannot be told apart ("deadzone", "gain", ...)
    reason: str
    experiment: str               #: the experiment that would separate them

    def text(self) -> str:
        if len(self.effects) == 1:
            return f"{self.effects[0]}: {self.reason} To test it: {self.experiment}."
        return f"{' vs '.join(self.effects)}: {self.reason} To separate them: {self.experiment}."


@dataclass
class Unexplained:
    dominant_frequency_hz: float | None
    amplitude_kgf: float | None
    periodic_share: float         #: share of the excess error a sinusoid at that frequency explains
    rmse_over_floor: float
    correlated_with_command: bool
    description: str


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
# the diagnosis
# ------------------------------------------------------------------------------------------
def diagnosable_effects(model: PlantModel) -> list[str]:
    have = {e.name for e in model.effects}
    return [n for n, c in CATALOGUE.items() if c.diagnosable and n not in have]


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
    ambiguities = _ambiguities(records, base_fit, cands, best)
    unexplained = None
    between = None
    if ratio > UNEXPLAINED_RATIO:
        say("freeing g and Δ per record")
        between = between_records(base_model, full, records, floor)
    if between is not None and between.stats.earns and between.follows == "order or level":
        ambiguities.append(Ambiguity(
            effects=[best.effect if best is not None else "a gain that depends on the command",
                     f"a {between.varies} that changed between the runs"],
            reason=(f"the records' own {between.varies}s would explain the error as well, and "
                    f"these records cannot tell a drift across the runs from a dependence on "
                    f"the command level (their levels rise with their order, or they are few)."),
            experiment=REPEAT_FIRST_RUN))
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
                why = (f"but it removes only {_pct(max(c.excess_share, 0.0))} of the error above "
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


# ------------------------------------------------------------------------------------------
# plain words
# ------------------------------------------------------------------------------------------
def _pct(x: float) -> str:
    return f"{100 * x:.0f} %"


def describe_residual(ev: Evaluation) -> list[str]:
    """Plain-words description of where and how the model ``ev.model`` misses the data."""
    out: list[str] = []
    floor = ev.noise_floor
    out.append(f"windowed RMSE {ev.rmse:.3g} kgf, fit {ev.fit_percent:.2f} %; noise floor "
               f"{floor:.3g} kgf (σ = {ev.noise_sigma:.3g} kgf); with the window starts "
               f"re-estimated the error is {ev.excess_ratio:.2f}× what the noise allows")
    rev = reversal_transient(ev.sims, ev.model.tau)
    if rev is not None:
        out.append(rev)
    out += slope_observations(ev.sims)
    if ev.excess_ratio > 1.1:
        out += drift_observation(ev.sims)
        out += jitter_observation(ev.sims, ev.model.g)
    conc = [r for r in ev.regimes if r.group == "reversal" and r.name.startswith("first")]
    if conc and ev.excess_ratio > 1.1:
        r = conc[0]
        if r.sse_share > 1.5 * r.time_share and r.sse_share > 0.3:
            out.append(f"error concentrates in the {AFTER_REVERSAL_S:g} s after each reversal: "
                       f"{_pct(r.sse_share)} of the squared error in {_pct(r.time_share)} of the time")
    if ev.excess_ratio > 1.1:
        worst = ev.worst_windows(3)
        out.append("worst windows: " + ", ".join(
            f"{w.t_start:.1f}–{w.t_end:.1f} s ({w.rmse:.3g} kgf, {w.regime})" for w in worst))
    if not ev.whiteness.white and ev.excess_ratio > 1.1:
        out.append("the residual is not white (autocorrelation beyond the ±1.96/√N band): "
                   "structure is left in it")
    if not ev.input_correlation.white and ev.excess_ratio > 1.1:
        out.append("the residual is correlated with the command: the model misses part of the "
                   "command's effect")
    return out


def reversal_transient(sims: Sequence[RecordSimulation], tau: float,
                       horizon_s: float = 0.6) -> str | None:
    """Ensemble of the residual after each rod reversal: the extra force the model misses in the
    new direction, and how fast it builds up ("error concentrates in the 0.2 s after ...")."""
    curves, dts = [], []
    for s in sims:
        dt = s.record.dt
        rev, _ = reversal_mask(s.q, dt)
        L = int(round(horizon_s / dt))
        for i in rev:
            w = s.win[i]
            if i + L >= len(s.r) or s.win[i + L] != w or i == 0:
                continue
            sgn = np.sign(s.q[i])
            # measured minus model, in the new direction of motion, from the reversal on
            curves.append(-(s.r[i:i + L] - s.r[i]) * sgn)
            dts.append(dt)
    if len(curves) < 3 or len(set(dts)) != 1:
        return None
    c = np.vstack(curves)
    dt = dts[0]
    mean = c.mean(axis=0)
    se = c.std(axis=0, ddof=1) / math.sqrt(len(c))
    phases = []
    for sign in (1, -1):
        k = int(np.argmax(sign * mean))
        if k > 0 and sign * mean[k] > max(4 * se[k], 1e-9):
            phases.append((k, float(mean[k])))
    if not phases:
        return None
    phases.sort()
    words = []
    for k, peak in phases:
        if peak > 0:
            words.append(f"moves up to {peak:.3g} kgf further in the new direction than the model "
                         f"predicts (at {k * dt:.2f} s)")
        else:
            words.append(f"lags up to {-peak:.3g} kgf behind the model (at {k * dt:.2f} s)")
    first, last = phases[0], phases[-1]
    if len(phases) == 2:
        meaning = ("a slow start then a faster take-off than the model: a transient after the "
                   "change of direction that the model lacks" if first[1] < 0 else
                   "a fast start then a slower ramp than the model: a transient after the change "
                   "of direction that the model lacks")
    elif first[1] > 0:
        meaning = "a faster take-off after a change of direction than the model has"
    else:
        meaning = "a slower take-off than the model: a lag, or more delay"
    return ("after each reversal the force " + ", then ".join(words)
            + f": the error concentrates in the first {last[0] * dt:.2f} s after the reversals "
            f"({meaning})")


def slope_observations(sims: Sequence[RecordSimulation]) -> list[str]:
    """Measured slope per % command on steady stretches: extend vs retract, and per |u| level."""
    num_e = num_r = den_e = den_r = 0.0
    lv_num: dict[int, float] = {}
    lv_den: dict[int, float] = {}
    q_all = np.concatenate([s.q for s in sims])
    groups, names = command_levels(np.abs(q_all))
    k0 = 0
    for s in sims:
        dt = s.record.dt
        _, after = reversal_mask(s.q, dt)
        dy = np.diff(s.y, append=s.y[-1])
        steady = ~after & (s.q != 0)
        steady[-1] = False
        g = groups[k0:k0 + len(s.q)]
        k0 += len(s.q)
        ext, ret = steady & (s.q > 0), steady & (s.q < 0)
        num_e += float(dy[ext].sum())
        den_e += float(s.q[ext].sum() * dt)
        num_r += float(dy[ret].sum())
        den_r += float(s.q[ret].sum() * dt)
        for lv in np.unique(g[steady]):
            sel = steady & (g == lv)
            lv_num[lv] = lv_num.get(lv, 0.0) + float((dy[sel] * np.sign(s.q[sel])).sum())
            lv_den[lv] = lv_den.get(lv, 0.0) + float(np.abs(s.q[sel]).sum() * dt)
    out = []
    if den_e > 0 and den_r < 0:
        ge, gr = num_e / den_e, num_r / den_r
        if ge > 0 and gr > 0 and abs(gr / ge - 1) >= 0.03:
            word = "lower" if gr < ge else "higher"
            out.append(f"retract slope is {abs(gr / ge - 1) * 100:.0f} % {word} than extend "
                       f"({gr:.4g} vs {ge:.4g} kgf/s per % command): an extend/retract asymmetry"
                       f" (or, at a single amplitude, the trend Δ)")
    gains = {lv: lv_num[lv] / lv_den[lv] for lv in lv_num if lv_den[lv] > 0 and lv >= 0}
    if len(gains) >= 2 and len(names) <= 6:
        lo_lv, hi_lv = min(gains), max(gains)
        glo, ghi = gains[lo_lv], gains[hi_lv]
        if ghi > 0 and abs(glo / ghi - 1) >= 0.03:
            word = "lower" if glo < ghi else "higher"
            hint = ("a dead zone (or a transient after reversals)" if glo < ghi
                    else "a flow limit (saturation) or a reversal boost that weighs more at small |u|")
            out.append(f"slope per % command is {abs(glo / ghi - 1) * 100:.0f} % {word} at "
                       f"{names[lo_lv]} than at {names[hi_lv]} ({glo:.4g} vs {ghi:.4g}): {hint}")
    return out


#: a change of the model's relative slope error of at least this much over the records is
#: worth saying
GAIN_CHANGE_MIN = 0.04


def drift_observation(sims: Sequence[RecordSimulation]) -> list[str]:
    """Does the model's slope error along the motion (steady stretches, away from reversals)
    change from the start of the records to their end? That is a gain that drifts during a run
    (oil warming up, supply pressure sagging): what ``gain_drift`` models, said in words
    because the records' clocks may not start with the runs.

    (The same comparison across |force| levels was tried for a specimen stiffness and dropped:
    between records |force| goes with the command level and the experiment, so a dead zone, a
    leak or a reversal boost made it speak of a stiffness; the ``stiffness`` candidate's fit
    tells it apart instead.)"""
    dr, dyh, _ = window_increments(sims)
    steady, sgn, into = [], [], []
    for s in sims:
        _, after = reversal_mask(s.q, s.record.dt)
        steady.append(~after & (s.q != 0) & (s.horizon > 0))
        sgn.append(np.sign(s.q))
        into.append((s.t - s.record.t[0]) / max(s.record.duration_s, s.record.dt))
    steady = np.concatenate(steady)
    along = (dr * np.concatenate(sgn))[steady]
    speed = np.abs(dyh)[steady]
    into = np.concatenate(into)[steady]

    def rel(sel: np.ndarray) -> float:
        v = float(speed[sel].sum())
        return float(along[sel].sum()) / v if v > 1e-9 and sel.sum() > 50 else math.nan

    first, last = rel(into < 0.25), rel(into >= 0.75)
    if not abs(first - last) >= GAIN_CHANGE_MIN:     # NaN (too little motion) says nothing
        return []
    return [f"the model's slope is {_signed_pct(first)} in the first quarter of the records and "
            f"{_signed_pct(last)} in the last: the gain {'grows' if last < first else 'falls'} "
            f"during a run (oil warming up, supply pressure changing): the `gain_drift` effect "
            f"models that; or let the stand warm up before measuring"]


def _signed_pct(x: float) -> str:
    """A relative slope error in words: '6 % too fast' / '4 % too slow'."""
    return f"{abs(x) * 100:.0f} % too {'fast' if x > 0 else 'slow'}"


def describe_unexplained(ev: Evaluation, floor: float, ratio: float,
                         fit: FitResult) -> Unexplained:
    """What the residual left by every candidate looks like: periodic or broadband, where."""
    f, amp, share = periodic_component(ev.sims, floor)
    corr = command_has_line(ev.sims, f) if f is not None else False
    closed = is_closed_loop(ev.sims)
    if f is not None and share >= 0.5:
        desc = (f"the residual is periodic at {f:.3g} Hz (amplitude ≈ {amp:.3g} kgf, "
                f"{_pct(share)} of the error above the noise)"
                + ((", and the command has it too: in closed loop the controller reacts to a "
                    "disturbance, so this alone does not tell cause from effect" if closed else
                    ", at a frequency where the command has a spectral line (the command's period "
                    "or a harmonic): a response to the command the model lacks") if corr else
                   ", unrelated to the command — like an external disturbance (a neighbouring "
                   "actuator, a structural resonance, pump ripple)"))
    else:
        where = max((r for r in ev.regimes if r.group in ("reversal", "direction")
                     and r.time_share >= 0.01),      # not a regime of a few samples
                    key=lambda r: r.sse_share / max(r.time_share, 1e-9), default=None)
        desc = "the residual is broadband (no dominant frequency)"
        if f is not None:
            desc += f"; its strongest periodic part is at {f:.3g} Hz ({_pct(share)} of the excess)"
        if where is not None:
            desc += (f"; it is largest in '{where.name}' ({_pct(where.sse_share)} of the squared "
                     f"error in {_pct(where.time_share)} of the time)")
    return Unexplained(dominant_frequency_hz=f, amplitude_kgf=amp, periodic_share=share,
                       rmse_over_floor=ratio, correlated_with_command=corr, description=desc)


def residual_is_noise(model: PlantModel, records: Sequence[Record], window_s: float,
                      floor: float) -> bool:
    """The residual of ``model`` is noise-like: not correlated with the command (prewhitened
    cross-correlation test, p ≥ :data:`NOISE_P`), not growing or shrinking along the free-run
    windows (:func:`horizon_growth` within :data:`NOISE_GROWTH_MAX`) and without a periodic component that
    carries half of its excess over ``floor``."""
    sims = simulate_records(model, records, window_s)
    dt = min(s.record.dt for s in sims)
    L = int(max(10, min(250, round(0.25 / dt))))
    if input_correlation_test(sims, L).p_value < NOISE_P:
        return False
    growth = horizon_growth(sims)
    if not 1 / NOISE_GROWTH_MAX <= growth <= NOISE_GROWTH_MAX:
        return False
    f, _, share = periodic_component(sims, floor)
    return f is None or share < 0.5


def horizon_growth(sims: Sequence[RecordSimulation]) -> float:
    """Mean square residual late in the windows (80-100 % of the horizon) over early on
    (20-40 %). A free-run from a measured start accumulates a model's error (a wrong gain grows
    linearly: ≈ 9×; a model fitted with re-estimated window starts can also leave its error
    early in the windows: 0.3× seen), while measurement noise only contributes n(t) − n(t₀),
    flat once past its correlation time (≈ 1×)."""
    early = late = 0.0
    n_early = n_late = 0
    for s in sims:
        h = s.horizon / s.window
        r2 = s.r ** 2
        e = (h >= 0.2) & (h < 0.4)
        l8 = h >= 0.8
        early += float(r2[e].sum())
        late += float(r2[l8].sum())
        n_early += int(e.sum())
        n_late += int(l8.sum())
    if not n_early or not n_late or early <= 0:
        return 1.0
    return (late / n_late) / (early / n_early)


def command_has_line(sims: Sequence[RecordSimulation], f: float) -> bool:
    """Whether the command has a spectral line at ``f`` (its fundamental or a harmonic): its
    power in the bin of ``f`` is ten times its median power around it."""
    from scipy.signal import welch
    dt = sims[0].record.dt
    seg = 1 << int(math.ceil(math.log2(max(16, round(8.0 / dt)))))
    u = np.concatenate([s.u for s in sims if s.record.dt == dt])
    fr, p = welch(u - u.mean(), fs=1 / dt, nperseg=min(seg, len(u)))
    k = int(np.argmin(np.abs(fr - f)))
    around = p[max(1, k - 20):k + 21]
    return bool(p[max(0, k - 1):k + 2].max() > 10 * np.median(around))


def periodic_component(sims: Sequence[RecordSimulation], floor: float,
                       max_samples: int = 400_000) -> tuple[float | None, float | None, float]:
    """Dominant frequency of the residual (window means removed): Welch spectrum peak, refined
    by fitting ``a·sin 2πft + b·cos 2πft`` (with the window means) on a fine frequency grid.
    Returns (frequency Hz, amplitude kgf, share of the excess squared error it explains)."""
    from scipy.signal import welch
    e = demeaned_residual(sims)
    dt = sims[0].record.dt
    psd_sum, freqs = None, None
    seg = 1 << int(math.ceil(math.log2(max(16, round(8.0 / dt)))))
    for s, x in zip(sims, e):
        if s.record.dt != dt or len(x) < 16:
            continue
        fr, p = welch(x, fs=1 / dt, nperseg=min(seg, len(x)), detrend=False)
        if freqs is None:
            freqs, psd_sum = fr, np.zeros_like(p)
        if len(fr) == len(freqs):
            psd_sum += p
    if freqs is None:
        return None, None, 0.0
    wmin = 1.0 / (sims[0].window * dt)  # below the window rate the demeaning removes power
    band = (freqs >= wmin) & (freqs < 0.45 / dt)
    if not band.any():
        return None, None, 0.0
    k = int(np.flatnonzero(band)[np.argmax(psd_sum[band])])
    df = freqs[1] - freqs[0]
    grid = np.linspace(max(wmin, freqs[k] - 1.5 * df), freqs[k] + 1.5 * df, 61)
    # fit on a bounded number of samples
    # fit on a bounded number of samples; each record with its own amplitude and phase (a
    # disturbance is not synchronous with the start of separate runs)
    pieces = []
    budget = max_samples
    for s, x in zip(sims, e):
        m = min(len(x), budget)
        if m <= 0:
            break
        wl = s.win[:m]
        pieces.append((s.t[:m], x[:m], wl, np.bincount(wl)))
        budget -= m

    best = (0.0, None, None)
    for f in grid:
        expl = weight = amp2 = 0.0
        for t, x, wl, cnt in pieces:
            S = np.sin(2 * np.pi * f * t)
            C = np.cos(2 * np.pi * f * t)
            S -= (np.bincount(wl, weights=S) / cnt)[wl]
            C -= (np.bincount(wl, weights=C) / cnt)[wl]
            A = np.column_stack([S, C])
            coef, *_ = np.linalg.lstsq(A, x, rcond=None)
            part = float(np.sum((A @ coef) ** 2))
            expl += part
            amp2 += float(coef @ coef) * len(x)
            weight += len(x)
        if expl > best[0]:
            best = (expl, float(f), math.sqrt(amp2 / weight))
    expl, f, amp = best
    x = np.concatenate([p[1] for p in pieces])
    excess = float(x @ x) - floor ** 2 * len(x)
    share = min(1.0, expl / excess) if excess > 0 else 0.0
    return f, amp, share


# ------------------------------------------------------------------------------------------
# what the data cannot tell apart
# ------------------------------------------------------------------------------------------
@dataclass
class Excitation:
    """What the data contain, as far as separating effects is concerned."""

    levels: list[float]           #: distinct nonzero |u| levels (empty if continuous)
    continuous: bool              #: the command varies continuously (feedback with smooth r)
    has_steps: bool               #: the command jumps (meander, relay)
    has_zero_hold: bool           #: the command rests at 0 for ≥ 0.5 s somewhere
    single_frequency: bool        #: smooth command dominated by one frequency
    force_span_kgf: float
    both_force_signs: bool

    @classmethod
    def of(cls, records: Sequence[Record]) -> "Excitation":
        u = np.concatenate([r.u for r in records])
        y = np.concatenate([r.y for r in records])
        nz = np.abs(u[u != 0])
        levels = np.unique(np.round(nz, 2)) if len(nz) else np.array([])
        continuous = len(levels) > 6
        span = float(np.ptp(u)) or 1.0
        steps = any(np.any(np.abs(np.diff(r.u)) > 0.25 * span) for r in records)
        zero = False
        for r in records:
            z = np.concatenate([[0], (r.u == 0).astype(int), [0]])
            edges = np.flatnonzero(np.diff(z))
            runs = edges[1::2] - edges[::2]
            if len(runs) and runs.max() * r.dt >= 0.5:
                zero = True
        single = False
        if continuous and not steps:
            spec = np.abs(np.fft.rfft(u - u.mean())) ** 2
            k = int(np.argmax(spec[1:])) + 1
            single = spec[max(1, k - 3):k + 4].sum() > 0.8 * spec[1:].sum()
        return cls([float(v) for v in levels] if not continuous else [], continuous, steps, zero,
                   single, float(np.ptp(y)), bool(y.min() < -0.1 * np.ptp(y) and y.max() > 0.1 * np.ptp(y)))


def _ambiguities(records: Sequence[Record], base_fit: FitResult, cands: Sequence[Candidate],
                 best: Candidate | None) -> list[Ambiguity]:
    ex = Excitation.of(records)
    out: list[Ambiguity] = []
    names = {c.effect for c in cands}
    single = len(ex.levels) == 1 and not ex.continuous
    if single:
        lv = f"{ex.levels[0]:g} %"
        like_gain = {
            "deadzone": "a dead zone d only lowers the slope to g·(|u| − d)",
            "flow_curve": "a bent flow curve only changes the slope",
            "backlash": "a play of width w lowers the slope to g·(|u| − w/2)",
            "saturation": "a flow limit below it caps the slope",
        }
        for name, how in like_gain.items():
            if name in names:
                out.append(Ambiguity([name, "gain"],
                                     f"at a single command amplitude (|u| = {lv}) {how}: it looks "
                                     f"exactly like another gain g.",
                                     separating_experiment(name, "gain")))
        if "stiction" in names:
            out.append(Ambiguity(["stiction", "delay"],
                                 f"at a single command amplitude (|u| = {lv}) a rod that sticks "
                                 f"after each reversal holds the force the same w/(g·|u|) every time: "
                                 f"it looks like more delay (the fitted τ = "
                                 f"{base_fit.model.tau * 1e3:.1f} ms may include such a hold).",
                                 separating_experiment("stiction", "delay")))
        if "asymmetry" in names and not ex.has_zero_hold:
            d = base_fit.model.delta
            ramp = base_fit.model.g * ex.levels[0]
            hint = (f" The fitted trend Δ = {d:.3g} kgf/s is {abs(d) / ramp * 100:.1f} % of the "
                    f"ramp rate g·|u|; if the valve's null offset is known to be small, read it as "
                    f"an asymmetry a ≈ {d / ramp:+.3f} (retract {'slower' if d > 0 else 'faster'}).") \
                if ramp > 0 else ""
            out.append(Ambiguity(["asymmetry", "trend"],
                                 f"with the command always ±{lv}, a gain that differs between extend "
                                 f"and retract adds the same force rate as the trend Δ.{hint}",
                                 separating_experiment("asymmetry", "trend")))
        if {"leakage", "load_pressure"} <= names or (best and best.effect in ("leakage", "load_pressure")):
            out.append(Ambiguity(["leakage", "load_pressure"],
                                 "at a single command amplitude the orifice law's slow-down "
                                 "(∝ sign(u)·y) acts like a leak toward zero force.",
                                 separating_experiment("leakage", "load_pressure")))
    if ex.continuous and not ex.has_steps and "lag" in names and (best is None or best.effect != "lag"):
        what = "a smooth single-frequency signal" if ex.single_frequency else "smooth, without steps"
        out.append(Ambiguity(["lag", "delay"],
                             f"the command is {what}: a valve lag T shifts a slow command like "
                             f"extra delay, so mainly τ + T is determined (fitted τ = "
                             f"{base_fit.model.tau * 1e3:.1f} ms may include a lag).",
                             separating_experiment("lag", "delay")))
    if best is not None and best.effect in ("lag", "sensor_lag"):
        other = "sensor_lag" if best.effect == "lag" else "lag"
        alt = next((c for c in cands if c.effect == other), None)
        if alt is None or alt.objective_rmse <= AMBIGUITY_RATIO * best.objective_rmse:
            out.append(Ambiguity(
                [best.effect, other],
                "a first-order filter in the dynamometer acts on the measured force exactly "
                "like a valve lag on an integrating plant (the two commute), in open and closed "
                "loop alike, unless a valve nonlinearity sits between them: these data cannot "
                "tell where the lag is.", separating_experiment("lag", "sensor_lag")))
    if best is not None and best.effect == "supply":
        T = best.params.get("supply.time_constant", math.nan)
        out.append(Ambiguity(
            ["supply", "flow_curve"],
            f"at a held command the supply's sag settles at k·|u| and the gain at "
            f"√(1 − k·|u|/100), a degressive flow characteristic of its own: only the sag's "
            f"build-up over T (fitted {T:.3g} s) after |u| changes tells a sagging supply from a "
            f"bent flow curve (or a dead zone with one).",
            separating_experiment("supply", "flow_curve")))
    if "saturation" in names and best is None:
        top = max((abs(r.u).max() for r in records), default=0.0)
        if top < 100.0:
            out.append(Ambiguity(["saturation"],
                                 f"the command never exceeds {top:.3g} %: a flow limit above that "
                                 f"cannot show in these data.",
                                 "runs at larger command amplitudes"))
    # candidates the data do not separate (comparable error reductions)
    if best is not None:
        for c in cands:
            if c is best or not c.earns:
                continue
            if c.objective_rmse <= AMBIGUITY_RATIO * best.objective_rmse:
                pair = [best.effect, c.effect]
                if any(set(a.effects) == set(pair) for a in out):
                    continue
                out.append(Ambiguity(pair, f"+{c.effect} leaves about as little error as "
                                           f"+{best.effect} ({c.objective_rmse:.3g} vs "
                                           f"{best.objective_rmse:.3g} kgf).",
                                     separating_experiment(*pair)))
        # parameters of the best candidate the data do not determine
        if best.fit is not None:
            for name in best.fit.non_identifiable():
                out.append(Ambiguity([name], "this parameter is not determined by these data "
                                             "(it trades off against another one).",
                                     "the meander at several amplitudes and periods"))
    return out
