"""Undo a build-up's choices: every effect it added tried in place of each of its look-alikes,
and left out, the others refitted.

A greedy build-up can take an effect early that mimics another (an overdamped resonance for a
sensor lag, a play in force for one in travel), and adding more effects on top never takes it
back. :func:`revise` tries, for each effect it is given, the model with the effect replaced by
each of its look-alikes (:func:`plant.catalogue.look_alikes`: those it names and those that name
it) and the model without it; each alternative is fitted (the new effect from its start grid,
the others warm) and judged against the current model on all windows. It is *kept* when

* it has fewer parameters and the current model does not help over it (the criteria of
  :mod:`.significance`, k = the parameters saved): it explains as much with less;
* it has as many parameters and a BIC lower by more than :data:`~.candidates.BIC_TIE`
  (equal parameters: lower error); an alternative within that that leaves about as little
  (within :data:`~plant.evidence.AMBIGUITY_RATIO`), neither helping over the other, is an
  ambiguity these data leave (reported, with the experiment that would separate them);
* it has more parameters, helps over the current model and lowers the BIC: it earns them;

and only if the effect it brings in shows its own evidence
(:meth:`plant.Effect.own_evidence`). Of the alternatives kept, the one with the lowest BIC
replaces the model, and the search starts again from there (never returning to a model it
left), until none is kept.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from plant import CATALOGUE, PlantModel
from plant.catalogue import look_alikes
from plant.contract import separating_experiment
from plant.evidence import AMBIGUITY_RATIO, Ambiguity

from ..identification.fit import REFIT_TOL, FitOptions, FitResult, fit_model
from ..identification.windows import Piece, errors, residual
from ..parallel import run_each, workers_for
from .candidates import BIC_TIE, bic
from .significance import error_cut

#: evaluations of the model an alternative's fit takes, about (a candidate's screening fit)
EVALS_PER_ALTERNATIVE = 100


@dataclass
class Alternative:
    """The model with one effect replaced by a look-alike (or left out), fitted and judged
    against the model it would replace."""

    removed: str
    added: str | None             #: the look-alike brought in (None: the effect left out)
    spec: str
    objective_rmse: float         #: on all windows, window starts re-estimated, kgf
    free_params: int
    bic: float
    kept: bool = False
    why: str = ""                 #: why it was kept, or not
    #: as many parameters and about as little error, neither helping over the other
    tie: bool = False
    fit: FitResult | None = field(default=None, repr=False)
    window_sse: np.ndarray | None = field(default=None, repr=False)

    @property
    def change(self) -> str:
        return (f"+{self.added} in place of +{self.removed}" if self.added
                else f"without +{self.removed}")

    def to_dict(self) -> dict:
        return {"removed": self.removed, "added": self.added, "spec": self.spec,
                "objective_rmse": self.objective_rmse, "free_params": self.free_params,
                "bic": self.bic, "kept": self.kept, "why": self.why}


@dataclass
class Revision:
    """What :func:`revise` changed: the model it ended with, the alternatives kept (in order)
    and the others tried, and the ties it found."""

    fit: FitResult
    kept: list[Alternative]
    rejected: list[Alternative]
    ambiguities: list[Ambiguity]

    @property
    def text(self) -> str:
        """The swaps kept, in words (empty: none)."""
        return "; ".join(f"{a.change}: {a.why}" for a in self.kept)


def _fit_alternative(shared: tuple, change: tuple[str, str | None]) -> FitResult | None:
    """The model with ``change`` = (effect removed, look-alike added or None) fitted: the
    look-alike from its start grid on the screening windows, the others warm; a model without
    the effect polished on all windows (a task for :func:`run_each`)."""
    full, screen, model = shared
    removed, added = change
    values = {k: v for k, v in model.params().items() if not k.startswith(removed + ".")}
    try:
        m0 = PlantModel.from_spec(_spec(model, change), values)
    except Exception:  # noqa: BLE001 - a look-alike that cannot start from here is skipped
        return None
    if added is None:
        return fit_model(full, m0, options=FitOptions.refit(tol=REFIT_TOL, covariance=False))
    return fit_model(screen, m0, options=FitOptions.add_effect(added))


def revise(fit: FitResult, effects: Sequence[str], full: Sequence[Piece],
           screen: Sequence[Piece], floor: float, jobs: int | None = None,
           say: Callable[[str], None] | None = None, drops: bool = True,
           tried: set | None = None, idle: Sequence[str] = ()) -> Revision:
    """Try every effect of ``effects`` (in ``fit``'s model) in place of each of its look-alikes
    and left out (``drops``), keep what the module docstring says, and repeat from the model
    kept. ``full``: all windows (the judging ones); ``screen``: those a look-alike is fitted on
    (the diagnosis's screening windows); ``floor``: the objective's noise floor. ``tried``:
    the changes tried before (the effects of the model, the change), skipped here and added to:
    a change rejected for a model with the same effects is not fitted again. ``idle``: effects
    that did not help added to ``fit``'s model; one of them is not tried in place of an effect
    with as few parameters (it could only explain more there, and does not on top of it)."""
    say = say or (lambda msg: None)
    tried = set() if tried is None else tried
    n = sum(p.n_eval for p in full)
    kept: list[Alternative] = []
    rejected: list[Alternative] = []
    ties: list[Ambiguity] = []
    visited = {fit.model.spec}
    current = fit
    w_cur = errors(current.model, full)[0]
    while True:
        have = {e.name for e in current.model.effects}
        changes = [(e, alike) for e in effects if e in have
                   for alike in look_alikes(e) + ([None] if drops else []) if alike not in have]
        changes = [c for c in changes if _spec(current.model, c) not in visited
                   and (frozenset(have), *c) not in tried
                   and not (current is fit and c[1] in idle
                            and len(CATALOGUE[c[1]].params) >= len(CATALOGUE[c[0]].params))]
        tried.update((frozenset(have), *c) for c in changes)
        if not changes:
            break
        say("trying " + ", ".join(f"+{a} for +{e}" if a else f"-{e}" for e, a in changes))
        cur = _judged(current, w_cur, n, None, "")
        alternatives = []
        for change, f in _fit_all(changes, full, screen, current.model, jobs):
            if f is None:
                continue
            w = errors(f.model, full)[0]
            alternatives.append(_judged(f, w, n, *change))
        for a in alternatives:
            _decide(a, cur, floor, n)
            if a.tie:
                pair = [a.removed, a.added]
                if not any(set(t.effects) == set(pair) for t in ties):
                    ties.append(Ambiguity(pair, (
                        f"+{a.added} in place of +{a.removed} leaves as little error "
                        f"({a.objective_rmse:.3g} vs {cur.objective_rmse:.3g} kgf) with as many "
                        f"parameters: these data do not tell them apart."),
                        separating_experiment(*pair)))
        best = min((a for a in alternatives if a.kept), key=lambda a: (a.bic, a.free_params),
                   default=None)
        for a in alternatives:
            if a.kept and a is not best:
                a.kept = False
                a.why += f", but {best.change} leaves less ({best.objective_rmse:.3g} kgf)"
        rejected += [a for a in alternatives if a is not best]
        if best is None:
            break
        say(f"keeping {best.change}")
        if best.added is not None:     # fitted on the screening windows: polished on all
            best.fit = fit_model(full, best.fit.model,
                                 options=FitOptions.refit(tol=REFIT_TOL, covariance=False))
            best.window_sse = errors(best.fit.model, full)[0]
        kept.append(best)
        visited.add(best.fit.model.spec)
        current, w_cur = best.fit, best.window_sse
        effects = [best.added if e == best.removed else e for e in effects if
                   e != best.removed or best.added]
    # the ties of an effect since replaced say nothing about the final model
    final = {e.name for e in current.model.effects}
    return Revision(current, kept, rejected, [t for t in ties if t.effects[0] in final])


def _spec(model: PlantModel, change: tuple[str, str | None]) -> str:
    """The spec of ``model`` with ``change`` (effect removed, look-alike added or None)."""
    removed, added = change
    names = [e.name for e in model.effects if e.name != removed] + ([added] if added else [])
    return PlantModel.from_spec("+".join(["base"] + names)).spec


def _fit_all(changes, full, screen, model, jobs):
    """Every change fitted, in worker processes when the work is worth it."""
    t0 = time.perf_counter()
    residual(model, screen)
    work = (time.perf_counter() - t0) * EVALS_PER_ALTERNATIVE * len(changes)
    done = dict(run_each(_fit_alternative, changes, (full, screen, model),
                         workers_for(len(changes), work, jobs)))
    return [(c, done[c]) for c in changes]


def _judged(f: FitResult, w: np.ndarray, n: int, removed: str | None,
            added: str | None) -> Alternative:
    obj = math.sqrt(w.sum() / n)
    return Alternative(removed or "", added, f.model.spec, obj, len(f.free),
                       bic(obj, len(f.free), n), fit=f, window_sse=w)


def _decide(a: Alternative, cur: Alternative, floor: float, n: int) -> None:
    """Judge alternative ``a`` against the current model ``cur`` (the module docstring)."""
    extra = a.free_params - cur.free_params
    if a.added is not None:
        own, evidence = CATALOGUE[a.added].own_evidence(a.fit.model.params())
        if not own:
            a.why = f"not let in: {evidence}"
            return
    ratio = f"{a.objective_rmse:.3g} vs {cur.objective_rmse:.3g} kgf"
    if extra < 0:
        richer = error_cut(cur.window_sse, a.window_sse, floor, n, -extra)
        a.kept = not richer.helps
        a.why = (f"explains {'more' if a.objective_rmse < cur.objective_rmse else 'as much'} "
                 f"with {-extra} parameter{'s' if extra < -1 else ''} fewer ({ratio})" if a.kept else
                 f"leaves more error ({ratio}: the current model helps over it)")
    elif extra == 0:
        a.kept = a.bic < cur.bic - BIC_TIE
        # a tie: neither helps over the other, and each leaves about as little as the other
        close = max(a.objective_rmse, cur.objective_rmse) <= AMBIGUITY_RATIO * min(
            a.objective_rmse, cur.objective_rmse)
        a.tie = not a.kept and close and not (
            error_cut(a.window_sse, cur.window_sse, floor, n, 1).helps
            or error_cut(cur.window_sse, a.window_sse, floor, n, 1).helps)
        a.why = (f"explains more with as many parameters ({ratio})" if a.kept else
                 f"a tie: as little error with as many parameters ({ratio})" if a.tie else
                 f"leaves more error ({ratio})")
    else:
        cut = error_cut(a.window_sse, cur.window_sse, floor, n, extra)
        a.kept = cut.helps and a.bic < cur.bic
        a.why = (f"earns its {extra} more parameter{'s' if extra > 1 else ''} ({ratio})"
                 if a.kept else f"does not earn its {extra} more parameter"
                 f"{'s' if extra > 1 else ''} ({ratio})")
