"""The plant emulator: a separate process that impersonates the stand's two CANopen nodes
(servo-valve drive, dynamometer) and the hydraulic plant behind them (:mod:`plant`), or every
channel of a rig on every one of its buses (:class:`EmulatedRig`, docs/rig.md).
"""
from .emulated_rig import EmulatedRig
from .stand import EmulatedStand, EmulatorOptions

__all__ = ["EmulatedRig", "EmulatedStand", "EmulatorOptions"]
