"""The gateway: CANopen master of the stand, control loop, experiments and run recorder.

Layers, bottom up: :mod:`standbus` (bus) → :mod:`gateway.master` (NMT/SDO/PDO set-up) →
:mod:`gateway.loop` (SYNC, force in, command out) with :mod:`gateway.supervisor` →
:mod:`gateway.recorder` / :mod:`gateway.capture` (run directory) → :mod:`analysis`.
"""
from __future__ import annotations

from core.lazy import lazy_exports

# imported on first use (core.lazy): `import gateway.x` and `stand --help` stay light
_EXPORTS = {
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
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
