"""The bus layer: our loopback-pinned python-can interface and bus specifications.

Nothing above this package knows which python-can interface it got.
"""
from __future__ import annotations

from core.lazy import lazy_exports

# imported on first use (core.lazy): `import standbus.x` and `stand --help` stay light
_EXPORTS = {
    "HandoverNotifier": ".handover",
    "LOCKSTEP_BUSY_POLL_S": ".loopback",
    "prefer_busy_poll": ".loopback",
    "DEFAULT_BUS": ".spec",
    "BusSpec": ".spec",
    "BusSpecError": ".spec",
    "open_bus": ".spec",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
