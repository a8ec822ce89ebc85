r"""Each channel of a rig diagnosed with the coupling in its model, the channels on an executor.

Channel i's force rate is its own one-channel model plus the other channels' part,
``c_i = Σ_{j≠i} G_ij·w_j`` (:mod:`analysis.rig.coupling`). Given a rig model (G and each
channel's model: what ``stand estimate --save`` writes, their base models; later what a
diagnosis arrived at), ``c_i`` is a known force rate along every run, and channel i becomes a
one-channel record that carries it. The one-channel :func:`.verdict.diagnose` or
:func:`.stepwise.stepwise` then runs on it unchanged (the simulation adds ``c_i`` as a
disturbance): it finds channel i's own effects (its reversal boost, ...), fits its own g
(``G_ii``), τ and Δ; the coupling entries stay as the rig model gives them.

The channels are independent given the others' models, so they run in parallel on any
:class:`concurrent.futures.Executor` (:mod:`analysis.executors`: a local process pool by
default, a dask cluster's with ``--scheduler``): one task per channel, carrying its records
and the user's plug-ins as sources. With ``rounds`` > 1 they run again, each channel's coupling
now from the others' models of the round before and its start its own (the others' reversal
boosts, absent from their base models, reach its force through G: a first round with base
models leaves them in its residual). The result is a rig model again: G with each channel's
fitted g on the diagonal, each channel's model.

Each channel is diagnosed from the runs that give it something to fit: where its own valve
moves, and where the coupling moves its force (a per-column campaign's other columns); a run
where neither does is left out, and a channel whose valve moves in no run is not diagnosed, its
model kept: both said in :attr:`RigDiagnosis.notes` (:func:`analysis.rig.coupling.diagnosable_records`).
"""
from __future__ import annotations

import time
from pathlib import Path
from concurrent.futures import Executor, as_completed
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from core.errors import DataError
from plant import PlantModel
from plant.plugins import ShippedPlugin, load_shipped, shippable_plugins
from plant.rig import RigModel

from ..executors import InlineExecutor
from ..identification.windows import WINDOW_S
from ..records.record import Record
from ..rig.coupling import aligned, diagnosable_records
from ..rig.record import RigRecord
from .stepwise import MAX_EFFECTS, stepwise
from .verdict import diagnose


@dataclass
class ChannelTask:
    """What a worker needs to diagnose one channel (picklable: arrays and strings)."""

    name: str
    records: list[Record]               #: the channel, each carrying its coupling rate
    spec: str                           #: the model to start from ...
    params: dict[str, float]            #: ... and its values
    build_up: bool                      #: stepwise (True) or one diagnosis
    window_s: float
    max_effects: int
    effects: list[str] | None
    plugins: list[ShippedPlugin] = field(default_factory=list)
    #: effects of the starting model a round before picked: checked again like added ones
    carried: list[str] = field(default_factory=list)


@dataclass
class ChannelResult:
    """One channel's diagnosis, as plain data (what came back from the worker)."""

    name: str
    verdict: str
    summary: str
    spec: str                           #: the model arrived at ...
    params: dict[str, float]            #: ... and its fitted values
    detail: dict[str, Any]              #: the diagnosis's (or build-up's) ``to_dict()``
    seconds: float                      #: the task's time in its worker

    def model(self) -> PlantModel:
        return PlantModel.from_spec(self.spec, self.params)


def diagnose_channel(task: ChannelTask) -> ChannelResult:
    """One channel's diagnosis (runs in a worker; module-level so any executor can send it)."""
    t0 = time.perf_counter()
    load_shipped(task.plugins)
    start = PlantModel.from_spec(task.spec, task.params)
    if task.build_up:
        r = stepwise(task.records, start, window_s=task.window_s, max_effects=task.max_effects,
                     effects=task.effects, jobs=1, carried=task.carried)
        model = r.model
        verdict, summary, detail = r.verdict, r.summary, r.to_dict()
    else:
        d = diagnose(task.records, start, window_s=task.window_s, effects=task.effects, jobs=1)
        best = d.best_candidate
        model = best.fit.model if best is not None else d.base_fit.model
        verdict, summary, detail = d.verdict, d.summary, d.to_dict()
    return ChannelResult(task.name, verdict, summary, model.spec,
                         {k: float(v) for k, v in model.params().items()}, detail,
                         time.perf_counter() - t0)


@dataclass
class RigDiagnosis:
    """Every channel diagnosed, and the rig model arrived at."""

    channels: list[ChannelResult]       #: in the order asked for
    rig: RigModel                       #: G (diagonal: the channels' fitted g) and models
    rounds: int
    seconds: float                      #: wall time of all rounds
    #: runs left out of a channel's diagnosis, channels not diagnosed, and why
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"schema": "hydrostand-rig-diagnosis/1", "rounds": self.rounds,
                "seconds": self.seconds, "notes": list(self.notes), "channels": [
                    {"channel": c.name, "verdict": c.verdict, "summary": c.summary,
                     "model": c.spec, "params": c.params, "seconds": c.seconds,
                     "diagnosis": c.detail} for c in self.channels],
                "rig": {"channels": self.rig.names, "G": self.rig.G.tolist(),
                        "models": {n: {"model": m.spec, "params": m.params()}
                                   for n, m in zip(self.rig.names, self.rig.channels)}}}


def diagnose_rig(records: Sequence[RigRecord], rig: RigModel,
                 channels: Sequence[str] | None = None, *, build_up: bool = True,
                 start: str | PlantModel | None = "base", window_s: float = WINDOW_S,
                 max_effects: int = MAX_EFFECTS, effects: Sequence[str] | None = None,
                 executor: Executor | None = None, rounds: int = 1,
                 progress: Callable[[str], None] | None = None) -> RigDiagnosis:
    """Diagnose ``channels`` (default: all) of a rig with the coupling in each one's model
    (module docstring). ``start``: each channel's first model (a spec or model; None: its
    model in ``rig``); ``build_up``: :func:`.stepwise.stepwise` (True) or one
    :func:`.verdict.diagnose`; ``executor``: where the channels run (default: in this
    process, in order); ``rounds``: how many times (each after the first starts every channel
    from its model of the round before, its coupling from the others'; a build-up checks the
    effects the rounds before added again at its end, as it checks its own)."""
    records = list(records)
    if not records:
        raise DataError("no rig runs given")
    for rec in records:
        aligned(rig, rec)
    names = list(channels) if channels else list(rig.names)
    unknown = [n for n in names if n not in rig.names]
    if unknown:
        raise DataError(f"no channel {', '.join(unknown)} in the rig model; its channels: "
                        f"{', '.join(rig.names)}")
    if rounds < 1:
        raise DataError(f"rounds = {rounds}: give 1 or more")
    say = progress or (lambda msg: None)
    executor = executor or InlineExecutor()
    plugins = shippable_plugins()
    t0 = time.perf_counter()
    current = rig
    results: dict[str, ChannelResult] = {}
    notes: list[str] = []
    start_model = PlantModel.from_spec(start) if isinstance(start, str) else start
    for r in range(rounds):
        tasks = []
        for name in names:
            recs, why = diagnosable_records(current, records, name)
            if r == 0:
                notes += why
            if not recs:
                continue
            origin = start_model if start_model is not None else rig.channels[rig.names.index(name)]
            first = origin if r == 0 else current.channels[current.names.index(name)]
            # what a round before added was picked against the couplings of its time: checked
            # again with the others in place, so an effect standing in for a neighbour's goes
            carried = [e.name for e in first.effects if origin.effect(e.name) is None]
            tasks.append(ChannelTask(name, recs, first.spec, first.params(), build_up,
                                     window_s, max_effects,
                                     None if effects is None else list(effects), plugins,
                                     carried))
        if not tasks:
            runs = ", ".join(Path(rec.source).name or rec.source for rec in records)
            one = len(names) == 1
            raise DataError(f"no channel can be diagnosed: the valve{'' if one else 's'} of "
                            f"{', '.join(names)} {'does' if one else 'do'} not move in {runs}, "
                            f"so {'its' if one else 'their'} own g, τ and effects are not in "
                            f"the data; give the runs where {'it moves' if one else 'they move'}"
                            " (each channel's column run, or a simultaneous run)")
        futures = {executor.submit(diagnose_channel, t): t.name for t in tasks}
        for fut in as_completed(futures):
            res = fut.result()
            results[res.name] = res
            say(f"round {r + 1} of {rounds}: {res.name}: {res.verdict} ({res.spec}, "
                f"{res.seconds:.1f} s)")
        current = updated(current, [results[t.name] for t in tasks])
    done = [n for n in names if n in results]
    return RigDiagnosis([results[n] for n in done], current, rounds, time.perf_counter() - t0,
                        notes)


def updated(rig: RigModel, results: Sequence[ChannelResult]) -> RigModel:
    """``rig`` with the diagnosed channels' models, their fitted g on G's diagonal."""
    G = rig.G.copy()
    models = list(rig.channels)
    for res in results:
        i = rig.names.index(res.name)
        m = res.model()
        models[i] = m
        G[i, i] = m.g
    return RigModel(models, G, rig.names)


def same_results(a: RigDiagnosis, b: RigDiagnosis, rel: float = 1e-9) -> bool:
    """Two runs arrived at the same models (the executor does not change the answer)."""
    if [c.name for c in a.channels] != [c.name for c in b.channels]:
        return False
    for x, y in zip(a.channels, b.channels):
        if x.spec != y.spec or x.verdict != y.verdict or set(x.params) != set(y.params):
            return False
        if not all(np.isclose(x.params[k], y.params[k], rtol=rel, atol=0) for k in x.params):
            return False
    return True
