"""The configuration the gateway gives a node: its PDOs, its error control, its settings, as the
SDO writes of CiA 301 in their order (what CiA 302's configuration manager does at boot).

Per device (:class:`~devices.device.Device`) and node id:

* **the cyclic PDOs**: the valve's command RPDO (control word, setpoint) and its TPDO (status
  word, actual spool position), the amplifier's TPDO (process value, status). A PDO whose
  mapping the EDS lets the master write (``AccessType=rw``: dynamic mapping) is written; a
  static one must already carry the objects the loop needs. A PDO is changed in the order
  CiA 301 asks: COB-ID with bit 31 set (invalid), transmission type, event timer, mapping
  count 0, the entries, the count, COB-ID valid again. TPDOs are synchronous (type 1: one
  answer to every SYNC); the command RPDO asynchronous (255: it acts when it arrives), its
  event timer the valve's own watchdog (the RPDO timeout) where the device has one;
* **the other TPDOs** the device would send are made invalid where it lets the master do so;
* **error control**: the heartbeat producer time (0x1017), or node guarding (guard time 0x100C
  and life time factor 0x100D; CiA 301 forbids using both on one node);
* **settings**: the communication cycle period (0x1006) where the device has it, the valve's
  device mode (0x6042 = 1: setpoint via the bus).

The plan is pure: the master carries it out over SDO (:mod:`gateway.configure`) and
``stand bench dcf`` writes it as a DCF (:mod:`devices.dcf`) without a bus.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from canopen import objectdictionary as od_module

from dbc.pdo_codec import PdoLayout

from .device import (GUARD_TIME, HEARTBEAT_TIME, LIFE_TIME_FACTOR, Device, DeviceError,
                     find_variable)
from .roles import DYNAMOMETER, ROLES, VALVE, Key, key_text

PDO_INVALID = 1 << 31
#: COB-ID bits that are not the identifier (valid, RTR not allowed, 29-bit frame)
_COB_FLAGS = 0xE0000000
COMM_CYCLE_PERIOD, SYNC_WINDOW = 0x1006, 0x1007
#: TPDOs: one answer to every SYNC; the command RPDO: applied when it arrives
TPDO_TRANS_TYPE, RPDO_TRANS_TYPE = 1, 255
#: node guarding: the device's life time = guard time × this (CiA 301 0x100D)
LIFE_TIME_FACTOR_DEFAULT = 3
#: the valve's objects the master sets once where the device has them: role, value, why, and
#: what to do where the device does not let it
VALVE_SETTINGS = (
    ("hold_setpoint", 0, "the hold setpoint: zero flow",
     "check on the bench that the drive's HOLD is zero flow"),
    ("device_mode", 1, "the device mode: setpoint via the bus",
     "set the drive to take its setpoint from the bus by its own tool"),
)
#: a classic CAN frame carries at most 64 bits of data
MAX_PDO_BITS = 64
#: the predefined connection set's PDO COB-IDs (PDOs 1-4) without the node id
_PREDEFINED = {"tpdo": (0x180, 0x280, 0x380, 0x480), "rpdo": (0x200, 0x300, 0x400, 0x500)}
_BASES = {"tpdo": (0x1800, 0x1A00), "rpdo": (0x1400, 0x1600)}


@dataclass(frozen=True)
class SdoWrite:
    """One SDO download of the plan: ``index:sub = value`` and why."""

    index: int
    sub: int
    value: int
    what: str

    def text(self) -> str:
        return f"0x{self.index:04X}:{self.sub:02X} = 0x{self.value:X} ({self.what})"


@dataclass(frozen=True)
class PdoSetup:
    """One PDO as the run needs it: which, its COB-ID, transmission type and entries
    ``(index, sub, bits, data type)``; ``writes``: what the master writes to get it (empty for
    a PDO the device has as needed and does not let the master change)."""

    direction: str
    number: int
    cob_id: int
    trans_type: int
    entries: tuple[tuple[int, int, int, int], ...]
    dynamic: bool
    writes: tuple[SdoWrite, ...]
    event_timer_ms: int | None = None

    @property
    def name(self) -> str:
        return f"{self.direction.upper()}{self.number}"

    @property
    def com_index(self) -> int:
        return _BASES[self.direction][0] + self.number - 1

    @property
    def map_index(self) -> int:
        return _BASES[self.direction][1] + self.number - 1

    @property
    def keys(self) -> tuple[Key, ...]:
        return tuple((i, s) for i, s, _, _ in self.entries)

    def layout(self) -> PdoLayout:
        return PdoLayout.from_entries(self.cob_id, list(self.entries))

    def describe(self) -> dict:
        return {"pdo": self.name, "cob_id": self.cob_id, "transmission_type": self.trans_type,
                "mapping": "dynamic" if self.dynamic else "static",
                "objects": [key_text((i, s)) for i, s, _, _ in self.entries],
                "event_timer_ms": self.event_timer_ms}


@dataclass(frozen=True)
class NodePlan:
    """What the master sets on one node, in order: ``settings`` (error control, period, mode),
    each PDO's writes, then ``disable`` (the TPDOs the run does not use)."""

    device: Device
    node_id: int
    tpdo: PdoSetup
    rpdo: PdoSetup | None
    settings: tuple[SdoWrite, ...]
    disable: tuple[SdoWrite, ...]
    notes: tuple[str, ...] = field(default=())

    @property
    def kind(self) -> str:
        return self.device.kind

    def writes(self) -> list[SdoWrite]:
        out = list(self.settings)
        for pdo in (self.rpdo, self.tpdo):
            if pdo is not None:
                out += pdo.writes
        return out + list(self.disable)

    def describe(self) -> dict:
        return {"node_id": self.node_id, "device": self.device.name,
                "error_control": self.device.error_control,
                "pdos": [p.describe() for p in (self.rpdo, self.tpdo) if p is not None],
                "notes": list(self.notes)}


def _writable(od, key: Key) -> bool:
    var = find_variable(od, key)
    return var is not None and var.writable


def _pdo_default_entries(od, direction: str, n: int) -> list[tuple[int, int, int, int]]:
    """The mapping a PDO has by default (its EDS), as entries; objects the EDS lacks are
    refused (the device would not send them either)."""
    map_index = _BASES[direction][1] + n - 1
    count = find_variable(od, (map_index, 0))
    out = []
    for sub in range(1, int(count.default or 0) + 1 if count is not None else 1):
        entry = find_variable(od, (map_index, sub))
        value = int(entry.default or 0) if entry is not None else 0
        index, subindex, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
        if bits == 0:
            continue
        var = find_variable(od, (index, subindex))
        if var is None:
            if 0x0001 <= index <= 0x0007:     # a dummy entry (CiA 301: data types as gaps)
                out.append((index, subindex, bits, index))
                continue
            raise DeviceError(f"{direction.upper()}{n}'s default mapping names "
                              f"{key_text((index, subindex))}, which the EDS does not describe")
        out.append((index, subindex, bits, var.data_type))
    return out


def _is_dynamic(od, direction: str, n: int, entries: int) -> bool:
    map_index = _BASES[direction][1] + n - 1
    return all(_writable(od, (map_index, s)) for s in range(0, entries + 1))


def _pdo_numbers(od, direction: str) -> list[int]:
    com, mapping = _BASES[direction]
    return [n for n in range(1, 513) if com + n - 1 in od and mapping + n - 1 in od]


def _cob_id(od, direction: str, n: int, node_id: int, where: str) -> int:
    var = find_variable(od, (_BASES[direction][0] + n - 1, 1))
    default = int(var.default or 0) if var is not None else 0
    cob = default & ~_COB_FLAGS
    if cob == 0:
        if n <= 4:
            return _PREDEFINED[direction][n - 1] + node_id
        raise DeviceError(f"{where}: {direction.upper()}{n} has no default COB-ID in the EDS "
                          "(and PDOs above 4 have none in the predefined connection set); choose "
                          f"{direction} 1-4 in the device file")
    return cob


def _plan_pdo(device: Device, od, node_id: int, direction: str, roles: list[str],
              chosen: int | None, event_timer_ms: int | None, notes: list[str]) -> PdoSetup:
    """The PDO of ``direction`` carrying ``roles`` (the required ones must be in it)."""
    where = f"{device.where}: {device.kind} node {node_id}"
    required = [device.key(r) for r in roles if _role(device, r).required]
    optional = [(r, device.key(r)) for r in roles
                if not _role(device, r).required and device.key(r) is not None]
    wanted = required + [k for _, k in optional]
    numbers = _pdo_numbers(od, direction)
    if not numbers:
        raise DeviceError(f"{where}: {device.eds.name} describes no {direction.upper()} "
                          f"(0x{_BASES[direction][0]:04X}/0x{_BASES[direction][1]:04X})")
    defaults = {}

    def default(n: int):
        if n not in defaults:
            try:
                defaults[n] = _pdo_default_entries(od, direction, n)
            except DeviceError as exc:
                raise DeviceError(f"{where}: {exc}") from None
        return defaults[n]

    if chosen is None:        # a PDO that already carries them, else the first that can be mapped
        carrying = [n for n in numbers if set(required) <= {(i, s) for i, s, _, _ in default(n)}]
        dynamic = [n for n in numbers if _is_dynamic(od, direction, n, len(wanted))]
        if carrying:
            chosen = carrying[0]
        elif dynamic:
            chosen = dynamic[0]
        else:
            raise DeviceError(
                f"{where}: no {direction.upper()} of {device.eds.name} can carry the "
                f"{' and '.join(_role(device, r).what for r in roles if _role(device, r).required)}: "
                "their mappings are static and none maps them; name the objects the device "
                "does map in the device file, or choose another device")
    dynamic = _is_dynamic(od, direction, chosen, len(wanted))
    com, mapping = _BASES[direction][0] + chosen - 1, _BASES[direction][1] + chosen - 1
    name = f"{direction.upper()}{chosen}"
    if dynamic:
        entries = []
        bits = 0
        for key in wanted:
            var = find_variable(od, key)
            size = len(var)
            if bits + size > MAX_PDO_BITS:
                if key in required:
                    raise DeviceError(f"{where}: the objects of {name} need more than "
                                      f"{MAX_PDO_BITS} bits; choose smaller objects")
                role_name = next(r for r, k in optional if k == key)
                notes.append(f"{name} has no room for the {_role(device, role_name).what} "
                             f"(over {MAX_PDO_BITS} bits): {_role(device, role_name).without}")
                continue
            bits += size
            entries.append((key[0], key[1], size, var.data_type))
    else:
        entries = default(chosen)
        have = {(i, s) for i, s, _, _ in entries}
        missing = [k for k in required if k not in have]
        if missing:
            raise DeviceError(f"{where}: {name}'s mapping is static (the EDS does not let the "
                              f"master write 0x{mapping:04X}) and does not map "
                              f"{', '.join(key_text(k) for k in missing)}, which the loop needs; "
                              f"choose another {direction} in the device file")
        for r, k in optional:
            if k not in have:
                notes.append(f"{name}'s static mapping does not carry the {_role(device, r).what}: "
                             f"{_role(device, r).without}")
    cob_id = _cob_id(od, direction, chosen, node_id, where)
    trans = TPDO_TRANS_TYPE if direction == "tpdo" else RPDO_TRANS_TYPE
    writes: list[SdoWrite] = []
    comm_writable = _writable(od, (com, 1))
    if comm_writable:
        writes.append(SdoWrite(com, 1, cob_id | PDO_INVALID, f"{name} COB-ID, invalid while it changes"))
    elif dynamic:
        raise DeviceError(f"{where}: {name}'s COB-ID (0x{com:04X}:01) is read-only, so its "
                          "mapping cannot be changed as CiA 301 asks; choose another PDO")
    tt_var = find_variable(od, (com, 2))
    if tt_var is not None and tt_var.writable:
        writes.append(SdoWrite(com, 2, trans, f"{name} transmission type"))
    else:
        have_tt = int(tt_var.default) if tt_var is not None and tt_var.default is not None else None
        if direction == "tpdo" and have_tt != TPDO_TRANS_TYPE:
            raise DeviceError(f"{where}: {name} has transmission type {have_tt} and the device "
                              "does not let the master change it; the loop needs one answer to "
                              "every SYNC (type 1)")
        if direction == "rpdo" and have_tt is not None and have_tt <= 240:
            notes.append(f"{name} is synchronous (type {have_tt}) and cannot be changed: each "
                         "command acts from the next SYNC, one period later")
        trans = have_tt if have_tt is not None else trans
    timer = None
    if direction == "rpdo":
        timer_var = find_variable(od, (com, 5))
        if event_timer_ms and timer_var is not None and timer_var.writable:
            timer = int(event_timer_ms)
            writes.append(SdoWrite(com, 5, timer, f"{name} event timer: the valve's RPDO timeout, ms"))
        elif event_timer_ms:
            notes.append(f"{name} has no writable event timer (0x{com:04X}:05): no RPDO timeout"
                         + (": its life guarding brings it to its safe state when the master "
                            "stops guarding it" if device.error_control == "guarding" else
                            ": the valve cannot detect by itself that commands stopped"))
    if dynamic:
        writes.append(SdoWrite(mapping, 0, 0, f"{name} mapping: none while it changes"))
        for sub, (index, subindex, size, _) in enumerate(entries, 1):
            writes.append(SdoWrite(mapping, sub, index << 16 | subindex << 8 | size,
                                   f"{name} mapping entry {sub}: {key_text((index, subindex))}"))
        writes.append(SdoWrite(mapping, 0, len(entries), f"{name} mapping: {len(entries)} entr{'y' if len(entries) == 1 else 'ies'}"))
    if comm_writable:
        writes.append(SdoWrite(com, 1, cob_id, f"{name} COB-ID, valid"))
    return PdoSetup(direction, chosen, cob_id, trans, tuple(entries), dynamic, tuple(writes), timer)


def _role(device: Device, name: str):
    return next(r for r in ROLES[device.kind] if r.name == name)


def plan_node(device: Device, node_id: int, *, period_s: float, heartbeat_ms: int,
              rpdo_timeout_ms: int = 0, life_time_factor: int = LIFE_TIME_FACTOR_DEFAULT,
              od: od_module.ObjectDictionary | None = None) -> NodePlan:
    """The configuration of ``device`` at ``node_id`` for a run at ``period_s`` with error
    control every ``heartbeat_ms`` (heartbeat producer time, or the guard time, with a life
    time of ``life_time_factor`` guard times) and the valve's RPDO timeout ``rpdo_timeout_ms``
    (0: none). :class:`DeviceError` when the device cannot be given what the loop needs."""
    od = od if od is not None else device.od(node_id)
    notes = list(device.notes)
    if device.kind == VALVE:
        rpdo = _plan_pdo(device, od, node_id, "rpdo", ["control_word", "setpoint"], device.rpdo,
                         rpdo_timeout_ms, notes)
        tpdo = _plan_pdo(device, od, node_id, "tpdo", ["status_word", "actual_spool"], device.tpdo,
                         None, notes)
    else:
        rpdo = None
        tpdo = _plan_pdo(device, od, node_id, "tpdo", ["process_value", "status"], device.tpdo,
                         None, notes)
    settings: list[SdoWrite] = []
    if device.error_control == "heartbeat":
        settings.append(SdoWrite(HEARTBEAT_TIME, 0, int(heartbeat_ms), "heartbeat producer time, ms"))
    else:
        if HEARTBEAT_TIME in od and _writable(od, (HEARTBEAT_TIME, 0)):
            settings.append(SdoWrite(HEARTBEAT_TIME, 0, 0, "no heartbeat: node guarding is used"))
        settings.append(SdoWrite(GUARD_TIME, 0, int(heartbeat_ms), "guard time, ms"))
        settings.append(SdoWrite(LIFE_TIME_FACTOR, 0, int(life_time_factor), "life time factor"))
    if COMM_CYCLE_PERIOD in od and _writable(od, (COMM_CYCLE_PERIOD, 0)):
        settings.append(SdoWrite(COMM_CYCLE_PERIOD, 0, int(round(period_s * 1e6)),
                                 "communication cycle period, µs"))
    else:
        notes.append("no communication cycle period (0x1006): the device is not told the period")
    for role, value, what, otherwise in VALVE_SETTINGS if device.kind == VALVE else ():
        key = device.key(role)
        if key is None:
            continue
        if _writable(od, key):
            settings.append(SdoWrite(key[0], key[1], value, what))
        else:
            notes.append(f"{what.split(':')[0]} ({key_text(key)}) is read-only: {otherwise}")
    disable = []
    used = tpdo.number
    for n in _pdo_numbers(od, "tpdo"):
        if n == used:
            continue
        var = find_variable(od, (0x1800 + n - 1, 1))
        default = int(var.default or 0) if var is not None else PDO_INVALID
        if default & PDO_INVALID:
            continue
        if var.writable:
            disable.append(SdoWrite(0x1800 + n - 1, 1, default | PDO_INVALID,
                                    f"TPDO{n} not used: invalid"))
        else:
            notes.append(f"TPDO{n} is sent too and cannot be switched off (its COB-ID is "
                         "read-only): its frames are counted and dropped by the gateway")
    return NodePlan(device, node_id, tpdo, rpdo, tuple(settings), tuple(disable), tuple(notes))


def channel_pdo_bytes(plans: "list[NodePlan]") -> dict[str, int]:
    """What one channel's cyclic PDOs carry, in bytes: the valve's command, its status and the
    force (the bus budget's figures)."""
    valve = next(p for p in plans if p.kind == VALVE)
    dyn = next(p for p in plans if p.kind == DYNAMOMETER)
    return {"valve command": valve.rpdo.layout().size, "valve status": valve.tpdo.layout().size,
            "force": dyn.tpdo.layout().size}
