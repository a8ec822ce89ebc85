"""The bus layer: our loopback-pinned python-can interface and bus specifications.

Nothing above this package knows which python-can interface it got.
"""
from __future__ import annotations

import importlib

# Names are imported on first use (PEP 562), so `import standbus.x` and the command line's --help do
# not pay for the numerics and the CAN stack behind them.
_LAZY = {
    "HandoverNotifier": ".handover",
    "LOCKSTEP_BUSY_POLL_S": ".loopback",
    "prefer_busy_poll": ".loopback",
    "DEFAULT_BUS": ".spec",
    "BusSpec": ".spec",
    "BusSpecError": ".spec",
    "open_bus": ".spec",
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
