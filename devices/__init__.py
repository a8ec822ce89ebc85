"""The devices of a loading channel, as files: which maker's CiA 408 valve drive and CiA 404
force amplifier each node is (its EDS), which of its objects play the roles the loop needs
(:mod:`devices.roles`), and the configuration the gateway gives it (:mod:`devices.plan`).

Used alike by the gateway (the master configures each node from its device) and the emulator
(each emulated node is built from its device). Layer: above the frame definitions (:mod:`dbc`),
below the plant and everything that talks to a bus.
"""
from .device import (Device, DeviceError, DeviceSet, Identity, RevisionRange, default_devices,
                     device_set_from_mapping, load_device_set)
from .plan import NodePlan, PdoSetup, SdoWrite, plan_node
from .roles import DYNAMOMETER, VALVE

__all__ = ["DYNAMOMETER", "Device", "DeviceError", "DeviceSet", "Identity", "NodePlan",
           "PdoSetup", "RevisionRange", "SdoWrite", "VALVE", "default_devices",
           "device_set_from_mapping", "load_device_set", "plan_node"]
