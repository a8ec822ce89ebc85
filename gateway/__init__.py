"""The gateway: CANopen master of the stand, control loop, experiments and run recorder.

Layers, bottom up: :mod:`standbus` (bus) → :mod:`gateway.master` (NMT/SDO/PDO set-up) →
:mod:`gateway.loop` (SYNC, force in, command out) with :mod:`gateway.supervisor` →
:mod:`gateway.recorder` / :mod:`gateway.capture` (run directory) → :mod:`analysis`.
"""
from .errors import DataError, NodeError, ParameterError, SafetyStop, StandError
from .runs import Run, load_run
from .session import Gateway, GatewayConfig, RunResult
from .supervisor import SafetyLimits

__all__ = ["DataError", "Gateway", "GatewayConfig", "NodeError", "ParameterError", "Run",
           "RunResult", "SafetyLimits", "SafetyStop", "StandError", "load_run"]
