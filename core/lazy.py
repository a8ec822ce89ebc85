"""Names a package exports, imported on first use (PEP 562).

A package's ``__init__`` that imports its modules eagerly makes ``import package.small_module``
pay for all of them (numpy, scipy, the CAN stack), and so ``stand --help``. With::

    __getattr__, __dir__ = lazy_exports(__name__, {"Gateway": ".session", ...})

``from gateway import Gateway`` still works and imports ``gateway.session`` only then.
"""
from __future__ import annotations

import importlib
import sys
from typing import Callable


def lazy_exports(package: str, names: dict[str, str]) -> tuple[Callable, Callable]:
    """``__getattr__`` and ``__dir__`` for ``package``: ``names`` maps an exported name to the
    module (relative to the package) that defines it."""
    def __getattr__(name: str):
        if name in names:
            value = getattr(importlib.import_module(names[name], package), name)
            setattr(sys.modules[package], name, value)
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(names))

    return __getattr__, __dir__
