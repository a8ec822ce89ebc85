"""What a rig experiment is to the control loop: one command law for every channel at once.

A per-channel :class:`~gateway.experiments.base.Experiment` sees one force and returns one
command; a channel it does not drive holds a zero command. A **rig experiment** sees every
channel's force each cycle and returns every channel's command (a multi-variable controller: a
decoupling feedforward through G⁻¹, a vector PI, simultaneous meanders of their own periods).
The loop calls :meth:`RigExperiment.configure_rig` once with the period and every channel's
force limit, :meth:`begin_rig` with the first forces, then :meth:`step_rig` every cycle until
:meth:`finished_rig`. Every channel's supervisor checks its own channel exactly as for
per-channel drivers (force limit, error detector on the channel's reference, command clamp and
slew), and a trip on any channel acts on the whole rig (:class:`gateway.loop.RigSafety`).

Not registered as a ``stand run`` experiment (those are :class:`Experiment` subclasses).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, ClassVar, Sequence


class RigExperiment(ABC):
    """One run's command law for every channel of a rig (module docstring)."""

    name: ClassVar[str]
    #: the loop steps it with every channel's force at once
    drives_rig: ClassVar[bool] = True
    #: the channels it was made for, in the rig's order (the loop refuses any other rig)
    names: list[str]
    #: |u| never exceeds this (%) on any channel; each supervisor clamps to its own limit too
    max_command_pct: float = 100.0
    #: set by :meth:`step_rig` to stop the run safely: ``(reason, message)``
    abort: tuple[str, str] | None = None
    #: the index of the channel the abort is about (None: the rig as a whole)
    abort_channel: int | None = None
    #: what the loop does on :attr:`abort`: ``hold`` every valve, or ``unload`` (the rig's
    #: unload keeping the load ratios)
    abort_action: str = "hold"

    @property
    @abstractmethod
    def duration_s(self) -> float: ...

    @property
    def max_duration_s(self) -> float:
        return self.duration_s

    @abstractmethod
    def params(self) -> dict[str, Any]:
        """The parameters as recorded in the run's metadata."""

    def configure_rig(self, period_s: float, force_limits_kgf: Sequence[float]) -> None:
        """Called before :meth:`begin_rig` with the loop's period and every channel's force
        limit (kgf, in the rig's order)."""

    def begin_rig(self, y0: Sequence[float]) -> None:
        """Called once before the first step with every channel's first force (kgf)."""

    @abstractmethod
    def step_rig(self, t: float, ys: Sequence[float]) -> tuple[Sequence[float], Sequence[float]]:
        """Every channel's command (%) for the coming cycle and its reference (kgf, NaN if
        none), from the time since the start (s) and every channel's force (kgf)."""

    def finished_rig(self, t: float, ys: Sequence[float]) -> bool:
        return t >= self.duration_s


def is_rig_experiment(experiment: object) -> bool:
    """True if the loop steps ``experiment`` with every channel at once."""
    return bool(getattr(experiment, "drives_rig", False))
