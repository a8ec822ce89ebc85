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

After each effect added, the earlier effects it looks like are revised (:mod:`.revision`): each
is tried in place of its look-alikes and left out, the others refitted, so a look-alike taken
early (an overdamped resonance for a sensor lag) can be undone. Stuck above the noise, every
added effect is revised and then every candidate fitted afresh before the build-up ends
*unexplained*; at the end every added effect is tried in place of its look-alikes once more.
The rules: docs/decisions.md, "The stepwise diagnosis that can undo its choices".

The steps keep their whole diagnoses (observations, ambiguities, warnings of each).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

from plant import PlantModel
from plant.catalogue import look_alikes

from ..identification.fit import REFIT_TOL, FitOptions, FitResult, fit_model
from ..identification.windows import WINDOW_S, errors, pieces_from_records, residual
from ..parallel import one_blas_thread, run_each, workers_for
from ..records.record import Record
from .ambiguity import Ambiguity
from .candidates import Candidate, judge
from .revision import Revision, revise
from .verdict import Diagnosis, Windows, diagnose

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
    #: the earlier effects tried in place of their look-alikes and left out once it was added
    #: (:func:`.revision.revise`; None: nothing to revise)
    revision: Revision | None = field(default=None, repr=False)

    @property
    def line(self) -> str:
        """What the step led to, in words (the effect added and why, the revision kept)."""
        text = f"+{self.added}: {self.why}" if self.added else self.why
        if self.revision is not None and self.revision.kept:
            text += f"; then {self.revision.text}"
        return text

    def to_dict(self) -> dict:
        return {"model": self.model, "rmse": self.rmse, "over_floor": self.over_floor,
                "added": self.added, "why": self.why,
                "revised": [a.to_dict() for a in self.revision.kept] if self.revision else [],
                "diagnosis": self.diagnosis.to_dict()}


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
    #: the end's revision: every added effect tried in place of its look-alikes
    revision: Revision | None = field(default=None, repr=False)
    #: what these data cannot tell apart about the final model (:func:`said_apart`)
    ambiguities: list[Ambiguity] = field(default_factory=list)
    #: unexplained: the catalogue effects that came closest and were rejected, closest first
    closest: list[str] = field(default_factory=list)

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
                "revised": [a.to_dict() for a in self.revision.kept] if self.revision else [],
                "ambiguities": [{**vars(a), "text": a.text()} for a in self.ambiguities],
                "closest": self.closest, "steps": [s.to_dict() for s in self.steps]}


def pick(d: Diagnosis) -> tuple[Candidate | None, str]:
    """The candidate to add after diagnosis ``d``, and why (or why none). Its equivalents (laws
    with more parameters that leave as little error: ties go to the simpler law) are named, and
    what it shows that its look-alikes tried beside it cannot (a resonance's ringing)."""
    if d.best_candidate is not None:
        c = d.best_candidate
        return c, (f"earns its parameters: lowers the error by {100 * c.rmse_reduction:.0f} %, "
                   f"{100 * max(c.excess_share, 0):.0f} % of the excess over the noise"
                   + equivalents_text(c) + preferred_text(c, d))
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
               f"consistent over the windows" + equivalents_text(c) + preferred_text(c, d))


def equivalents_text(c: Candidate) -> str:
    """``c``'s equivalents in words (empty if it has none)."""
    if not c.equivalents:
        return ""
    return (f"; {', '.join('+' + e for e in c.equivalents)} leave{'s' if len(c.equivalents) == 1 else ''}"
            f" as little error with more parameters (equivalent, ranked after it)")


def preferred_text(c: Candidate, d: Diagnosis) -> str:
    """Why ``c`` was preferred over its look-alikes tried beside it, when its values show
    evidence of its own (:meth:`plant.Effect.own_evidence`: "it rings ..."); empty otherwise."""
    if not c.evidence or not c.own:
        return ""
    alike = set(look_alikes(c.effect))
    others = [o for o in d.candidates if o.effect in alike]
    if not others:
        return f"; {c.evidence}"
    return (f"; preferred over {', '.join(f'+{o.effect} ({o.objective_rmse:.3g} kgf)' for o in others)}"
            f" ({c.objective_rmse:.3g} kgf): {c.evidence}")


#: evaluations of the model a refit without one effect takes, about (from fitted values)
REFIT_EVALS = 60

#: a runner-up that lowers the error at least this fraction as much as the effect picked on a
#: "part of the missing behaviour" step is tried in its place when the build-up does not end
#: adequate (greedy selection can take a look-alike first, then stall)
ALTERNATIVE_RATIO = 0.8
#: screening windows of a diagnosis, at most (:func:`.verdict.diagnose`'s default)
MAX_SCREEN_WINDOWS = 150


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
    own = [e.name for e in start.effects if e.name not in carried]
    windows = Windows.of(records, window_s, MAX_SCREEN_WINDOWS)
    run = _BuildUpRun(records, own, window_s, max_effects, effects, say, jobs, windows)
    up = run.forward(start, [])
    tried = ""
    if up.verdict != "adequate":
        branch = _alternative(up.steps)
        if branch is not None:
            i, alt = branch.step, branch.runner_up
            chosen = up.steps[i].added
            say(f"trying +{alt.effect} instead of +{chosen} at step {i + 1}")
            first = replace(up.steps[i], added=alt.effect, revision=None,
                            why=f"runner-up to +{chosen}, tried in its place: {100 * alt.rmse_reduction:.0f} % "
                                f"lower error")
            other = run.forward(alt.fit.model, up.steps[:i] + [first])
            better = (other.verdict == "adequate"
                      or other.steps[-1].over_floor < up.steps[-1].over_floor)
            tried = (f"; +{alt.effect} tried in place of +{chosen} at step {i + 1}: "
                     + ("kept, it ends closer to the noise" if better else "dropped, it ends no closer"))
            if better:
                up = other
    # the end: every added effect tried in place of its look-alikes (left out, each is refitted
    # by the backward check below); a build-up stuck above the noise did it already
    revision = None
    final_fit = up.steps[-1].diagnosis.base_fit
    checked = run.added(final_fit.model)
    if checked and up.verdict != "unexplained":
        say("trying each added effect in place of its look-alikes")
        last = up.steps[-1].diagnosis
        revision = revise(final_fit, checked, windows.full, windows.screen, last.objective_floor,
                          jobs, say, drops=False, tried=run.tried,
                          idle=[c.effect for c in last.candidates if not c.helps])
        final_fit = revision.fit
    steps, verdict = up.steps, up.verdict
    last = steps[-1].diagnosis
    needed: list[Needed] = []
    # with several effects, or with one when the build-up did not end adequate (what was added
    # on the way to "unexplained" must still earn its place, or it is not kept)
    checked = run.added(final_fit.model)
    if len(checked) >= 2 or (checked and verdict != "adequate"):
        say("checking each added effect with the others in place")
        final_fit, needed = backward_check(records, final_fit, checked, last.objective_floor,
                                           window_s, jobs)
    result = Stepwise(steps=steps, model=final_fit.model, fit=final_fit, verdict=verdict,
                      needed=needed, summary="", revision=revision)
    result.ambiguities = said_apart(result)
    if verdict == "unexplained":
        result.closest = closest_rejected(result)
    result.summary = _summary(result) + tried
    return result


@dataclass
class BuildUp:
    """A forward build-up: its diagnoses, and how it ended."""

    steps: list[Step]
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


@dataclass
class _BuildUpRun:
    """What every build-up of one ``stepwise`` call shares."""

    records: Sequence[Record]
    own: list[str]                #: the starting model's effects (the user's, never revised)
    window_s: float
    max_effects: int
    effects: Sequence[str] | None
    say: Callable[[str], None]
    jobs: int | None
    windows: Windows
    #: the revisions' changes tried so far (:func:`.revision.revise`)
    tried: set = field(default_factory=set)
    #: the models a build-up was stuck at and tried to get past (revised, fitted afresh)
    unstuck: set = field(default_factory=set)

    def added(self, model: PlantModel) -> list[str]:
        """The effects of ``model`` a build-up added (or carried from an earlier one)."""
        return [e.name for e in model.effects if e.name not in self.own]

    def forward(self, current: PlantModel, steps: list[Step]) -> BuildUp:
        """The build-up from ``current`` (reached by ``steps``) to its end. After each effect
        added, the effects added before it that it looks like are revised
        (:func:`.revision.revise`): tried in place of their look-alikes and left out, with it
        in place. Stuck above the noise (no candidate helps), every added effect is revised so,
        and if that changes nothing, every candidate is fitted afresh (once per model)."""
        steps = list(steps)
        verdict = "max_effects"
        while True:
            self.say(f"diagnosing {current.spec}")
            todo = None if self.effects is None else [e for e in self.effects
                                                      if current.effect(e) is None]
            # after the first step the model is a candidate fitted to these records: polished
            d = diagnose(self.records, current, window_s=self.window_s, effects=todo,
                         progress=self.say, jobs=self.jobs, fitted=bool(steps))
            floor = d.objective_floor
            step = Step(model=d.base_fit.model.spec, rmse=d.base_eval.rmse,
                        over_floor=d.base_fit.objective_rmse / floor if floor > 0 else math.inf,
                        diagnosis=d)
            steps.append(step)
            c, why = pick(d)
            afresh = False
            stuck = c is None and d.verdict == "unexplained" and self.added(current)
            if stuck and current.spec not in self.unstuck:
                self.unstuck.add(current.spec)
                # stuck above the noise: first every added effect tried in place of its
                # look-alikes and left out; if nothing changes, every candidate fitted afresh
                # (the effects in may have settled where a missing one should be: a boost that
                # took up a resonance's ringing with a longer delay)
                self.say("stuck: trying each added effect in place of its look-alikes")
                step.why = why
                step.revision = revise(d.base_fit, self.added(current), self.windows.full,
                                       self.windows.screen, floor, self.jobs, self.say,
                                       tried=self.tried)
                if step.revision.kept:
                    current = step.revision.fit.model
                    continue
                self.say(f"fitting every candidate to {current.spec} afresh")
                again = diagnose(self.records, d.base_fit.model, window_s=self.window_s,
                                 effects=todo, progress=self.say, jobs=self.jobs, fitted=True,
                                 afresh=True)
                c, why = pick(again)
                if c is not None:
                    step.diagnosis, why = again, f"fitted afresh (every parameter searched): {why}"
                    afresh = True
            if c is not None and len(self.added(current)) >= self.max_effects:
                step.why = (f"stopped after {self.max_effects} added effects (--max-effects); "
                            f"next: {c.effect}")
                break
            step.why = why
            if c is None:
                verdict = d.verdict if d.verdict in ("adequate", "varies_between_records") \
                    else "unexplained"
                break
            step.added = c.effect
            # the diagnosis weighed +c against the other candidates and against the model
            # without it: the revisions need not fit those changes again
            have = frozenset(e.name for e in c.fit.model.effects)
            self.tried.update((have, c.effect, x.effect) for x in step.diagnosis.candidates
                              if x is not c)
            self.tried.add((have, c.effect, None))
            current = c.fit.model
            # the earlier effects whose role the new one may have taken: its look-alikes (all
            # of them after a candidate fitted afresh: the others may have settled for it)
            earlier = [e for e in self.added(current) if e != c.effect
                       and (afresh or c.effect in look_alikes(e))]
            if earlier:
                self.say(f"revising {', '.join('+' + e for e in earlier)} with +{c.effect} in place")
                step.revision = revise(c.fit, earlier, self.windows.full, self.windows.screen,
                                       floor, self.jobs, self.say, tried=self.tried)
                current = step.revision.fit.model
        return BuildUp(steps, verdict)


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


def said_apart(r: Stepwise) -> list[Ambiguity]:
    """What these data cannot tell apart about the final model: the last step's ambiguities,
    then those of the earlier steps that name an effect of the final model (the step that added
    it says what it could not be told from), then the revisions' ties; one per set of
    explanations."""
    final = {e.name for e in r.model.effects}
    found = list(r.last.ambiguities)
    for s in reversed(r.steps[:-1]):
        found += [a for a in s.diagnosis.ambiguities if set(a.effects) & final]
    for rev in [s.revision for s in r.steps] + [r.revision]:
        if rev is not None:
            found += [a for a in rev.ambiguities if a.effects[0] in final]
    out, seen = [], set()
    for a in found:
        if frozenset(a.effects) not in seen:
            seen.add(frozenset(a.effects))
            out.append(a)
    return out


#: catalogue effects named as the closest rejected when the build-up ends unexplained
CLOSEST = 3


def closest_rejected(r: Stepwise) -> list[str]:
    """The catalogue effects that came closest and were rejected, closest first: the last
    diagnosis's candidates that lowered the error, and the end's revision's look-alikes tried
    in place of an effect, each with the error it leaves and why it was not kept."""
    d = r.last
    floor = d.objective_floor
    final = {e.name for e in r.model.effects}
    near: list[tuple[float, str]] = []
    for c in d.candidates:
        if c.effect in final or c.improvement <= 0:
            continue
        why = (f"not let in: {c.evidence}" if not c.own else
               f"removes {100 * max(c.excess_share, 0):.0f} % of the error above the noise"
               if c.helps else f"lowers the error by {100 * c.improvement:.1f} %, not "
               f"significantly or consistently")
        near.append((c.objective_rmse, f"+{c.effect} ({c.objective_rmse / floor:.2f}× the "
                                       f"floor: {why})"))
    rejected = [a for rev in (r.steps[-1].revision, r.revision) if rev is not None
                for a in rev.rejected if a.added is not None and a.removed in final]
    for a in rejected:
        near.append((a.objective_rmse, f"{a.change} ({a.objective_rmse / floor:.2f}× the "
                                       f"floor: {a.why})"))
    return [text for _, text in sorted(near)[:CLOSEST]]


def _path(r: Stepwise) -> str:
    """The build-up's path: the effects added, and what the revisions changed."""
    def revised(rev: Revision | None) -> list[str]:
        if rev is None:
            return []
        return [f"({a.change})" for a in rev.kept]
    items = [r.steps[0].model]
    for s in r.steps:
        if s.added:
            items.append(f"+{s.added}")
        items += revised(s.revision)
    return " → ".join(items + revised(r.revision))


def _summary(r: Stepwise) -> str:
    steps, verdict, fit, needed, last = r.steps, r.verdict, r.fit, r.needed, r.last
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
        if r.closest:
            tail += f"; closest rejected: {'; '.join(r.closest)}"
    else:
        head = f"stopped at {fit.model.spec} (effect limit); the error is still above the noise"
    return f"{head}: {_path(r)}, {change}{tail}"
