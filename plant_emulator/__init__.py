"""The plant emulator: a separate process that impersonates the stand's two CANopen nodes
(servo-valve drive, dynamometer) and the hydraulic plant behind them (:mod:`plant`).
"""
from .stand import EmulatedStand, EmulatorOptions

__all__ = ["EmulatedStand", "EmulatorOptions"]
