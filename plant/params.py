"""Parameter declarations shared by the base model and every effect."""
from __future__ import annotations

import math
from dataclasses import dataclass


class ModelError(ValueError):
    """A model description or parameter value is invalid (message says what and how to fix)."""


@dataclass(frozen=True)
class Param:
    """One physical parameter.

    ``lower``/``upper`` are the physically meaningful bounds the fit is allowed to explore;
    ``log`` asks the optimizer to work on log(value) (strictly positive scale parameters).
    """

    name: str
    default: float
    lower: float
    upper: float
    unit: str
    doc: str
    log: bool = False

    def validate(self, value: float, owner: str) -> float:
        if isinstance(value, (bool, str, bytes)):
            raise ModelError(f"{owner}.{self.name} must be a number, got {value!r}")
        try:
            value = float(value)
        except (TypeError, ValueError, OverflowError):
            raise ModelError(f"{owner}.{self.name} must be a number, got {value!r}") from None
        if not math.isfinite(value):
            raise ModelError(f"{owner}.{self.name} must be finite, got {value}")
        if not (self.lower <= value <= self.upper):
            raise ModelError(
                f"{owner}.{self.name} = {value:g} {self.unit} is outside its physical range "
                f"[{self.lower:g}, {self.upper:g}] {self.unit} ({self.doc})")
        return value
