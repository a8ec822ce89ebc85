r"""Build the model up one effect at a time, as a user would: diagnose, add the effect that
lowers the error most, diagnose again, until the model is within the noise.

Real stands rarely miss just one effect. With several, no single catalogue effect may remove
most of the error above the noise, so :func:`.verdict.diagnose` alone says
*unexplained* and lists the effects that would remove part of it. ``stepwise`` (forward
selection with a backward check, like stepwise regression):

1. diagnoses the current model (start: the paper's base model);
2. adds the best candidate that *earns its parameters*, or, when none does, the best one that
   *helps* (lowers the error by at least :data:`~.significance.MIN_IMPROVEMENT`,
   significantly and consistently over the windows: part of the missing behaviour);
3. stops when the diagnosis says *adequate*, when a g or Δ of its own per record explains the
   rest (*varies between records*: the stand changed between the runs), when nothing helps, or
   after ``max_effects``;
4. checks every added effect again with the others in place (an effect picked early can become
   redundant once a later one explains the same error): it is refitted without it, and dropped
   if it no longer helps. What stays is reported with how much worse the error would be
   without it.

The steps keep their whole diagnoses (observations, ambiguities, warnings of each).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

from plant import PlantModel

from ..identification.fit import REFIT_TOL, FitOptions, FitResult, fit_model
from ..identification.windows import WINDOW_S, errors, pieces_from_records, residual
from ..parallel import one_blas_thread, run_each, workers_for
from ..records.record import Record
from .candidates import Candidate, judge
from .verdict import Diagnosis, diagnose

#: effects added at most (each step is one diagnosis: all candidates fitted)
from ..defaults import MAX_EFFECTS  # noqa: E402  (re-exported)


@dataclass
class Step:
    """One diagnosis of the build-up and what it led to."""

    model: str                    #: the model diagnosed
    rmse: float                   #: its windowed RMSE from the measured starts, kgf
    over_floor: float             #: its objective error over the noise floor
    diagnosis: Diagnosis = field(repr=False)
    added: str | None = None      #: the effect added after this diagnosis
    why: str = ""                 #: why it was added, or why the build-up stopped here

    def to_dict(self) -> dict:
        return {"model": self.model, "rmse": self.rmse, "over_floor": self.over_floor,
                "added": self.added, "why": self.why, "diagnosis": self.diagnosis.to_dict()}


@dataclass
class Needed:
    """An effect of the final model, checked with the others in place."""

    effect: str
    kept: bool
    error_without: float          #: objective RMSE of the final model refitted without it, kgf
    factor: float                 #: error without it / error with it (objective)

    def text(self) -> str:
        if self.kept:
            return (f"{self.effect}: without it the error is {self.factor:.2f}× higher "
                    f"({self.error_without:.3g} kgf)")
        return (f"{self.effect}: dropped — once the others are in, the model without it leaves "
                f"{self.error_without:.3g} kgf, within what fitting noise explains")


@dataclass
class Stepwise:
    steps: list[Step]
    model: PlantModel             #: the final model (after the backward check), fitted
    fit: FitResult = field(repr=False)
    #: "adequate" | "varies_between_records" | "unexplained" | "max_effects"
    verdict: str
    needed: list[Needed]
    summary: str

    @property
    def path(self) -> list[str]:
        return [s.model for s in self.steps]

    @property
    def last(self) -> Diagnosis:
        return self.steps[-1].diagnosis

    def to_dict(self) -> dict:
        return {"verdict": self.verdict, "model": self.model.spec, "params": self.model.params(),
                "intervals": {k: e.to_dict() for k, e in self.fit.estimates.items()},
                "summary": self.summary, "needed": [vars(n) for n in self.needed],
                "steps": [s.to_dict() for s in self.steps]}


def pick(d: Diagnosis) -> tuple[Candidate | None, str]:
    """The candidate to add after diagnosis ``d``, and why (or why none). Its equivalents (laws
    with more parameters that leave as little error: ties go to the simpler law) are named."""
    if d.best_candidate is not None:
        c = d.best_candidate
        return c, (f"earns its parameters: lowers the error by {100 * c.rmse_reduction:.0f} %, "
                   f"{100 * max(c.excess_share, 0):.0f} % of the excess over the noise"
                   + equivalents_text(c))
    if d.verdict == "adequate":
        return None, "adequate: the error is within the noise"
    if d.verdict == "varies_between_records":
        return None, (f"a {d.between.varies} of its own per record explains the error better "
                      f"than any effect tried: the stand changed between the runs")
    helping = [c for c in d.candidates if c.helps]
    if not helping:
        return None, "no effect tried lowers the error significantly"
    c = helping[0]
    return c, (f"part of the missing behaviour: lowers the error by {100 * c.rmse_reduction:.0f} % "
               f"({100 * max(c.excess_share, 0):.0f} % of the excess), significant and "
               f"consistent over the windows" + equivalents_text(c))


def equivalents_text(c: Candidate) -> str:
    """``c``'s equivalents in words (empty if it has none)."""
    if not c.equivalents:
        return ""
    return (f"; {', '.join('+' + e for e in c.equivalents)} leave{'s' if len(c.equivalents) == 1 else ''}"
            f" as little error with more parameters (equivalent, ranked after it)")


#: evaluations of the model a refit without one effect takes, about (from fitted values)
REFIT_EVALS = 60

#: a runner-up that lowers the error at least this fraction as much as the effect picked on a
#: "part of the missing behaviour" step is tried in its place when the build-up does not end
#: adequate (greedy selection can take a look-alike first, then stall)
ALTERNATIVE_RATIO = 0.8


@one_blas_thread
def stepwise(records: Sequence[Record], model: PlantModel | str = "base",
             window_s: float = WINDOW_S, max_effects: int = MAX_EFFECTS,
             effects: Sequence[str] | None = None,
             progress: Callable[[str], None] | None = None, jobs: int | None = None,
             carried: Sequence[str] = ()) -> Stepwise:
    """Add effects to ``model`` one at a time until it explains ``records`` (module docstring).
    ``carried``: effects of ``model`` an earlier build-up added (a rig's round before), checked
    again at the end with the ones this one adds.
    If the build-up does not end adequate and one of its partial picks had a close runner-up,
    the build-up is run once more from there with the runner-up, and the better end is kept.
    ``jobs``: worker processes for each diagnosis (see :func:`.verdict.diagnose`)."""
    say = progress or (lambda msg: None)
    start = PlantModel.from_spec(model) if isinstance(model, str) else model
    up = _forward(records, start, [], [], window_s, max_effects, effects, say, jobs)
    tried = ""
    if up.verdict != "adequate":
        branch = _alternative(up.steps)
        if branch is not None:
            i, alt = branch.step, branch.runner_up
            chosen = up.steps[i].added
            say(f"trying +{alt.effect} instead of +{chosen} at step {i + 1}")
            first = replace(up.steps[i], added=alt.effect,
                            why=f"runner-up to +{chosen}, tried in its place: {100 * alt.rmse_reduction:.0f} % "
                                f"lower error")
            other = _forward(records, alt.fit.model, up.steps[:i] + [first],
                             up.added[:i] + [alt.effect], window_s, max_effects, effects, say, jobs)
            better = (other.verdict == "adequate"
                      or other.steps[-1].over_floor < up.steps[-1].over_floor)
            tried = (f"; +{alt.effect} tried in place of +{chosen} at step {i + 1}: "
                     + ("kept, it ends closer to the noise" if better else "dropped, it ends no closer"))
            if better:
                up = other
    steps, added, verdict = up.steps, up.added, up.verdict
    last = steps[-1].diagnosis
    final_fit = last.base_fit
    needed: list[Needed] = []
    # with several effects, or with one when the build-up did not end adequate (what was added
    # on the way to "unexplained" must still earn its place, or it is not kept)
    checked = [e for e in carried if e not in added] + list(added)
    if len(checked) >= 2 or (checked and verdict != "adequate"):
        say("checking each added effect with the others in place")
        final_fit, needed = backward_check(records, final_fit, checked, last.objective_floor,
                                           window_s, jobs)
    summary = _summary(steps, verdict, final_fit, needed, last) + tried
    return Stepwise(steps=steps, model=final_fit.model, fit=final_fit, verdict=verdict,
                    needed=needed, summary=summary)


@dataclass
class BuildUp:
    """A forward build-up: its diagnoses, the effects it added, and how it ended."""

    steps: list[Step]
    added: list[str]
    #: "adequate" | "varies_between_records" | "unexplained" | "max_effects"
    verdict: str


@dataclass
class Branch:
    """A step whose partial pick had a close runner-up, to be tried in its place."""

    step: int                     #: the step's index
    runner_up: Candidate


@dataclass
class Check:
    """An added effect checked with the others in place: the model refitted without it."""

    effect: str
    helps: bool                   #: it still helps, judged as a candidate added to the rest
    factor: float                 #: objective error without it / with it
    reduced: FitResult            #: the model refitted without it
    error_without: float          #: objective RMSE without it, kgf


def _forward(records, current: PlantModel, steps: list[Step], added: list[str], window_s: float,
             max_effects: int, effects, say, jobs: int | None = None) -> BuildUp:
    """The build-up from ``current`` (reached by ``steps``, having ``added``) to its end."""
    steps, added = list(steps), list(added)
    verdict = "max_effects"
    while True:
        say(f"diagnosing {current.spec}")
        todo = None if effects is None else [e for e in effects if current.effect(e) is None]
        # after the first step the model is a candidate fitted to these records: polished
        d = diagnose(records, current, window_s=window_s, effects=todo, progress=say, jobs=jobs,
                     fitted=bool(steps))
        floor = d.objective_floor
        step = Step(model=d.base_fit.model.spec, rmse=d.base_eval.rmse,
                    over_floor=d.base_fit.objective_rmse / floor if floor > 0 else math.inf,
                    diagnosis=d)
        steps.append(step)
        c, why = pick(d)
        if c is not None and len(added) >= max_effects:
            step.why = f"stopped after {max_effects} added effects (--max-effects); next: {c.effect}"
            break
        step.why = why
        if c is None:
            verdict = d.verdict if d.verdict in ("adequate", "varies_between_records") \
                else "unexplained"
            break
        step.added = c.effect
        added.append(c.effect)
        current = c.fit.model
    return BuildUp(steps, added, verdict)


def _alternative(steps: Sequence[Step]) -> Branch | None:
    """The first step that added a partial explanation (none earned) with a runner-up that
    helps nearly as much."""
    for i, st in enumerate(steps):
        d = st.diagnosis
        if st.added is None or d.best_candidate is not None:
            continue
        helping = [c for c in d.candidates if c.helps]
        if len(helping) >= 2 and helping[0].effect == st.added and \
                helping[1].improvement >= ALTERNATIVE_RATIO * helping[0].improvement:
            return Branch(i, helping[1])
    return None


def without(model: PlantModel, effect: str) -> PlantModel:
    """``model`` minus one effect, the other values kept (the start of its refit)."""
    spec = "+".join(["base"] + [e.name for e in model.effects if e.name != effect])
    values = {k: v for k, v in model.params().items() if not k.startswith(effect + ".")}
    return PlantModel.from_spec(spec, values)


def _refit_without(shared: tuple, name: str) -> FitResult:
    """The model refitted without one of its effects (a task for :func:`run_each`)."""
    pieces, model = shared
    return fit_model(pieces, without(model, name),
                     options=FitOptions.refit(tol=REFIT_TOL, covariance=False))


def backward_check(records: Sequence[Record], full: FitResult, added: Sequence[str],
                   floor: float, window_s: float,
                   jobs: int | None = None) -> tuple[FitResult, list[Needed]]:
    """Refit the model without each added effect in turn; drop the one that helps least if it
    no longer helps, and repeat. Returns the final fit and the verdict on every added effect.
    The refits are independent: in worker processes as :func:`.verdict.diagnose` runs its
    candidates (``jobs``)."""
    pieces = pieces_from_records(records, window_s)
    n = sum(p.n_eval for p in pieces)
    dropped: list[Needed] = []
    while True:
        w_full, rmse_full = errors(full.model, pieces)
        obj_full = math.sqrt(w_full.sum() / n)
        checks = []
        names = [a for a in added if full.model.effect(a) is not None]
        t0 = time.perf_counter()
        residual(full.model, pieces)
        workers = workers_for(len(names), (time.perf_counter() - t0) * REFIT_EVALS * len(names), jobs)
        refits = dict(run_each(_refit_without, names, (pieces, full.model), workers))
        for name in names:
            reduced = refits[name]
            w_red, rmse_red = errors(reduced.model, pieces)
            obj_red = math.sqrt(w_red.sum() / n)
            # judged as a candidate added to the reduced model, like in the diagnosis
            c = judge(name, full, w_full, rmse_full, w_red, rmse_red, floor, n, "final")
            checks.append(Check(name, c.helps, obj_red / obj_full if obj_full > 0 else math.inf,
                                reduced, obj_red))
        weakest = min(checks, key=lambda x: (x.helps, x.factor), default=None)
        if weakest is None or weakest.helps:
            kept = [Needed(x.effect, True, x.error_without, x.factor) for x in checks]
            return full, kept + dropped
        dropped.append(Needed(weakest.effect, False, weakest.error_without, weakest.factor))
        full = weakest.reduced


def _summary(steps: list[Step], verdict: str, fit: FitResult, needed: list[Needed],
             last: Diagnosis) -> str:
    path = " → ".join([steps[0].model] + [f"+{s.added}" for s in steps if s.added])
    first, end = steps[0], steps[-1]
    change = (f"error {first.rmse:.3g} → {end.rmse:.3g} kgf ({first.over_floor:.2f}× → "
              f"{end.over_floor:.2f}× the noise floor)")
    dropped = [n.effect for n in needed if not n.kept]
    tail = f"; dropped again: {', '.join(dropped)}" if dropped else ""
    if verdict == "adequate":
        head = f"adequate with {fit.model.spec}"
    elif verdict == "varies_between_records":
        head = f"{fit.model.spec} explains each record, not all of them with one g and Δ ({last.between.text})"
    elif verdict == "unexplained":
        head = (f"{fit.model.spec} is the closest the effects tried get; the rest is unexplained"
                + (f" ({last.unexplained.description})" if last.unexplained else ""))
    else:
        head = f"stopped at {fit.model.spec} (effect limit); the error is still above the noise"
    return f"{head}: {path}, {change}{tail}"
