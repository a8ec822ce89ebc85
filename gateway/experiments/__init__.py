"""The experiments the gateway can run (``stand run NAME``)."""
from __future__ import annotations

from typing import Any

from ..errors import ParameterError
from .base import Experiment, check_range
from .meander import Meander

EXPERIMENTS: dict[str, type[Experiment]] = {"meander": Meander}


def make_experiment(name: str, params: dict[str, Any]) -> Experiment:
    """Build an experiment by name; unknown names or parameters give a clear error."""
    try:
        klass = EXPERIMENTS[name]
    except KeyError:
        raise ParameterError(f"unknown experiment {name!r}; choose one of: {', '.join(EXPERIMENTS)}") from None
    try:
        return klass(**params)
    except TypeError as exc:
        import inspect
        accepted = [p for p in inspect.signature(klass).parameters]
        raise ParameterError(f"{name}: {exc}; it accepts: {', '.join(accepted)}") from None


__all__ = ["EXPERIMENTS", "Experiment", "Meander", "check_range", "make_experiment"]
