"""Finding the devices on a bench (``stand bench scan``): every node that answers, the fresh ones
found by LSS and given a node id, each matched against the device files the user has.

1. **LSS** (CiA 305, canopen's LSS master): every device to waiting; then fastscan finds, bit
   by bit, the LSS address (vendor, product, revision, serial) of a device without a node id,
   which is given the next free node id and stores it; back to waiting it boots with it. Again
   until none answers.
2. **SDO scan**: an expedited upload of the device type 0x1000 to every node id at once (1-127),
   the answers collected for a bounded time; then the identity 0x1018:01-04 of every node that
   answered, again all at once.
3. **Matching**: a node is the valve drive or the amplifier of a device set whose EDS has its
   vendor and product (and whose file accepts its revision).

Nothing is configured but the node ids LSS gives; no node is started.
"""
from __future__ import annotations

import logging
import os
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import canopen
from canopen.lss import LssError

from devices import DYNAMOMETER, VALVE, Device, DeviceSet
from devices.device import revision_text

log = logging.getLogger(__name__)

DEVICE_TYPE, IDENTITY = 0x1000, 0x1018
SDO_RX, SDO_TX = 0x600, 0x580
PROFILE_NAMES = {408: "CiA 408", 404: "CiA 404", 401: "CiA 401", 402: "CiA 402", 406: "CiA 406"}


@dataclass
class FoundNode:
    """A node that answered: what it says of itself and which device file it matches."""

    node_id: int
    device_type: int | None = None
    vendor: int | None = None
    product: int | None = None
    revision: int | None = None
    serial: int | None = None
    #: it had no node id: LSS gave it this one
    by_lss: bool = False
    #: the device set and the device of it this node is (None: no file the user has)
    devices: DeviceSet | None = None
    device: Device | None = None
    #: SDO aborts while reading it (object, code)
    aborts: list[tuple[str, int]] = field(default_factory=list)

    @property
    def kind(self) -> str | None:
        return self.device.kind if self.device is not None else None

    @property
    def profile(self) -> str:
        if self.device_type is None:
            return "?"
        number = self.device_type & 0xFFFF
        return PROFILE_NAMES.get(number, f"CiA {number}" if number else "none")


@dataclass
class ScanResult:
    bus: str
    nodes: list[FoundNode]
    lss_found: int
    seconds: float


class _Answers:
    """SDO answers on 0x581-0x5FF, collected by node id for the current request."""

    def __init__(self, network: canopen.Network) -> None:
        self.network = network
        self.lock = threading.Lock()
        self.got: dict[int, bytes] = {}
        self.arrived = threading.Event()
        self.waiting: set[int] = set()
        for nid in range(1, 128):
            network.subscribe(SDO_TX + nid, self._on_answer)

    def close(self) -> None:
        for nid in range(1, 128):
            self.network.unsubscribe(SDO_TX + nid, self._on_answer)

    def _on_answer(self, can_id: int, data: bytes, timestamp: float) -> None:
        nid = can_id - SDO_TX
        with self.lock:
            if nid in self.waiting and len(data) == 8:
                self.got[nid] = bytes(data)
                self.waiting.discard(nid)
                if not self.waiting:
                    self.arrived.set()

    def upload(self, ids, index: int, sub: int, timeout_s: float) -> dict[int, bytes]:
        """An expedited SDO upload of ``index:sub`` to every node of ``ids`` at once; the
        answers that came within ``timeout_s`` by node id."""
        ids = list(ids)
        with self.lock:
            self.got = {}
            self.waiting = set(ids)
            self.arrived.clear()
        request = struct.pack("<BHB4x", 0x40, index, sub)
        for nid in ids:
            self.network.send_message(SDO_RX + nid, request)
        if ids:
            self.arrived.wait(timeout_s)
        with self.lock:
            self.waiting = set()
            return dict(self.got)


def _value(answer: bytes, index: int, sub: int) -> tuple[int | None, int | None]:
    """(value, abort code) of an expedited upload's answer."""
    cs = answer[0]
    got_index, got_sub = struct.unpack_from("<HB", answer, 1)
    if (got_index, got_sub) != (index, sub):
        return None, None
    if cs == 0x80:
        return None, struct.unpack_from("<I", answer, 4)[0]
    if cs & 0xE0 == 0x40 and cs & 0x02:           # expedited upload response
        size = 4 - ((cs >> 2) & 0x3) if cs & 0x01 else 4
        return int.from_bytes(answer[4:4 + size], "little"), None
    return None, None


def sdo_scan(network: canopen.Network, ids=range(1, 128), timeout_s: float = 0.3) -> list[FoundNode]:
    """Every node of ``ids`` that answers an SDO upload of its device type, with its identity."""
    answers = _Answers(network)
    try:
        found = {}
        for nid, raw in answers.upload(ids, DEVICE_TYPE, 0, timeout_s).items():
            node = found[nid] = FoundNode(nid)
            node.device_type, abort = _value(raw, DEVICE_TYPE, 0)
            if abort is not None:
                node.aborts.append(("0x1000", abort))
        for sub, name in ((1, "vendor"), (2, "product"), (3, "revision"), (4, "serial")):
            for nid, raw in answers.upload(sorted(found), IDENTITY, sub, timeout_s).items():
                value, abort = _value(raw, IDENTITY, sub)
                setattr(found[nid], name, value)
                if abort is not None:
                    found[nid].aborts.append((f"0x1018:{sub:02X}", abort))
        return [found[nid] for nid in sorted(found)]
    finally:
        answers.close()


def lss_assign(network: canopen.Network, free_ids, timeout_s: float = 0.05,
               store: bool = True) -> list[tuple[int, tuple[int, int, int, int]]]:
    """Find every device without a node id by LSS fastscan and give each the next of
    ``free_ids``; returns (node id, LSS address) of each. The devices boot with their ids."""
    lss = network.lss
    lss.RESPONSE_TIMEOUT = timeout_s
    lss.send_switch_state_global(lss.WAITING_STATE)
    out = []
    free = iter(free_ids)
    while True:
        found, address = lss.fast_scan()
        if not found:
            return out
        nid = next(free, None)
        if nid is None:
            lss.send_switch_state_global(lss.WAITING_STATE)
            raise RuntimeError("LSS found more devices without a node id than there are free ids")
        try:
            lss.configure_node_id(nid)
            if store:
                try:
                    lss.store_configuration()
                except LssError as exc:         # a device may not store: it says so, not fatal
                    log.warning("LSS: node %d could not store its configuration: %s", nid, exc)
        finally:
            lss.send_switch_state_global(lss.WAITING_STATE)
        out.append((nid, tuple(address)))
        time.sleep(0.05)                        # its boot-up


def match(nodes: list[FoundNode], device_sets: list[DeviceSet]) -> None:
    """Which device of which set each node is: vendor and product as its EDS says, the revision
    in the range its file accepts (the first set that fits)."""
    for node in nodes:
        for devices in device_sets:
            for device in (devices.valve, devices.dynamometer):
                ident = device.identity
                if (node.vendor, node.product) != (ident.vendor, ident.product):
                    continue
                if device.revisions is not None and node.revision is not None \
                        and node.revision not in device.revisions:
                    continue
                node.devices, node.device = devices, device
                break
            if node.device is not None:
                break


def scan_bench(network: canopen.Network, device_sets: list[DeviceSet], *, lss: bool = True,
               first_id: int = 1, timeout_s: float = 0.3, lss_timeout_s: float = 0.05,
               bus: str = "") -> ScanResult:
    """The whole scan (the module doc): nodes that answer, LSS for those without an id (given
    free ids from ``first_id``), every node matched against ``device_sets``."""
    start = time.monotonic()
    nodes = sdo_scan(network, timeout_s=timeout_s)
    assigned = []
    if lss:
        used = {n.node_id for n in nodes}
        free = [i for i in range(first_id, 128) if i not in used]
        assigned = lss_assign(network, free, lss_timeout_s)
        if assigned:
            new = sdo_scan(network, [nid for nid, _ in assigned], timeout_s)
            for node in new:
                node.by_lss = True
            nodes = sorted(nodes + new, key=lambda n: n.node_id)
    match(nodes, device_sets)
    return ScanResult(bus, nodes, len(assigned), time.monotonic() - start)


def result_table(result: ScanResult) -> str:
    """The scan as a table, a node a line."""
    head = f"{'node':>4}  {'device':40s}  {'profile':7s}  {'vendor':10s}  {'product':10s}  " \
           f"{'revision':8s}  {'serial':10s}  file"
    lines = [head]
    for n in result.nodes:
        if n.device is not None:
            name = f"{n.device.name} ({n.kind})"
            file = n.devices.where
        else:
            name, file = "unknown device", "no device file matches: write one (docs/devices.md)"
        hexes = [f"0x{v:08X}" if v is not None else "?" for v in (n.vendor, n.product)]
        serial = f"0x{n.serial:08X}" if n.serial is not None else "?"
        lss = "  (node id given by LSS)" if n.by_lss else ""
        lines.append(f"{n.node_id:>4}  {name[:40]:40s}  {n.profile:7s}  {hexes[0]:10s}  "
                     f"{hexes[1]:10s}  {revision_text(n.revision):8s}  {serial:10s}  {file}{lss}")
    return "\n".join(lines)


def skeleton_rig(result: ScanResult, bus_spec: str, name: str = "bench",
                 base: Path | None = None) -> tuple[str, list[str]]:
    """A rig file of the channels the scan found: each valve with the next amplifier of the same
    device set, by node id; device files named relative to ``base`` (the rig file's directory;
    default the working directory). Returns its text and what could not be paired."""
    valves = [n for n in result.nodes if n.kind == VALVE]
    amps = [n for n in result.nodes if n.kind == DYNAMOMETER]
    lines = [f"# found by stand bench scan on {bus_spec}: {len(result.nodes)} node(s)",
             "# add each channel's range_kgf and force_limit_kgf, and for the emulator its",
             "# [channel.plant] and the [structure] (docs/rig.md); stand rig check checks it",
             f"name = \"{name}\"", "", "[[bus]]", "name = \"can0\"", f"spec = \"{bus_spec}\""]
    left = []
    k = 0
    for valve in valves:
        amp = next((a for a in amps if a.devices is valve.devices), None)
        if amp is None:
            left.append(f"valve node {valve.node_id} ({valve.device.name}): no amplifier of its "
                        f"device set ({valve.devices.where}) was found")
            continue
        amps.remove(amp)
        k += 1
        lines += ["", "[[channel]]", f"name = \"ch{k}\"", "bus = \"can0\"",
                  f"valve_id = {valve.node_id}", f"dynamometer_id = {amp.node_id}"]
        if not valve.devices.is_default:
            where = os.path.relpath(Path(valve.devices.path).resolve(), (base or Path.cwd()).resolve())
            lines.append(f"devices = \"{Path(where).as_posix()}\"")
    for amp in amps:
        left.append(f"amplifier node {amp.node_id} ({amp.device.name}): no valve of its device "
                    f"set ({amp.devices.where}) was found")
    for n in result.nodes:
        if n.device is None:
            left.append(f"node {n.node_id}: vendor 0x{(n.vendor or 0):08X} product "
                        f"0x{(n.product or 0):08X} matches no device file")
    lines += [f"# not in a channel: {t}" for t in left]
    return "\n".join(lines) + "\n", left
