"""A rig file: the loading channels of one test, the CAN buses they are on, and the structure
that couples them (``rig.toml``).

A channel is what the one-channel stand is: a servo-valve drive (CiA 408) and a dynamometer
(CiA 404), each a node on one bus. The structure couples the channels' force rates,
``dy/dt = G·w(t − τ) + Δ`` (``w_i`` is channel i's flow after its own valve and flow effects, ``G``
N×N in kgf/(%·s), ``G_ii`` the paper's g of channel i); a file gives either ``G`` or the
structure's stiffness at the attachment points ``K`` (kgf/mm, symmetric) with each actuator's flow
gain ``c_i/A_i`` (mm/(%·s)), ``G = K·diag(c/A)`` (../shared/notes/rig.md)::

    name = "wing box, 4 channels"
    period_ms = 2.0                  # the control period (default 2)
    bus_load_limit_pct = 70          # a bus may be loaded this much (default 70)

    [[bus]]
    name = "can0"
    spec = "udp_loopback:rig-can0"   # any python-can bus: socketcan:can0, pcan:PCAN_USBBUS1, ...
    bitrate = 1000000                # bit/s (default 1 Mbit/s)
    # fd = true                      # CAN FD, with data_bitrate = 2000000

    devices = "devices/servotek.toml"  # the channels' devices (default: the emulated pair;
                                     # docs/devices.md), a channel may name its own

    [[channel]]
    name = "root_left"
    bus = "can0"
    valve_id = 1
    dynamometer_id = 2
    range_kgf = 10000                # the dynamometer's range (default 10000)
    force_limit_kgf = 9000           # the supervisor's limit (default 95 % of the range)
    [channel.plant]                  # the emulated plant (stand emulate --rig), as a plant file:
    model = "base+reversal"          # [base] tau, delta (g comes from the structure), [effects.*],
    [channel.plant.base]             # [sensor], [initial]; or plant = "root_left.toml"
    tau = 0.05

    [structure]
    G = [[120, 36, 0, 0], [36, 120, 36, 0], [0, 36, 120, 36], [0, 0, 36, 120]]

    [[structure.change]]             # the emulated structure changes (a crack), optional:
    channel = "root_left"            # at this channel's attachment point
    stiffness_factor = 0.97          # its own stiffness K_ii times this (< 1: softer)
    from_s = 600.0                   # from this stand time (s)
    ramp_s = 0.0                     # at once (0), or linearly over this long (s)

Only the emulator reads the plants and the structure's changes
(:class:`plant.rig.StructureChange`: a compliance in series at the attachment point, so its
row and column of K and of G fall by the factor; ``stand emulate --rig --change`` adds
more); a rig file for a bench needs none (the structure is then
what the user believes, and ``stand rig check`` checks it). Everything is checked on load: a
mistake is one :class:`RigError` naming the file, the table and what to do.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from core.errors import ParameterError
from devices import DeviceError, DeviceSet, default_devices, load_device_set
from plant.config import PlantConfig, plant_config_from_mapping, read_toml
from plant.params import ModelError
from plant.rig import StructureChange, changed_structure
from standbus.spec import BusSpec, BusSpecError

#: what a bus may be loaded to, by default (CiA and bus vendors advise 60-80 % for cyclic traffic)
DEFAULT_LOAD_LIMIT = 0.70
DEFAULT_PERIOD_S = 0.002
DEFAULT_BITRATE = 1_000_000
DEFAULT_RANGE_KGF = 10_000.0
#: the force limit's default share of the dynamometer's range
DEFAULT_LIMIT_SHARE = 0.95
NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_-]*$")


class RigError(ParameterError):
    """A rig file cannot be used; the message names the file, the table and what to do."""


@dataclass(frozen=True)
class BusConfig:
    """One CAN bus of the rig."""

    name: str
    spec: str                      #: a python-can bus as ``INTERFACE:CHANNEL[,key=value]``
    bitrate: int = DEFAULT_BITRATE  #: nominal (arbitration) bit rate, bit/s
    fd: bool = False               #: CAN FD: the data phase at ``data_bitrate``
    data_bitrate: int | None = None


@dataclass
class ChannelConfig:
    """One loading channel: a valve and a dynamometer on one bus."""

    name: str
    bus: str
    valve_id: int
    dynamometer_id: int
    range_kgf: float = DEFAULT_RANGE_KGF
    force_limit_kgf: float | None = None   #: None: :data:`DEFAULT_LIMIT_SHARE` of the range
    #: the emulated plant (the emulator only); its g is the structure's G_ii
    plant: PlantConfig | None = None
    #: the g the plant's file gave, if it gave one (it must agree with the structure's G_ii)
    plant_g: float | None = None
    #: the channel's valve drive and amplifier (:mod:`devices`; default: the emulated pair)
    devices: DeviceSet = field(default_factory=default_devices)

    @property
    def limit_kgf(self) -> float:
        return self.force_limit_kgf if self.force_limit_kgf is not None \
            else DEFAULT_LIMIT_SHARE * self.range_kgf


@dataclass
class RigConfig:
    """A rig: its buses, its channels (in the order of G's rows), the structure, the period."""

    name: str
    buses: list[BusConfig]
    channels: list[ChannelConfig]
    #: the coupling, kgf/(%·s), rows and columns in the order of :attr:`channels`; None when
    #: neither the file nor the channels' plants give it
    G: np.ndarray | None = None
    #: where G came from: "G", "K" (stiffness and flow gains) or "plants" (uncoupled: each
    #: channel's own g) or "none"
    structure_from: str = "none"
    #: the structure's stiffness at the attachment points as the file gives it (kgf/mm; only
    #: when G comes from K)
    K: np.ndarray | None = None
    period_s: float = DEFAULT_PERIOD_S
    bus_load_limit: float = DEFAULT_LOAD_LIMIT
    heartbeat_ms: int = 100
    path: Path | None = None
    #: the emulated structure's scheduled changes (``[[structure.change]]``, ``stand emulate
    #: --change``), in the order given; each names its channel by index
    changes: list[StructureChange] = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.channels]

    @property
    def G_changed(self) -> np.ndarray | None:
        """G once every scheduled change is complete (:attr:`G` without changes)."""
        if self.G is None or not self.changes:
            return self.G
        factors = np.ones(len(self.channels))
        for c in self.changes:
            factors[c.channel] *= c.stiffness_factor
        return changed_structure(self.G, factors)

    def change_text(self, change: StructureChange) -> str:
        """A change as ``stand rig check`` says it."""
        how = (f"over {change.ramp_s:g} s (complete at {change.end_s:g} s)" if change.ramp_s
               else "at once")
        return (f"{self.channels[change.channel].name}: stiffness × {change.stiffness_factor:g} "
                f"from {change.from_s:g} s of stand time, {how}")

    def channel(self, name: str) -> ChannelConfig:
        for c in self.channels:
            if c.name == name:
                return c
        raise RigError(f"{self.where}: no channel {name!r}; the rig has: {', '.join(self.names)}")

    def bus(self, name: str) -> BusConfig:
        for b in self.buses:
            if b.name == name:
                return b
        raise RigError(f"{self.where}: no bus {name!r}; the rig has: "
                       f"{', '.join(b.name for b in self.buses)}")

    def channels_on(self, bus: str) -> list[ChannelConfig]:
        return [c for c in self.channels if c.bus == bus]

    @property
    def where(self) -> str:
        return str(self.path) if self.path is not None else f"rig {self.name!r}"


# ------------------------------------------------------------------------------------------
# reading
# ------------------------------------------------------------------------------------------
def load_rig_file(path: str | Path) -> RigConfig:
    """The rig a ``rig.toml`` describes (see the module docstring); :class:`RigError` if it
    cannot be used."""
    path = Path(path)
    try:
        data = read_toml(path)
    except ModelError as exc:
        raise RigError(str(exc)) from None
    return rig_from_mapping(data, str(path), path.parent, path)


def rig_from_mapping(data: Mapping[str, Any], where: str = "rig", base_dir: Path | None = None,
                     path: Path | None = None) -> RigConfig:
    known = {"name", "period_ms", "bus_load_limit_pct", "heartbeat_ms", "bus", "channel",
             "structure", "devices"}
    unknown = set(data) - known
    if unknown:
        raise RigError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}; a rig file has "
                       f"{', '.join(sorted(known))}")
    name = str(data.get("name", Path(where).stem))
    period_s = _number(data, "period_ms", where, 2.0, 0.5, 100.0) / 1e3
    limit = _number(data, "bus_load_limit_pct", where, 100 * DEFAULT_LOAD_LIMIT, 1.0, 100.0) / 100
    heartbeat_ms = int(_number(data, "heartbeat_ms", where, 100, 10, 10000))
    buses = [_bus(b, f"{where}: [[bus]] #{i + 1}") for i, b in enumerate(_tables(data, "bus", where))]
    if not buses:
        raise RigError(f"{where}: no [[bus]]: a rig needs at least one bus (name, spec)")
    _unique([b.name for b in buses], f"{where}: bus name")
    bus_names = {b.name for b in buses}
    loaded: dict = {}
    devices = _devices(data.get("devices"), where, base_dir, loaded)
    channels = [_channel(c, f"{where}: [[channel]] #{i + 1}", bus_names, base_dir, devices, loaded)
                for i, c in enumerate(_tables(data, "channel", where))]
    if not channels:
        raise RigError(f"{where}: no [[channel]]: a rig needs at least one channel (name, bus, "
                       "valve_id, dynamometer_id)")
    _unique([c.name for c in channels], f"{where}: channel name")
    for b in buses:
        ids = [i for c in channels if c.bus == b.name for i in (c.valve_id, c.dynamometer_id)]
        dupes = sorted({i for i in ids if ids.count(i) > 1})
        if dupes:
            raise RigError(f"{where}: bus {b.name!r}: node id(s) {', '.join(map(str, dupes))} "
                           "used twice: every valve and dynamometer on one bus needs its own id")
    structure = data.get("structure")
    G, source, K = _structure(structure, channels, f"{where}: [structure]")
    changes = _changes(structure, channels, G, f"{where}: [[structure.change]]")
    return RigConfig(name=name, buses=buses, channels=channels, G=G, structure_from=source, K=K,
                     period_s=period_s, bus_load_limit=limit, heartbeat_ms=heartbeat_ms, path=path,
                     changes=changes)


def _tables(data: Mapping[str, Any], key: str, where: str) -> list[Mapping[str, Any]]:
    value = data.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, Mapping) for v in value):
        raise RigError(f"{where}: '{key}' must be an array of tables ([[{key}]])")
    return value


def _unique(names: list[str], what: str) -> None:
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise RigError(f"{what}(s) {', '.join(dupes)} given twice: names must be unique")


def _number(table: Mapping[str, Any], key: str, where: str, default: float | None,
            lo: float, hi: float) -> float:
    if key not in table:
        if default is None:
            raise RigError(f"{where}: '{key}' is missing")
        return float(default)
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
            or not lo <= v <= hi:
        raise RigError(f"{where}: {key} = {v!r} must be a number in [{lo:g}, {hi:g}]")
    return float(v)


def _name(table: Mapping[str, Any], where: str) -> str:
    name = table.get("name")
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise RigError(f"{where}: name = {name!r} must be letters, digits, '_' or '-', starting "
                       "with a letter (it names files and columns)")
    return name


def _bus(table: Mapping[str, Any], where: str) -> BusConfig:
    _keys(table, {"name", "spec", "bitrate", "fd", "data_bitrate"}, where)
    name = _name(table, where)
    spec = table.get("spec")
    if not isinstance(spec, str):
        raise RigError(f"{where} ({name}): spec must be a python-can bus, e.g. "
                       "\"socketcan:can0\" or \"udp_loopback:rig-can0\"")
    try:
        BusSpec.parse(spec)
    except BusSpecError as exc:
        raise RigError(f"{where} ({name}): {exc}") from None
    bitrate = int(_number(table, "bitrate", f"{where} ({name})", DEFAULT_BITRATE, 10_000, 1_000_000))
    fd = table.get("fd", False)
    if not isinstance(fd, bool):
        raise RigError(f"{where} ({name}): fd must be true or false")
    data_bitrate = None
    if fd:
        data_bitrate = int(_number(table, "data_bitrate", f"{where} ({name})", bitrate,
                                   bitrate, 12_000_000))
    elif "data_bitrate" in table:
        raise RigError(f"{where} ({name}): data_bitrate is for CAN FD buses: add fd = true")
    return BusConfig(name, spec, bitrate, fd, data_bitrate)


def _keys(table: Mapping[str, Any], known: set[str], where: str) -> None:
    unknown = set(table) - known
    if unknown:
        raise RigError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}; known: "
                       f"{', '.join(sorted(known))}")


def _devices(value: Any, where: str, base_dir: Path | None, loaded: dict) -> DeviceSet:
    """The device set a rig file or a channel names (a path relative to the rig file); each
    file read once."""
    if value is None:
        return default_devices()
    if not isinstance(value, str):
        raise RigError(f"{where}: devices = {value!r} must be the path of a device file "
                       "(docs/devices.md)")
    path = Path(value).expanduser()
    if base_dir is not None and not path.is_absolute():
        path = base_dir / path
    if path not in loaded:
        try:
            loaded[path] = load_device_set(path)
        except DeviceError as exc:
            raise RigError(f"{where}: devices: {exc}") from None
    return loaded[path]


def _channel(table: Mapping[str, Any], where: str, buses: set[str],
             base_dir: Path | None, devices: DeviceSet, loaded: dict) -> ChannelConfig:
    _keys(table, {"name", "bus", "valve_id", "dynamometer_id", "range_kgf", "force_limit_kgf",
                  "plant", "devices"}, where)
    name = _name(table, where)
    where = f"{where} ({name})"
    bus = table.get("bus")
    if bus not in buses:
        raise RigError(f"{where}: bus = {bus!r} is not one of the rig's buses "
                       f"({', '.join(sorted(buses))})")
    ids = []
    for key in ("valve_id", "dynamometer_id"):
        v = table.get(key)
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 127:
            raise RigError(f"{where}: {key} = {v!r} must be a CANopen node id, 1..127")
        ids.append(v)
    if ids[0] == ids[1]:
        raise RigError(f"{where}: the valve and the dynamometer need different node ids")
    range_kgf = _number(table, "range_kgf", where, DEFAULT_RANGE_KGF, 1.0, 1e7)
    limit = None
    if "force_limit_kgf" in table:
        limit = _number(table, "force_limit_kgf", where, None, 1.0, range_kgf)
    plant, g = _plant(table.get("plant"), where, base_dir)
    if "devices" in table:
        devices = _devices(table["devices"], where, base_dir, loaded)
    return ChannelConfig(name, bus, ids[0], ids[1], range_kgf, limit, plant, g, devices)


def _plant(value: Any, where: str, base_dir: Path | None) -> tuple[PlantConfig | None, float | None]:
    """The channel's emulated plant and the g its file gives (None: left to the structure)."""
    if value is None:
        return None, None
    try:
        if isinstance(value, str):
            path = Path(value)
            if base_dir is not None and not path.is_absolute():
                path = base_dir / path
            data, label, here = read_toml(path), str(path), path.parent
        elif isinstance(value, Mapping):
            data, label, here = value, f"{where}: [channel.plant]", base_dir
        else:
            raise RigError(f"{where}: plant must be a plant file's path or a [channel.plant] table")
        base = data.get("base", {})
        g = base.get("g") if isinstance(base, Mapping) else None
        return plant_config_from_mapping(data, label, here), g
    except ModelError as exc:
        raise RigError(str(exc)) from None


def _matrix(value: Any, n: int, what: str, where: str) -> np.ndarray:
    try:
        m = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise RigError(f"{where}: {what} must be a list of {n} rows of {n} numbers") from None
    if m.shape != (n, n):
        raise RigError(f"{where}: {what} is {'x'.join(map(str, m.shape)) or 'a number'}, the rig "
                       f"has {n} channel(s): give {n} rows of {n} numbers, in the channels' order")
    if not np.all(np.isfinite(m)):
        raise RigError(f"{where}: {what} has a value that is not a finite number")
    return m


def _structure(value: Any, channels: list[ChannelConfig],
               where: str) -> tuple[np.ndarray | None, str, np.ndarray | None]:
    """G from the [structure] table (G, or K with the flow gains), or each plant's own g (no
    coupling), where it came from, and K when given; a plant's [base] g, when given too, must
    agree with G_ii."""
    n = len(channels)
    if value is None:
        value = {}
    if not isinstance(value, Mapping):
        raise RigError(f"{where} must be a table")
    _keys(value, {"G", "K", "flow_gain_mm_per_pct_s", "change"}, where)
    if "G" in value and "K" in value:
        raise RigError(f"{where}: give G or K (with flow_gain_mm_per_pct_s), not both")
    G: np.ndarray | None = None
    K: np.ndarray | None = None
    source = "none"
    if "G" in value:
        G, source = _matrix(value["G"], n, "G", where), "G"
    elif "K" in value:
        K = _matrix(value["K"], n, "K", where)
        gains = value.get("flow_gain_mm_per_pct_s")
        try:
            c = np.array(gains, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            c = np.array([])
        if c.shape != (n,) or not np.all(np.isfinite(c)) or not np.all(c > 0):
            raise RigError(f"{where}: K needs flow_gain_mm_per_pct_s, each actuator's flow gain "
                           f"over its piston area c_i/A_i in mm/(%·s): {n} positive numbers")
        G, source = K * c[None, :], "K"
    elif all(c.plant is not None for c in channels):
        G, source = np.diag([c.plant.model.g for c in channels]), "plants"
    if G is not None and source != "plants":
        if np.any(np.diag(G) <= 0):
            bad = [channels[i].name for i in np.flatnonzero(np.diag(G) <= 0)]
            raise RigError(f"{where}: G's diagonal (each channel's own gain g) must be positive; "
                           f"it is not for {', '.join(bad)}")
        for i, c in enumerate(channels):
            if c.plant is None:
                continue
            if c.plant_g is not None and not math.isclose(c.plant_g, G[i, i], rel_tol=1e-9):
                raise RigError(f"{where}: channel {c.name!r}: its plant says g = {c.plant_g:g} "
                               f"but the structure's G[{i + 1},{i + 1}] = {G[i, i]:g}: a channel's "
                               "own gain is the structure's diagonal; leave g out of the plant")
            c.plant.model = c.plant.model.with_params({"g": float(G[i, i])})
    return G, source, K


# ------------------------------------------------------------------------------------------
# the structure's scheduled changes
# ------------------------------------------------------------------------------------------
#: how far a change may stiffen a point (a jammed part); softening goes down to 1 %
CHANGE_FACTOR_RANGE = (0.01, 10.0)
#: the latest stand time a change may begin (s): ten years
CHANGE_LATEST_S = 3.2e8


def _changes(structure: Any, channels: list[ChannelConfig], G: np.ndarray | None,
             where: str) -> list[StructureChange]:
    """The ``[[structure.change]]`` tables of ``[structure]`` (none: an empty list)."""
    if not isinstance(structure, Mapping) or "change" not in structure:
        return []
    tables = structure["change"]
    if not isinstance(tables, list) or not all(isinstance(t, Mapping) for t in tables):
        raise RigError(f"{where}: 'change' must be an array of tables ([[structure.change]] with "
                       "channel, stiffness_factor, from_s, ramp_s)")
    names = [c.name for c in channels]
    out = [_change(t, names, f"{where} #{i + 1}") for i, t in enumerate(tables)]
    if out and G is None:
        raise RigError(f"{where}: a change of the structure needs the structure: give [structure] "
                       "G, or K with flow_gain_mm_per_pct_s (or a plant for every channel)")
    return out


def _change(table: Mapping[str, Any], names: list[str], where: str) -> StructureChange:
    _keys(table, {"channel", "stiffness_factor", "from_s", "ramp_s"}, where)
    channel = table.get("channel")
    if channel not in names:
        raise RigError(f"{where}: channel = {channel!r} is not a channel of the rig; it has "
                       f"{', '.join(names)}")
    where = f"{where} ({channel})"
    factor = _number(table, "stiffness_factor", where, None, *CHANGE_FACTOR_RANGE)
    from_s = _number(table, "from_s", where, None, 0.0, CHANGE_LATEST_S)
    ramp_s = _number(table, "ramp_s", where, 0.0, 0.0, CHANGE_LATEST_S)
    return StructureChange(names.index(channel), factor, from_s, ramp_s)


#: ``CHANNEL:FACTOR@FROM_S`` or ``CHANNEL:FACTOR@FROM_S+RAMP_S`` (``stand emulate --change``)
CHANGE_RE = re.compile(r"^(?P<channel>[^:@+\s]+):(?P<factor>[^@]+)@(?P<from_s>[^+]+)"
                       r"(?:\+(?P<ramp_s>.+))?$")
CHANGE_FORM = "CHANNEL:FACTOR@FROM_S[+RAMP_S], e.g. inner:0.97@600 or inner:0.97@600+60"


def parse_change(text: str, rig: RigConfig) -> StructureChange:
    """A change as the command line gives it (:data:`CHANGE_FORM`): at ``CHANNEL``'s attachment
    its stiffness times ``FACTOR`` from the stand time ``FROM_S`` (s), at once or over
    ``RAMP_S`` (s); :class:`RigError` naming what is wrong."""
    m = CHANGE_RE.match(text.strip())
    if not m:
        raise RigError(f"--change {text!r}: give it as {CHANGE_FORM}")
    table: dict[str, Any] = {"channel": m["channel"]}
    for key in ("factor", "from_s", "ramp_s"):
        if m[key] is None:
            continue
        try:
            table["stiffness_factor" if key == "factor" else key] = float(m[key])
        except ValueError:
            raise RigError(f"--change {text!r}: {m[key]!r} is not a number ({CHANGE_FORM})") from None
    if rig.G is None:
        raise RigError(f"--change {text!r}: {rig.where} gives no structure to change: give "
                       "[structure] G, or K with flow_gain_mm_per_pct_s")
    return _change(table, rig.names, f"--change {text!r}")


def with_changes(rig: RigConfig, changes: list[StructureChange]) -> RigConfig:
    """``rig`` with ``changes`` scheduled after its own."""
    return replace(rig, changes=list(rig.changes) + list(changes))
