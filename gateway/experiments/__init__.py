"""The experiments the gateway can run (``stand run NAME``).

Every module here that defines an :class:`Experiment` subclass with a ``name`` is registered
automatically; adding an experiment is adding one module.
"""
from __future__ import annotations

import importlib
import inspect
import pkgutil
from typing import Any

from ..errors import ParameterError
from .base import Experiment, check_range
from .meander import Meander


def _discover() -> dict[str, type[Experiment]]:
    found: dict[str, type[Experiment]] = {}
    for m in pkgutil.iter_modules(__path__):
        if m.name == "base":
            continue
        module = importlib.import_module(f"{__name__}.{m.name}")
        for obj in vars(module).values():
            if (inspect.isclass(obj) and issubclass(obj, Experiment) and obj is not Experiment
                    and getattr(obj, "name", None) and obj.__module__ == module.__name__):
                found[obj.name] = obj
    return dict(sorted(found.items(), key=lambda kv: (kv[0] != "meander", kv[0])))


EXPERIMENTS: dict[str, type[Experiment]] = _discover()


def make_experiment(name: str, params: dict[str, Any]) -> Experiment:
    """Build an experiment by name; unknown names or parameters give a clear error."""
    try:
        klass = EXPERIMENTS[name]
    except KeyError:
        raise ParameterError(f"unknown experiment {name!r}; choose one of: {', '.join(EXPERIMENTS)}") from None
    try:
        return klass(**params)
    except TypeError as exc:
        accepted = list(inspect.signature(klass).parameters)
        raise ParameterError(f"{name}: {exc}; it accepts: {', '.join(accepted)}") from None


__all__ = ["EXPERIMENTS", "Experiment", "Meander", "check_range", "make_experiment"]
