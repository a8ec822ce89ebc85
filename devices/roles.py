"""What the loop needs of each device: the roles its objects play, with the CiA profiles'
objects as the defaults.

A role is one thing the gateway reads or writes: the valve drive's control word and setpoint
(sent every cycle in an RPDO), its status word and actual spool position (received every cycle
in a TPDO), its device mode (written once over SDO); the amplifier's process value (received
every cycle). A device that follows its profile (CiA 408 for the valve, CiA 404 for the
amplifier) needs no role table: the defaults below are the profile's objects. A device file
names an object only where the maker chose another one (``../shared/notes/canopen.md``).
"""
from __future__ import annotations

from dataclasses import dataclass

from canopen.objectdictionary import datatypes as T

#: the two devices of a loading channel, by the name the project gives them
VALVE, DYNAMOMETER = "valve", "dynamometer"
DEVICE_KINDS = (VALVE, DYNAMOMETER)
#: the CiA device profile each follows (the low 16 bits of the device type 0x1000)
PROFILES = {VALVE: 408, DYNAMOMETER: 404}
PROFILE_NAMES = {VALVE: "CiA 408 servo-valve drive", DYNAMOMETER: "CiA 404 measuring amplifier"}

#: a role's object as (index, sub-index)
Key = tuple[int, int]

_INTEGERS = frozenset({T.INTEGER8, T.INTEGER16, T.INTEGER32, T.UNSIGNED8, T.UNSIGNED16, T.UNSIGNED32})
_SIGNED = frozenset({T.INTEGER16, T.INTEGER32})
_NUMBERS = frozenset({T.INTEGER16, T.INTEGER32, T.REAL32})
_WORD = frozenset({T.UNSIGNED16, T.INTEGER16})
_BYTE = frozenset({T.UNSIGNED8, T.INTEGER8})

#: the data types by name, for messages
TYPE_NAMES = {T.BOOLEAN: "BOOLEAN", T.INTEGER8: "INTEGER8", T.INTEGER16: "INTEGER16",
              T.INTEGER32: "INTEGER32", T.UNSIGNED8: "UNSIGNED8", T.UNSIGNED16: "UNSIGNED16",
              T.UNSIGNED32: "UNSIGNED32", T.REAL32: "REAL32", T.REAL64: "REAL64",
              T.INTEGER64: "INTEGER64", T.UNSIGNED64: "UNSIGNED64",
              T.VISIBLE_STRING: "VISIBLE_STRING", T.OCTET_STRING: "OCTET_STRING",
              T.DOMAIN: "DOMAIN"}


@dataclass(frozen=True)
class Role:
    """One object the gateway uses on a device.

    ``candidates``: the profile's objects for the role, the first the device has is taken;
    ``pdo``: ``"rpdo"`` (the gateway writes it every cycle), ``"tpdo"`` (the device sends it
    every cycle) or None (read or written once, over SDO); ``required``: the loop cannot run
    without it (an optional role the device lacks is noted, and what the run then lacks said).
    """

    name: str
    what: str
    candidates: tuple[Key, ...]
    types: frozenset[int]
    pdo: str | None
    required: bool
    #: what the run lacks without it (optional roles)
    without: str = ""

    @property
    def default(self) -> Key:
        return self.candidates[0]

    def type_names(self) -> str:
        return " or ".join(sorted(TYPE_NAMES.get(t, hex(t)) for t in self.types))


VALVE_ROLES = (
    Role("control_word", "control word (CiA 408 0x6040)", ((0x6040, 0),), _WORD, "rpdo", True),
    Role("setpoint", "spool setpoint (CiA 408 0x6300:01)", ((0x6300, 1),), _SIGNED, "rpdo", True),
    Role("status_word", "status word (CiA 408 0x6041)", ((0x6041, 0),), _WORD, "tpdo", True),
    Role("actual_spool", "actual spool position (CiA 408 0x6301:01)", ((0x6301, 1),), _SIGNED,
         "tpdo", False, "the spool position is not recorded (the run's spool column is NaN)"),
    Role("device_mode", "device mode (CiA 408 0x6042; 1: setpoint via the bus)", ((0x6042, 0),),
         _BYTE, None, False, "the device mode is not set by the gateway: set the drive to take "
         "its setpoint from the bus by its own tool"),
    Role("setpoint_reference", "setpoint reference, counts at 100 % (CiA 408 0x6311)",
         ((0x6311, 0),), _INTEGERS, None, False, "100 % is taken as 16384 counts"),
    Role("hold_setpoint", "hold setpoint (CiA 408 0x6314)", ((0x6314, 0),), _SIGNED, None, False,
         "the valve holds at its drive's own HOLD position: check on the bench that it is zero flow"),
)

DYNAMOMETER_ROLES = (
    Role("process_value", "process value (CiA 404 0x9130:01 INTEGER32, 0x6130:01 REAL32 or "
         "0x7130:01 INTEGER16)", ((0x9130, 1), (0x6130, 1), (0x7130, 1)), _NUMBERS, "tpdo", True),
    Role("pv_unit", "physical unit of the process value (CiA 404 0x6131:01, CiA 303-2 coding)",
         ((0x6131, 1),), frozenset({T.UNSIGNED32}), None, False,
         "the unit must be given in the device file (unit = \"kN\")"),
    Role("pv_decimals", "decimal digits of the process value (CiA 404 0x6132:01)", ((0x6132, 1),),
         _BYTE, None, False, "the decimal digits must be given in the device file (decimals = 1)"),
    Role("status", "analog input status (CiA 404 0x6150:01)", ((0x6150, 1),), _BYTE, "tpdo", False,
         "the amplifier's own over-range flags are not received"),
)

ROLES = {VALVE: VALVE_ROLES, DYNAMOMETER: DYNAMOMETER_ROLES}


def role(kind: str, name: str) -> Role:
    for r in ROLES[kind]:
        if r.name == name:
            return r
    raise KeyError(name)


def key_text(key: Key) -> str:
    """``(0x6300, 1)`` → ``"0x6300:01"``; sub-index 0 → ``"0x6040"``."""
    index, sub = key
    return f"0x{index:04X}" + (f":{sub:02X}" if sub else "")
