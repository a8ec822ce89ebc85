"""The gateway: CANopen master of the stand, control loop, experiments and run recorder.

Layers, bottom up: :mod:`standbus` (bus) → :mod:`gateway.master` (NMT/SDO/PDO set-up) →
:mod:`gateway.loop` (SYNC, force in, command out) with :mod:`gateway.supervisor` →
:mod:`gateway.recorder` / :mod:`gateway.capture` (run directory) → :mod:`analysis`.
"""
from __future__ import annotations

import importlib

# Names are imported on first use (PEP 562), so `import gateway.x` and the command line's --help do
# not pay for the numerics and the CAN stack behind them.
_LAZY = {
    "DataError": ".errors",
    "NodeError": ".errors",
    "ParameterError": ".errors",
    "SafetyStop": ".errors",
    "StandError": ".errors",
    "Run": ".runs",
    "load_run": ".runs",
    "Gateway": ".session",
    "GatewayConfig": ".config",
    "RunResult": ".session",
    "SafetyLimits": ".supervisor",
}
__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
