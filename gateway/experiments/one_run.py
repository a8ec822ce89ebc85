"""Every channel of a rig at once, each valve a ±u0 meander whose signs follow its own row of a
Hadamard matrix, all switching on one grid: the run that identifies all of G (``stand campaign
--rig RIG --one-run``; the excitation and why: :mod:`rig.excitation`).

The grid counts control cycles (a slot is a whole number of them), so every channel switches in
the same cycle. Each channel's force is guarded as a meander's is: at ``guard_fraction`` of its
force limit the run stops itself, naming the channel (the plan's swing check keeps the forces
well inside, :class:`gateway.campaign.GPlan`). No set-point approach: the run starts where the
forces are.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

from .base import check_range
from .phases import ForceGuard
from .rig import RigExperiment


class OneRun(RigExperiment):
    """The Hadamard meanders of ``names`` (module docstring): channel i at ``±amplitudes_pct[i]``
    (one number: every channel), slots of ``slot_s``, the pattern ``repeats`` times."""

    #: run.json's experiment name, by which the estimate knows the run (analysis.rig.onerun)
    name = "one-run"

    def __init__(self, names: Sequence[str], amplitudes_pct: float | Sequence[float],
                 slot_s: float, repeats: int = 1, guard_fraction: float = 0.9) -> None:
        from rig.excitation import hadamard_order, hadamard_signs   # numerics: not for --help
        self.names = list(names)
        n = len(self.names)
        if n < 1:
            raise ValueError("a one-run excitation needs at least one channel")
        amps = [amplitudes_pct] * n if isinstance(amplitudes_pct, (int, float)) else list(amplitudes_pct)
        if len(amps) != n:
            raise ValueError(f"{len(amps)} amplitudes for {n} channels")
        self.amplitudes_pct = [check_range("amplitude_pct", a, 1e-3, 100.0, "%") for a in amps]
        self.slot_s = check_range("slot_s", slot_s, 0.02, 600.0, "s")
        self.repeats = check_range("repeats", repeats, 1, 1000, integer=True)
        self.signs = hadamard_signs(n, self.repeats)
        self.order = hadamard_order(n)
        self.max_command_pct = max(self.amplitudes_pct)
        self.guards = [ForceGuard(guard_fraction) for _ in range(n)]
        self._per_slot = 1
        self._period_s = 0.0

    @property
    def duration_s(self) -> float:
        return self.signs.shape[1] * self.slot_s

    def params(self) -> dict[str, Any]:
        return {"excitation": "hadamard", "order": self.order,
                "slot_s": self.slot_s, "repeats": self.repeats, "slots": int(self.signs.shape[1]),
                "amplitude_pct": dict(zip(self.names, self.amplitudes_pct)),
                "guard_fraction": self.guards[0].fraction}

    def configure_rig(self, period_s: float, force_limits_kgf: Sequence[float]) -> None:
        self._period_s = float(period_s)
        self._per_slot = max(1, int(round(self.slot_s / period_s)))
        for guard, limit in zip(self.guards, force_limits_kgf):
            guard.configure(limit)

    def begin_rig(self, y0: Sequence[float]) -> None:
        self.abort = None
        self.abort_channel = None

    def finished_rig(self, t: float, ys: Sequence[float]) -> bool:
        return self._slot(t) >= self.signs.shape[1]

    def _slot(self, t: float) -> int:
        if self._period_s <= 0:
            return int(math.floor(t / self.slot_s + 1e-9))
        return int(round(t / self._period_s)) // self._per_slot

    def step_rig(self, t: float, ys: Sequence[float]) -> tuple[list[float], list[float]]:
        n = len(self.names)
        for i, (guard, y) in enumerate(zip(self.guards, ys)):
            verdict = guard.check(y)
            if verdict is not None:
                self.abort, self.abort_channel = verdict, i
                return [0.0] * n, [math.nan] * n
        k = self._slot(t)
        if k >= self.signs.shape[1]:
            return [0.0] * n, [math.nan] * n
        return ([a * float(s) for a, s in zip(self.amplitudes_pct, self.signs[:, k])],
                [math.nan] * n)
