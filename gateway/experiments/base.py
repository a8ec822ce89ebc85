"""What an experiment is to the control loop: a command law run once per control cycle."""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Any, ClassVar

from ..errors import ParameterError


def check_range(name: str, value: Any, lower: float, upper: float, unit: str = "",
                integer: bool = False) -> float:
    """Validate one experiment parameter; the error names it, its range and its unit."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(number) or not (lower <= number <= upper) or (
            integer and number != int(number)):
        kind = "an integer" if integer else "a number"
        u = f" {unit}" if unit else ""
        raise ParameterError(
            f"{name} = {value}{u} is out of range: it must be {kind} from {lower:g} to {upper:g}{u}")
    return int(number) if integer else number


class Experiment(ABC):
    """One run's command law.

    The loop calls :meth:`begin` once with the first force reading, then :meth:`step` every
    cycle with the time since the start (s) and the force (kgf); ``step`` returns the valve
    command (%) for the coming cycle and the reference force (kgf, NaN if none). The run ends
    after :attr:`duration_s` (or earlier when :meth:`finished` says so).
    """

    name: ClassVar[str]
    #: |u| never exceeds this (%); the supervisor clamps to its own limit as well
    max_command_pct: float = 100.0
    #: set by :meth:`step` to stop the run safely: ``(reason, message)``, e.g.
    #: ``("force_near_limit", "force 9200 kgf within 10 % of the limit")``
    abort: tuple[str, str] | None = None

    @property
    @abstractmethod
    def duration_s(self) -> float: ...

    @property
    def max_duration_s(self) -> float:
        """Upper bound of the run's stand time (progress bars); experiments with phases of
        variable length (a set-point approach) say more than :attr:`duration_s`."""
        return self.duration_s

    @abstractmethod
    def params(self) -> dict[str, Any]:
        """The parameters as recorded in the run's metadata."""

    def begin(self, y0: float) -> None:
        """Called once before the first step with the first force reading."""

    def configure(self, period_s: float, force_limit_kgf: float) -> None:
        """Called before :meth:`begin` with the loop's period and the supervisor's force limit
        (experiments that must stay clear of the limit use it)."""

    @abstractmethod
    def step(self, t: float, y: float) -> tuple[float, float]: ...

    def finished(self, t: float, y: float) -> bool:
        return t >= self.duration_s
