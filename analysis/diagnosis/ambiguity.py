"""What the data cannot tell apart, and the experiment that would.

Two explanations of the same error are *ambiguous* when these records cannot separate them:
look-alikes at a single command amplitude (a dead zone lowers the slope like another gain), under
a smooth command (a valve lag shifts it like more delay), candidates that leave about as little
error as the best (within :data:`AMBIGUITY_RATIO`; a richer one tied with it is its equivalent,
:func:`.candidates.rank_candidates`), a parameter the data do not determine, or a
gain that changed between the runs where the runs' order and command levels rise together. Each
:class:`~plant.evidence.Ambiguity` names the experiment that separates them. What an effect looks
like and what tells it apart lives on its class (:meth:`plant.Effect.ambiguities`,
:attr:`plant.Effect.look_alikes`), a plug-in's as the catalogue's: every effect is asked here.
"""
from __future__ import annotations

from typing import Sequence

from plant.catalogue import CATALOGUE
from plant.contract import separating_experiment
from plant.evidence import AMBIGUITY_RATIO, Ambiguity, Evidence, Excitation  # noqa: F401

from ..identification.fit import FitResult
from ..records.record import Record
from .between_records import BetweenRecords
from .candidates import Candidate

#: what separates a drift across the runs from an effect of the command level
REPEAT_FIRST_RUN = ("the first run repeated at the end of the campaign (the same command, "
                    "later): an effect of the command level gives it the first run's gain, a "
                    "drift across the runs the last run's")


def ambiguities(records: Sequence[Record], base_fit: FitResult, cands: Sequence[Candidate],
                best: Candidate | None) -> list[Ambiguity]:
    """What these records cannot tell apart among the candidates (``cands``, ranked; ``best``
    the one that earns, if any): look-alikes at a single command amplitude or under a smooth
    command, candidates that leave about as little error as the best, and parameters of the
    best that the data do not determine; each with the experiment that would separate them."""
    tried = {c.effect for c in cands}
    ev = Evidence(Excitation.of(records), base_fit.model.params(), frozenset(tried),
                  best.effect if best is not None else None,
                  dict(best.params) if best is not None else {},
                  {c.effect: c.objective_rmse for c in cands})
    out: list[Ambiguity] = []
    for cls in CATALOGUE.values():          # each effect knows its look-alikes
        out += [a for a in cls.ambiguities(ev) if a not in out]
    # candidates the data do not separate (comparable error reductions); a richer one tied
    # with the best is its equivalent (ranked after it: ties go to the simpler law)
    if best is not None:
        for c in cands:
            equivalent = c.effect in best.equivalents
            if c is best or not (c.earns or equivalent):
                continue
            if equivalent or c.objective_rmse <= AMBIGUITY_RATIO * best.objective_rmse:
                pair = [best.effect, c.effect]
                if any(set(a.effects) == set(pair) for a in out):
                    continue
                errors = f"({c.objective_rmse:.3g} vs {best.objective_rmse:.3g} kgf)"
                extra = c.free_params - best.free_params
                reason = (f"+{c.effect} is the equivalent of +{best.effect}: it leaves as little "
                          f"error {errors} with {extra} more parameter{'s' if extra > 1 else ''}, "
                          f"which these data do not pay for, so the simpler law is named first."
                          if equivalent else
                          f"+{c.effect} leaves about as little error as +{best.effect} {errors}.")
                out.append(Ambiguity(pair, reason, separating_experiment(*pair)))
        # parameters of the best candidate the data do not determine
        if best.fit is not None:
            for name in best.fit.non_identifiable():
                out.append(Ambiguity([name], "this parameter is not determined by these data "
                                             "(it trades off against another one).",
                                     "the meander at several amplitudes and periods"))
    return out


def drift_or_level(best: Candidate | None, between: BetweenRecords) -> Ambiguity:
    """The records' own g or Δ explain the error as well as ``best`` (or a gain that depends on
    the command), and the records cannot tell a drift across the runs from a dependence on the
    command level."""
    return Ambiguity(
        effects=[best.effect if best is not None else "a gain that depends on the command",
                 f"a {between.varies} that changed between the runs"],
        reason=(f"the records' own {between.varies}s would explain the error as well, and "
                f"these records cannot tell a drift across the runs from a dependence on "
                f"the command level (their levels rise with their order, or they are few)."),
        experiment=REPEAT_FIRST_RUN)
