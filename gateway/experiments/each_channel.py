"""Every channel of a rig its own one-channel experiment, all at once: a rig experiment made of
per-channel ones (the simultaneous identification: every channel a meander of its own period).

Each channel's experiment is stepped with its own force exactly as the loop steps a per-channel
driver (``configure`` with the channel's force limit, ``begin`` with its first force, ``step``
until it is ``finished``); a channel whose experiment has finished, or that has none, holds a
zero command until every experiment has finished. An experiment that stops itself (its force
near the limit) stops the rig run, naming its channel.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

from .base import Experiment
from .rig import RigExperiment


class EachChannel(RigExperiment):
    """``experiments[i]`` on channel ``names[i]`` (None: that channel holds a zero command)."""

    def __init__(self, names: Sequence[str], experiments: Sequence[Experiment | None]) -> None:
        if len(names) != len(experiments):
            raise ValueError(f"{len(experiments)} experiments for {len(names)} channels")
        self.names = list(names)
        self.experiments = list(experiments)
        used = [e for e in self.experiments if e is not None]
        if not used:
            raise ValueError("no channel has an experiment")
        kinds = {e.name for e in used}
        self.name = kinds.pop() if len(kinds) == 1 else "each-channel"
        self.max_command_pct = max(e.max_command_pct for e in used)
        self._active = [e is not None for e in self.experiments]

    @property
    def duration_s(self) -> float:
        return max(e.duration_s for e in self.experiments if e is not None)

    @property
    def max_duration_s(self) -> float:
        return max(e.max_duration_s for e in self.experiments if e is not None)

    def params(self) -> dict[str, Any]:
        """Each parameter as ``{channel: value}`` (channels without an experiment left out),
        as a simultaneous run's ``experiment.params`` reads."""
        per = {n: e.params() for n, e in zip(self.names, self.experiments) if e is not None}
        keys = dict.fromkeys(k for p in per.values() for k in p)
        return {k: {n: p.get(k) for n, p in per.items()} for k in keys}

    def configure_rig(self, period_s: float, force_limits_kgf: Sequence[float]) -> None:
        for e, limit in zip(self.experiments, force_limits_kgf):
            if e is not None:
                e.abort = None
                e.configure(period_s, limit)

    def begin_rig(self, y0: Sequence[float]) -> None:
        self.abort = None
        self.abort_channel = None
        self._active = [e is not None for e in self.experiments]
        for e, y in zip(self.experiments, y0):
            if e is not None:
                e.begin(y)

    def finished_rig(self, t: float, ys: Sequence[float]) -> bool:
        for i, e in enumerate(self.experiments):
            if self._active[i] and e.finished(t, ys[i]):
                self._active[i] = False
        return not any(self._active)

    def step_rig(self, t: float, ys: Sequence[float]) -> tuple[list[float], list[float]]:
        n = len(self.names)
        us, rs = [0.0] * n, [math.nan] * n
        for i, e in enumerate(self.experiments):
            if not self._active[i]:
                continue
            us[i], rs[i] = e.step(t, ys[i])
            if e.abort is not None:
                self.abort, self.abort_channel = e.abort, i
                return [0.0] * n, rs
        return us, rs
