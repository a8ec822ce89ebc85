"""A device file: which maker's device a node is, from its EDS, and which of its objects play
the roles the loop needs (:mod:`devices.roles`).

A device set names the two devices of a loading channel, each with its EDS (or DCF) and,
where the device differs from its CiA profile, a short role table::

    name = "Servotek SVD-40 with LCA-4 amplifier"

    [valve]                          # the servo-valve drive, CiA 408
    eds = "svd40.eds"                # relative to this file
    revision = "2.0-2.9"             # accepted revisions, major.minor (default: any)
    rpdo = 2                         # the RPDO for the command (default: the first that can)
    tpdo = 2                         # the TPDO for status and spool (default: likewise)
    actual_spool = "0x6301:01"       # a role's object, where it is not the profile's;
                                     # "none" for an optional role the device lacks

    [dynamometer]                    # the force amplifier, CiA 404
    eds = "lca4.eds"
    process_value = "0x9130:01"      # default: 0x9130:01, 0x6130:01 or 0x7130:01, the first it has
    unit = "kgf"                     # default: read from 0x6131 at start-up
    decimals = 1                     # default: read from 0x6132 at start-up

The keys of each table: ``eds``, ``revision``, ``error_control`` (``heartbeat`` or
``guarding``; default: heartbeat where the EDS has 0x1017, else node guarding), ``rpdo`` and
``tpdo`` (PDO numbers, 1-based), the roles' names, and the scaling (the valve's
``setpoint_full_scale``, counts at 100 %, default 0x6311 or 16384; the amplifier's ``unit``
and ``decimals``). Every mistake is one :class:`DeviceError` naming the file, the table and
what to do.
"""
from __future__ import annotations

import functools
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import canopen
from canopen import objectdictionary as od_module

from core.errors import ParameterError
from core.tomlfile import read_toml
from dbc import DYNAMOMETER_EDS, VALVE_EDS

from .roles import (DEVICE_KINDS, DYNAMOMETER, PROFILE_NAMES, ROLES, TYPE_NAMES, VALVE, Key,
                    Role, key_text)
from .units import FORCE_UNITS, kgf_per_count, unit_name_of_code

#: error control: the device's heartbeat (0x1017) or node guarding (0x100C/0x100D)
ERROR_CONTROLS = ("heartbeat", "guarding")
HEARTBEAT_TIME, GUARD_TIME, LIFE_TIME_FACTOR = 0x1017, 0x100C, 0x100D
#: an object as CANopen writes it, in hex: "0x6300:01", "6300:1", "0x6040"
_OBJECT_RE = re.compile(r"^\s*(?:0x)?([0-9A-Fa-f]{4})\s*(?::\s*(?:0x)?([0-9A-Fa-f]{1,2}))?\s*$")
_REVISION_RE = re.compile(r"^\s*(\d+)(?:\.(\d+))?\s*(?:-\s*(\d+)(?:\.(\d+))?)?\s*$")
_BITS = {od_module.INTEGER8: 8, od_module.UNSIGNED8: 8, od_module.INTEGER16: 16,
         od_module.UNSIGNED16: 16, od_module.INTEGER32: 32, od_module.UNSIGNED32: 32,
         od_module.REAL32: 32}
_TABLE_KEYS = {"eds", "revision", "error_control", "rpdo", "tpdo"}
_SCALING_KEYS = {VALVE: {"setpoint_full_scale"}, DYNAMOMETER: {"unit", "decimals"}}


class DeviceError(ParameterError):
    """A device file (or the device it describes) cannot be used; the message names the file,
    the table and what to do."""


@dataclass(frozen=True)
class RevisionRange:
    """Accepted revisions of 0x1018:03 (major in the high 16 bits, minor in the low 16)."""

    low: int
    high: int
    text: str

    @classmethod
    def parse(cls, text: str, where: str) -> "RevisionRange":
        m = _REVISION_RE.match(str(text))
        if not m:
            raise DeviceError(f"{where}: revision = {text!r}: write MAJOR.MINOR or a range "
                              "MAJOR.MINOR-MAJOR.MINOR, e.g. \"2.0-2.9\" (a bare MAJOR accepts "
                              "every minor revision of it)")
        a, b, c, d = m.groups()
        low = int(a) << 16 | (int(b) if b is not None else 0)
        if c is None:
            high = int(a) << 16 | (int(b) if b is not None else 0xFFFF)
        else:
            high = int(c) << 16 | (int(d) if d is not None else 0xFFFF)
        if not (int(a) <= 0xFFFF and (c is None or int(c) <= 0xFFFF)) or low > high:
            raise DeviceError(f"{where}: revision = {text!r}: the range is empty or out of "
                              "16 bits; write it low-high, e.g. \"2.0-2.9\"")
        return cls(low, high, str(text).strip())

    def __contains__(self, revision: int) -> bool:
        return self.low <= revision <= self.high


def revision_text(revision: int | None) -> str:
    if revision is None:
        return "?"
    return f"{revision >> 16}.{revision & 0xFFFF}"


@dataclass(frozen=True)
class Identity:
    """What 0x1018 says of a device: vendor, product, revision (and the names of the EDS)."""

    vendor: int
    product: int
    revision: int | None = None
    vendor_name: str = ""
    product_name: str = ""

    def text(self) -> str:
        name = " ".join(n for n in (self.vendor_name, self.product_name) if n)
        return (f"{name + ' ' if name else ''}(vendor 0x{self.vendor:08X}, product "
                f"0x{self.product:08X}, revision {revision_text(self.revision)})")


@dataclass(frozen=True)
class Device:
    """One device of a channel as its file describes it, its roles resolved against its EDS.

    ``objects``: each role's object, None for an optional role the device lacks; ``types``:
    their CANopen data types."""

    kind: str
    eds: Path
    where: str
    identity: Identity
    objects: Mapping[str, Key | None]
    types: Mapping[str, int]
    error_control: str
    revisions: RevisionRange | None = None
    rpdo: int | None = None
    tpdo: int | None = None
    #: the valve: counts at 100 % given in the file (None: 0x6311, else 16384)
    setpoint_full_scale: int | None = None
    #: the amplifier: unit and decimals given in the file (None: read from the device)
    unit: str | None = None
    decimals: int | None = None
    #: what the device lacks and what the run then cannot do
    notes: tuple[str, ...] = field(default=())

    @property
    def name(self) -> str:
        return self.identity.product_name or self.eds.stem

    def od(self, node_id: int) -> od_module.ObjectDictionary:
        """The device's object dictionary for ``node_id`` (a fresh copy: callers may set values)."""
        return canopen.import_od(str(self.eds), node_id)

    def key(self, role: str) -> Key | None:
        return self.objects.get(role)

    def nominal_kgf_per_count(self) -> float:
        """An amplifier's kgf per count as its file says, else as its EDS's defaults of
        0x6131/0x6132 say (offline: the device itself may say otherwise at start-up)."""
        od = self.od(1)
        unit = self.unit
        if unit is None:
            unit = unit_name_of_code(int(find_variable(od, self.key("pv_unit")).default))
        decimals = self.decimals
        if decimals is None:
            key = self.key("pv_decimals")
            decimals = int(find_variable(od, key).default) if key is not None else 0
        return kgf_per_count(unit, decimals, self.types["process_value"] != od_module.REAL32)

    def type_bits(self, role: str) -> int:
        """The size of a role's object, bits."""
        return _BITS[self.types[role]]

    def describe(self) -> dict[str, Any]:
        """For run.json and ``stand bench``: the file, the identity, the roles' objects."""
        return {"file": self.where, "eds": str(self.eds), "name": self.name,
                "vendor": self.identity.vendor, "product": self.identity.product,
                "revisions": self.revisions.text if self.revisions else None,
                "error_control": self.error_control,
                "objects": {r: key_text(k) if k else None for r, k in self.objects.items()}}


@dataclass(frozen=True)
class DeviceSet:
    """The two devices of a loading channel."""

    name: str
    valve: Device
    dynamometer: Device
    path: Path | None = None

    def device(self, kind: str) -> Device:
        return self.valve if kind == VALVE else self.dynamometer

    @property
    def is_default(self) -> bool:
        return self.path is None

    @property
    def where(self) -> str:
        return str(self.path) if self.path is not None else "the emulated devices (dbc/)"

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "file": str(self.path) if self.path else None,
                VALVE: self.valve.describe(), DYNAMOMETER: self.dynamometer.describe()}


# -- reading ------------------------------------------------------------------------------------
def read_eds(path: Path, where: str, node_id: int = 1) -> od_module.ObjectDictionary:
    """The EDS (or DCF) at ``path`` as canopen reads it; a :class:`DeviceError` saying why not."""
    if not path.is_file():
        raise DeviceError(f"{where}: the EDS {path} does not exist (a path relative to the "
                          "device file)")
    if path.suffix.lower() not in (".eds", ".dcf"):
        raise DeviceError(f"{where}: {path.name} is not an EDS or DCF file (CiA 306 .eds/.dcf; "
                          "an XDD must be converted to an EDS first, e.g. with the maker's tool)")
    try:
        return canopen.import_od(str(path), node_id)
    except Exception as exc:    # configparser, ValueError, KeyError: a file canopen cannot read
        text = str(exc).replace("\n", " ")
        raise DeviceError(f"{where}: the EDS {path} cannot be read ({type(exc).__name__}: "
                          f"{text}); check it against CiA 306 (every object needs ParameterName, "
                          "ObjectType, DataType, AccessType; [DeviceInfo] is mandatory)") from None


def parse_object(text: Any, where: str) -> Key | None:
    """``"0x6300:01"`` → ``(0x6300, 1)``, ``"0x6040"`` → ``(0x6040, 0)``, ``"none"`` → None
    (index and sub-index in hex, as CANopen writes them)."""
    if isinstance(text, str) and text.strip().lower() == "none":
        return None
    if isinstance(text, int) and not isinstance(text, bool):
        index, sub = text, 0
    else:
        m = _OBJECT_RE.match(str(text)) if isinstance(text, str) else None
        if not m:
            raise DeviceError(f"{where}: {text!r} is not an object: write \"0xINDEX:SUB\" in hex "
                              "(e.g. \"0x6300:01\"), \"0xINDEX\" for sub-index 0, or \"none\"")
        index = int(m.group(1), 16)
        sub = int(m.group(2), 16) if m.group(2) else 0
    if not (0x1000 <= index <= 0xFFFF and 0 <= sub <= 0xFF):
        raise DeviceError(f"{where}: object {text!r} is out of range (index 0x1000-0xFFFF, "
                          "sub-index 0-0xFF)")
    return index, sub


def find_variable(od: od_module.ObjectDictionary, key: Key) -> od_module.ODVariable | None:
    """The object dictionary's entry for ``key``, None if the device has no such object."""
    index, sub = key
    if index not in od:
        return None
    obj = od[index]
    if isinstance(obj, od_module.ODVariable):
        return obj if sub == 0 else None
    return obj[sub] if sub in obj else None


def _resolve_role(role: Role, given: Any, od, where: str, eds: Path) -> tuple[Key | None, int | None]:
    """The role's object and data type: the one given, else the first of the profile's the
    device has; None for an optional role the device lacks."""
    what = f"{where}: {role.name}"
    if given is not None:
        key = parse_object(given, what)
        if key is None:
            if role.required:
                raise DeviceError(f"{what} = \"none\": the loop cannot run without the "
                                  f"{role.what}; name the device's object for it")
            return None, None
        candidates: tuple[Key, ...] = (key,)
    else:
        candidates = role.candidates
    for key in candidates:
        var = find_variable(od, key)
        if var is None:
            if given is not None:
                raise DeviceError(f"{what} = \"{key_text(key)}\": {eds.name} has no such object; "
                                  "name one the EDS has (its sections [IIII] and [IIIIsubS])")
            continue
        if given is None and not role.required and not _fits(role, var):
            continue          # the profile's object, but not usable for the role here: absent
        if var.data_type not in role.types:
            raise DeviceError(
                f"{what}: {key_text(key)} in {eds.name} is {TYPE_NAMES.get(var.data_type, var.data_type)}, "
                f"which cannot carry the {role.what} (it must be {role.type_names()}); name "
                "another object in the device file")
        if role.pdo is not None and not var.pdo_mappable:
            raise DeviceError(f"{what}: {key_text(key)} in {eds.name} cannot be mapped to a PDO "
                              f"(PDOMapping=0), but the {role.what} goes in one every cycle")
        if role.pdo == "rpdo" and not var.writable:
            raise DeviceError(f"{what}: {key_text(key)} in {eds.name} is read-only "
                              f"(AccessType={var.access_type}), but the gateway writes the "
                              f"{role.what} every cycle")
        if role.pdo == "tpdo" and not var.readable:
            raise DeviceError(f"{what}: {key_text(key)} in {eds.name} is write-only "
                              f"(AccessType={var.access_type}), but the device sends the "
                              f"{role.what} every cycle")
        return key, var.data_type
    if role.required:
        raise DeviceError(f"{where}: {eds.name} has none of the objects of the {role.what} "
                          f"({', '.join(key_text(k) for k in role.candidates)}); name the "
                          f"device's object: {role.name} = \"0xINDEX:SUB\"")
    return None, None


def _fits(role: Role, var) -> bool:
    """The object can play the role: its type, and for a PDO role mappable the right way."""
    return (var.data_type in role.types
            and (role.pdo is None or bool(var.pdo_mappable))
            and (role.pdo != "rpdo" or var.writable) and (role.pdo != "tpdo" or var.readable))


def _int(value: Any, what: str, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise DeviceError(f"{what} = {value!r}: give a whole number {low}..{high}")
    return value


def device_from_mapping(kind: str, table: Mapping[str, Any], where: str,
                        base_dir: Path | None = None) -> Device:
    """A :class:`Device` of ``kind`` from its table of a device file (see the module doc)."""
    if not isinstance(table, Mapping):
        raise DeviceError(f"{where}: [{kind}] must be a table with eds = \"FILE.eds\"")
    roles = ROLES[kind]
    known = (_TABLE_KEYS - ({"rpdo"} if kind != VALVE else set())) | {r.name for r in roles} \
        | _SCALING_KEYS[kind]
    unknown = set(table) - known
    if unknown:
        raise DeviceError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}; [{kind}] "
                          f"takes {', '.join(sorted(known))}")
    if "eds" not in table or not isinstance(table["eds"], str):
        raise DeviceError(f"{where}: [{kind}] needs eds = \"FILE.eds\", the {PROFILE_NAMES[kind]}'s "
                          "electronic data sheet from its maker")
    eds = Path(table["eds"]).expanduser()
    if not eds.is_absolute() and base_dir is not None:
        eds = base_dir / eds
    od = read_eds(eds, where)
    objects: dict[str, Key | None] = {}
    types: dict[str, int] = {}
    for role in roles:
        key, dtype = _resolve_role(role, table.get(role.name), od, where, eds)
        objects[role.name] = key
        if key is not None:
            types[role.name] = dtype
    given = {"pv_unit": "unit" in table, "pv_decimals": "decimals" in table}   # the file's own
    notes = tuple(f"{role.what} is missing: {role.without}" for role in roles
                  if objects[role.name] is None and not role.required and not given.get(role.name))
    info = od.device_information
    vendor = info.vendor_number if info.vendor_number is not None else _default(od, (0x1018, 1))
    product = info.product_number if info.product_number is not None else _default(od, (0x1018, 2))
    if vendor is None or product is None:
        raise DeviceError(f"{where}: {eds.name} states no vendor and product (VendorNumber and "
                          "ProductNumber in [DeviceInfo], or 0x1018 defaults): the gateway "
                          "could not tell the device from another at start-up")
    revision = info.revision_number if info.revision_number is not None else _default(od, (0x1018, 3))
    identity = Identity(vendor, product, revision, info.vendor_name or "", info.product_name or "")
    revisions = (RevisionRange.parse(table["revision"], f"{where}: revision")
                 if "revision" in table else None)
    error_control = _error_control(table.get("error_control"), od, where, eds)
    rpdo = tpdo = None
    if "rpdo" in table:           # (the valve's only: the amplifier receives no PDO)
        rpdo = _pdo_number(table["rpdo"], od, 0x1400, f"{where}: rpdo", eds)
    if "tpdo" in table:
        tpdo = _pdo_number(table["tpdo"], od, 0x1800, f"{where}: tpdo", eds)
    full = None
    if "setpoint_full_scale" in table:
        full = _int(table["setpoint_full_scale"], f"{where}: setpoint_full_scale", 1, 2**31 - 1)
    unit = decimals = None
    if kind == DYNAMOMETER:
        if "unit" in table:
            unit = table["unit"]
            if unit not in FORCE_UNITS:
                raise DeviceError(f"{where}: unit = {unit!r}: use one of {', '.join(FORCE_UNITS)}")
        elif objects["pv_unit"] is None:
            raise DeviceError(f"{where}: {eds.name} has no unit object (0x6131): give the process "
                              "value's unit in the device file, e.g. unit = \"kN\"")
        if "decimals" in table:
            decimals = _int(table["decimals"], f"{where}: decimals", 0, 9)
        elif objects["pv_decimals"] is None and types["process_value"] != od_module.REAL32:
            raise DeviceError(f"{where}: {eds.name} has no decimal digits object (0x6132): give "
                              "them in the device file, e.g. decimals = 1")
    return Device(kind, eds, where, identity, objects, types, error_control, revisions, rpdo,
                  tpdo, full, unit, decimals, notes)


def _default(od, key: Key):
    var = find_variable(od, key)
    return None if var is None else var.default


def _error_control(given: Any, od, where: str, eds: Path) -> str:
    heartbeat = HEARTBEAT_TIME in od
    guarding = GUARD_TIME in od and LIFE_TIME_FACTOR in od
    if given is None:
        if heartbeat:
            return "heartbeat"
        if guarding:
            return "guarding"
        raise DeviceError(f"{where}: {eds.name} has neither a heartbeat producer (0x1017) nor "
                          "node guarding (0x100C, 0x100D): the gateway could not tell it is alive")
    if given not in ERROR_CONTROLS:
        raise DeviceError(f"{where}: error_control = {given!r}: use \"heartbeat\" or \"guarding\"")
    if given == "heartbeat" and not heartbeat:
        raise DeviceError(f"{where}: error_control = \"heartbeat\" but {eds.name} has no 0x1017; "
                          "use \"guarding\" (node guarding, 0x100C/0x100D)")
    if given == "guarding" and not guarding:
        raise DeviceError(f"{where}: error_control = \"guarding\" but {eds.name} lacks 0x100C or "
                          "0x100D; use \"heartbeat\"")
    return given


def _pdo_number(value: Any, od, base: int, where: str, eds: Path) -> int:
    n = _int(value, where, 1, 512)
    if base + n - 1 not in od or base + 0x200 + n - 1 not in od:
        have = [i - base + 1 for i in range(base, base + 512) if i in od]
        kind = "RPDO" if base == 0x1400 else "TPDO"
        raise DeviceError(f"{where} = {n}: {eds.name} has no {kind}{n} (0x{base + n - 1:04X} and "
                          f"0x{base + 0x200 + n - 1:04X}); it has {kind}s "
                          f"{', '.join(map(str, have)) or 'none'}")
    return n


def load_device_set(path: str | Path) -> DeviceSet:
    """The device set a file describes (see the module doc); :class:`DeviceError` if it
    cannot be used."""
    path = Path(path)
    data = read_toml(path, DeviceError)
    return device_set_from_mapping(data, str(path), path.parent, path)


def device_set_from_mapping(data: Mapping[str, Any], where: str, base_dir: Path | None = None,
                            path: Path | None = None) -> DeviceSet:
    unknown = set(data) - {"name", *DEVICE_KINDS}
    if unknown:
        raise DeviceError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}; a device file "
                          "has name, [valve] and [dynamometer]")
    for kind in DEVICE_KINDS:
        if kind not in data:
            raise DeviceError(f"{where}: no [{kind}] table: a device set names the valve drive "
                              "([valve], CiA 408) and the force amplifier ([dynamometer], CiA 404)")
    valve = device_from_mapping(VALVE, data[VALVE], f"{where} [valve]", base_dir)
    dyn = device_from_mapping(DYNAMOMETER, data[DYNAMOMETER], f"{where} [dynamometer]", base_dir)
    name = str(data.get("name", f"{valve.name} with {dyn.name}"))
    return DeviceSet(name, valve, dyn, path)


@functools.lru_cache(maxsize=1)
def default_devices() -> DeviceSet:
    """The emulated valve drive and dynamometer this project ships (dbc/): the devices a stand
    has when no device file is given."""
    valve = device_from_mapping(VALVE, {"eds": str(VALVE_EDS)}, "dbc/servo_valve.eds")
    dyn = device_from_mapping(DYNAMOMETER, {"eds": str(DYNAMOMETER_EDS)}, "dbc/dynamometer.eds")
    return DeviceSet("hydrostand emulated devices", valve, dyn, None)
