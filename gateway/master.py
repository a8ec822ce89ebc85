"""The gateway as CANopen master of the stand: NMT, identity check, PDO set-up (CiA 301).

Start-up, in the order a careful master does it:

1. reset both nodes (NMT reset node) and wait for their boot-up messages;
2. read the identity object 0x1018 over SDO and compare it with the EDS (wrong node id, wrong
   device or wrong EDS are refused with a message naming the node);
3. write the communication cycle period 0x1006, the heartbeat producer time 0x1017 and the RPDO
   timeout, and read back the PDO mappings (canopen's ``tpdo.read()``/``rpdo.read()``), checking
   that they carry the objects the control loop needs;
4. read the dynamometer's unit and decimals (0x6131/0x6132) to scale its process value to kgf;
5. NMT start, and confirm OPERATIONAL from the heartbeats; meanwhile a hold command (zero
   setpoint) goes to the valve every 20 ms, so its RPDO timeout (armed when it enters
   OPERATIONAL) never fires before the control loop's first command.

Only frames from the two nodes reach the canopen stack: the master declares their ids and data
lengths to the network's acceptance filter (EMCY 8, SDO 8, heartbeat 1, each TPDO its mapped
size once read); anything else is counted and dropped (:class:`gateway.capture.TappedNetwork`).
"""
from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import canopen

from dbc import DYNAMOMETER_EDS, VALVE_EDS
from dbc import profile as P
from dbc.pdo_codec import PdoLayout, PdoLayoutError

from .capture import TappedNetwork
from .config import SDO_TIMEOUT_S
from .errors import NodeError

log = logging.getLogger(__name__)

NMT_START, NMT_PREOP, NMT_RESET_NODE = P.NMT_START, P.NMT_PREOP, P.NMT_RESET_NODE
_NMT_NAMES = P.NMT_STATE_NAMES
_SDO_ERRORS = (canopen.SdoCommunicationError, canopen.SdoAbortedError)


@dataclass
class NodeLink:
    """What the master knows about one node."""

    role: str                     #: "valve" or "dynamometer"
    node: canopen.RemoteNode
    identity: dict = field(default_factory=dict)
    last_heartbeat: float | None = None   #: monotonic time of the last heartbeat
    nmt_state: int | None = None
    booted: threading.Event = field(default_factory=threading.Event)

    @property
    def id(self) -> int:
        return self.node.id


class StandMaster:
    """Master of the valve and dynamometer nodes on one :class:`TappedNetwork`."""

    def __init__(self, network: TappedNetwork, valve_id: int, dynamometer_id: int,
                 sdo_timeout_s: float = SDO_TIMEOUT_S) -> None:
        if valve_id == dynamometer_id:
            raise NodeError(valve_id, "the valve and the dynamometer cannot have the same node id")
        for nid in (valve_id, dynamometer_id):
            if not 1 <= nid <= 127:
                raise NodeError(nid, f"node id {nid} is outside 1..127")
        self.network = network
        self.valve = NodeLink("valve", canopen.RemoteNode(valve_id, str(VALVE_EDS)))
        self.dynamometer = NodeLink("dynamometer", canopen.RemoteNode(dynamometer_id, str(DYNAMOMETER_EDS)))
        self.links = (self.valve, self.dynamometer)
        for link in self.links:
            link.node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
            network.add_node(link.node)
            network.subscribe(P.HEARTBEAT_BASE + link.id, self._heartbeat_callback(link))
            if hasattr(network, "expect"):
                nid = link.id
                network.expect(P.EMCY_BASE + nid, 8)
                network.expect(P.SDO_TX_BASE + nid, 8)
                network.expect(P.HEARTBEAT_BASE + nid, 1)    # heartbeat / boot-up
                for base in P.TPDO_BASES:
                    network.expect(base + nid, None)     # TPDOs: exact size once configured
        self.force_scale_kgf: float | None = None
        self.valve_tpdo: PdoLayout | None = None
        self.valve_rpdo: PdoLayout | None = None
        self.force_tpdo: PdoLayout | None = None
        self.lockstep_capable: bool | None = None
        #: the stand's clock object 0x2100 (0 real time, 1 lockstep), None if it has none
        self.stand_clock: int | None = None

    def _heartbeat_callback(self, link: NodeLink):
        def on_heartbeat(can_id: int, data: bytes, timestamp: float) -> None:
            if len(data) != 1:
                return
            state = data[0] & 0x7F
            link.last_heartbeat = time.monotonic()
            link.nmt_state = state
            if state == 0:
                link.booted.set()
        return on_heartbeat

    # -- 1. boot ----------------------------------------------------------------------------------
    def boot(self, timeout_s: float = 5.0) -> None:
        """Reset both nodes and wait for their boot-up messages."""
        boot_links(self.links, timeout_s)

    # -- 2. identity --------------------------------------------------------------------------------
    def check_identity(self) -> None:
        for link in self.links:
            info = link.node.object_dictionary.device_information
            with sdo_errors(link, "cannot read its identity (0x1018) over SDO"):
                vendor = link.node.sdo[P.IDENTITY][1].raw
                product = link.node.sdo[P.IDENTITY][2].raw
                revision = link.node.sdo[P.IDENTITY][3].raw
                serial = link.node.sdo[P.IDENTITY][4].raw
            link.identity = dict(vendor=vendor, product=product, revision=revision, serial=serial)
            if (vendor, product) != (info.vendor_number, info.product_number):
                raise NodeError(
                    link.id,
                    f"node {link.id} is not the expected {link.role}: identity vendor 0x{vendor:08X} "
                    f"product 0x{product:08X}, but {link.node.object_dictionary.device_information.product_name!r} "
                    f"has vendor 0x{info.vendor_number:08X} product 0x{info.product_number:08X}. "
                    "Check --valve-id/--dynamometer-id (swapped node ids?) and the EDS files.")

    # -- 3./4. configuration ------------------------------------------------------------------------
    def configure(self, period_s: float, heartbeat_ms: int, rpdo_timeout_ms: int) -> None:
        period_us = int(round(period_s * 1e6))
        for link in self.links:
            sdo = link.node.sdo
            with sdo_errors(link, "configuration over SDO failed"):
                sdo[P.COMM_CYCLE_PERIOD].raw = period_us
                sdo[P.PRODUCER_HEARTBEAT].raw = heartbeat_ms
                link.node.tpdo.read()
                if link is self.valve:
                    sdo[0x1400][5].raw = rpdo_timeout_ms
                    link.node.rpdo.read()
        self._set_layouts()
        dyn = self.dynamometer.node.sdo
        with sdo_errors(self.dynamometer, "cannot read its unit/decimals (0x6131/0x6132)"):
            unit = dyn[P.PV_UNIT[0]][P.PV_UNIT[1]].raw
            decimals = dyn[P.PV_DECIMALS[0]][P.PV_DECIMALS[1]].raw
        try:
            self.force_scale_kgf = P.force_scale_kgf(unit, decimals)
        except ValueError as exc:
            raise NodeError(self.dynamometer.id, f"dynamometer node {self.dynamometer.id}: {exc}") from None
        try:
            self.stand_clock = int(self.valve.node.sdo[P.EMULATOR_CLOCK].raw)
        except (*_SDO_ERRORS, KeyError):
            self.stand_clock = None  # a real valve: no such object
        self.lockstep_capable = self.stand_clock == 1

    def configure_from_eds(self) -> None:
        """Set up the PDO layouts and the force scale from the EDS defaults, without talking to
        the nodes (offline use: fuzzing the frame handling, replaying captures)."""
        for link in self.links:
            link.node.tpdo.read(from_od=True)
        self.valve.node.rpdo.read(from_od=True)
        self._set_layouts()
        od = self.dynamometer.node.object_dictionary
        self.force_scale_kgf = P.force_scale_kgf(od[P.PV_UNIT[0]][P.PV_UNIT[1]].default,
                                                 od[P.PV_DECIMALS[0]][P.PV_DECIMALS[1]].default)
        self.lockstep_capable = False

    def _set_layouts(self) -> None:
        """The control loop's PDO layouts from the PDO maps just read, checked for what it
        needs; the frame filter then accepts exactly those TPDOs."""
        self.valve_tpdo = self._layout(self.valve, self.valve.node.tpdo[1],
                                       [(P.STATUS_WORD, 0), P.ACTUAL_VALUE], synchronous=True)
        self.valve_rpdo = self._layout(self.valve, self.valve.node.rpdo[1],
                                       [(P.CONTROL_WORD, 0), P.SETPOINT], synchronous=False)
        self._rpdo_cw = self.valve_rpdo.position(P.CONTROL_WORD, 0)
        self._rpdo_sp = self.valve_rpdo.position(*P.SETPOINT)
        self._rpdo_two = self.valve_rpdo.keys == ((P.CONTROL_WORD, 0), tuple(P.SETPOINT))
        self._cyclic_flags = getattr(self.network, "cyclic_flags", 0)
        self._last_command = self._last_frame = None
        self.force_tpdo = self._layout(self.dynamometer, self.dynamometer.node.tpdo[1], [P.PV_INT32],
                                       synchronous=True)
        if hasattr(self.network, "expect"):
            for layout in (self.valve_tpdo, self.force_tpdo):
                self.network.expect(layout.cob_id, layout.size)

    def _layout(self, link: NodeLink, pdo_map, needed, synchronous: bool) -> PdoLayout:
        if not pdo_map.enabled:
            raise NodeError(link.id, f"{link.role} node {link.id}: {pdo_map.name} is disabled; "
                                     "enable it (see its EDS)")
        try:
            layout = PdoLayout.from_map(pdo_map)
        except PdoLayoutError as exc:
            raise NodeError(link.id, f"{link.role} node {link.id}: {pdo_map.name}: {exc}") from None
        for key in needed:
            if tuple(key) not in layout.keys:
                raise NodeError(link.id, f"{link.role} node {link.id}: {pdo_map.name} does not map "
                                         f"0x{key[0]:04X}:{key[1]:02X}, which the control loop needs")
        tt = pdo_map.trans_type
        if synchronous and not (tt == 0 or 1 <= tt <= 240):
            raise NodeError(link.id, f"{link.role} node {link.id}: {pdo_map.name} has transmission "
                                     f"type {tt}; the loop needs a synchronous TPDO (type 1)")
        return layout

    def declare_run(self, period_s: float, sync_window_s: float = 0.0) -> None:
        """At each run start, make the run's capture self-describing: write the communication
        cycle period 0x1006 again (which period the SYNCs stand for), and on a stand that can run
        in lockstep read its clock 0x2100 (whether they stand for wall-clock time at all). Then
        the synchronous window 0x1007 (0: none): a node that would answer a SYNC later than
        that discards the answer (CiA 301); a node without the object keeps answering late."""
        for link in self.links:
            with sdo_errors(link, "cannot declare the run (0x1006/0x1007) over SDO"):
                link.node.sdo[P.COMM_CYCLE_PERIOD].raw = int(round(period_s * 1e6))
                if P.SYNC_WINDOW in link.node.object_dictionary:
                    link.node.sdo[P.SYNC_WINDOW].raw = int(round(sync_window_s * 1e6))
        if self.stand_clock is not None:  # only a stand that has the object (the emulator)
            with sdo_errors(self.valve, "cannot read its clock (0x2100) over SDO"):
                self.valve.node.sdo[P.EMULATOR_CLOCK].raw

    # -- 5. start / stop ------------------------------------------------------------------------
    def start(self, timeout_s: float = 2.0, keepalive_s: float = 0.02) -> None:
        """NMT start both nodes and wait for OPERATIONAL; a hold command with zero setpoint goes
        to the valve every ``keepalive_s`` meanwhile (its RPDO timeout runs from OPERATIONAL)."""
        start_all([self], timeout_s, keepalive_s)

    def send_valve_command(self, control_word: int, setpoint_counts: int) -> None:
        """One valve RPDO: control word and setpoint (the rest of the mapping zero); an FD frame
        on a CAN FD bus, as every cyclic frame there."""
        send_frames = getattr(self.network, "send_frames", None)
        if send_frames is not None:
            send_frames([self.valve_frame(control_word, setpoint_counts)])
            return
        rpdo = self.valve_rpdo
        values = [0] * len(rpdo.keys)
        values[self._rpdo_cw] = int(control_word)
        values[self._rpdo_sp] = setpoint_counts
        self.network.send_message(rpdo.cob_id, rpdo.encode(*values))

    def valve_frame(self, control_word: int, setpoint_counts: int) -> tuple[int, int, int, bytes]:
        """One valve RPDO as a raw frame (:mod:`standbus.wire`) for
        :meth:`~gateway.capture.TappedNetwork.send_frames`: the bytes of
        :meth:`send_valve_command`, an FD frame on a CAN FD bus."""
        key = (control_word, setpoint_counts)
        if key == self._last_command:    # a held command: the same frame again
            return self._last_frame
        rpdo = self.valve_rpdo
        if self._rpdo_two:               # the default mapping: control word, setpoint
            data = rpdo.codec.pack(control_word, setpoint_counts)
        else:
            values = [0] * len(rpdo.keys)
            values[self._rpdo_cw] = int(control_word)
            values[self._rpdo_sp] = setpoint_counts
            data = rpdo.encode(*values)
        self._last_command = key
        self._last_frame = frame = (self._cyclic_flags, rpdo.cob_id, len(data), data)
        return frame

    def hold_command(self) -> None:
        """One valve RPDO: control word HOLD, setpoint 0 (zero flow)."""
        self.send_valve_command(P.CW_HOLD, 0)

    def enter_preoperational(self, timeout_s: float = 1.0) -> None:
        for link in self.links:
            link.node.nmt.send_command(NMT_PREOP)

    # -- 6. faults ------------------------------------------------------------------------------
    def valve_state(self) -> P.ValveState | None:
        """The valve's device state from its status word 0x6041 (read by SDO; None if unknown)."""
        with sdo_errors(self.valve, "cannot read its status word (0x6041) over SDO"):
            state = int(self.valve.node.sdo[P.STATUS_WORD].raw) & 0xF
        return P.ValveState(state) if state in P.ValveState._value2member_map_ else None

    def reset_valve_fault(self) -> str | None:
        """CiA 408 fault reset: a rising edge of the reset-fault bit of the control word 0x6040,
        written by SDO (so it works in PRE-OPERATIONAL, between runs). A valve in FAULT_HOLD goes
        to DISABLED. Returns what was reset (``"FAULT_HOLD -> DISABLED"``), None if the valve had
        no fault. Raises :class:`NodeError` if the fault stays (its cause is still there)."""
        before = self.valve_state()
        if before is None or not before.is_fault:
            return None
        sdo = self.valve.node.sdo
        with sdo_errors(self.valve, "cannot write its control word (0x6040) over SDO"):
            sdo[P.CONTROL_WORD].raw = 0                       # the edge needs the bit low first
            sdo[P.CONTROL_WORD].raw = int(P.ControlBit.RESET_FAULT)
            sdo[P.CONTROL_WORD].raw = int(P.CW_DISABLED)
        after = self.valve_state()
        if after is None or after.is_fault:
            raise NodeError(self.valve.id, f"valve node {self.valve.id} stayed in "
                                           f"{after.name if after else 'an unknown state'} after a "
                                           "fault reset: its cause is still there (see its EMCY)")
        log.info("valve node %d: fault reset, %s -> %s", self.valve.id, before.name, after.name)
        return f"{before.name} -> {after.name}"

    def wait_state(self, state: int, timeout_s: float, keepalive=None, keepalive_s: float = 0.02,
                   since: float | None = None) -> None:
        """Wait until every node's heartbeat reports ``state``; with ``since`` (monotonic time
        of the NMT command) only heartbeats received after it count: one already on its way
        may still carry the state before the command."""
        wait_links(self.links, state, timeout_s, keepalive, keepalive_s, since)


@contextlib.contextmanager
def sdo_errors(link: NodeLink, what: str) -> Iterator[None]:
    """An SDO timeout or abort on ``link`` as a :class:`NodeError` that names the node and
    says what the master was doing, not canopen's traceback."""
    try:
        yield
    except _SDO_ERRORS as exc:
        timeout = link.node.sdo.RESPONSE_TIMEOUT
        hint = (f" within {timeout * 1e3:g} ms: is it powered and on this bus? On a slow host, "
                "raise --sdo-timeout" if isinstance(exc, canopen.SdoCommunicationError) else "")
        raise NodeError(link.id, f"{link.role} node {link.id}: {what}: {exc}{hint}") from None


# -- every channel of a bus (or of a rig) at once ------------------------------------------------
def boot_links(links, timeout_s: float = 5.0) -> None:
    """Reset every node of ``links`` (NMT reset node) and wait for all their boot-up messages:
    the nodes of all channels boot together, not one channel after the other."""
    for link in links:
        link.booted.clear()
    for link in links:
        link.node.nmt.send_command(NMT_RESET_NODE)
    deadline = time.monotonic() + timeout_s
    resend = time.monotonic() + 1.0
    while time.monotonic() < deadline:
        missing = [l for l in links if not l.booted.is_set()]
        if not missing:
            return
        if time.monotonic() >= resend:  # a node that came up after our reset
            for link in missing:
                link.node.nmt.send_command(NMT_RESET_NODE)
            resend = time.monotonic() + 1.0
        missing[0].booted.wait(0.05)
    missing = [l for l in links if not l.booted.is_set()]
    if missing:
        link = missing[0]
        heard = link.nmt_state is not None
        raise NodeError(
            link.id,
            f"{link.role} node {link.id} did not boot within {timeout_s:g} s"
            + (" (it sends heartbeats but ignored NMT reset)" if heard else
               " (nothing heard from it: is it powered, on this bus, with this node id? "
               "For the emulator run `stand emulate` with the same --bus)"))


def boot_all(masters: "list[StandMaster]", timeout_s: float = 5.0) -> None:
    """Boot the nodes of every channel together (:func:`boot_links`)."""
    boot_links([l for m in masters for l in m.links], timeout_s)


def start_all(masters: "list[StandMaster]", timeout_s: float = 2.0,
              keepalive_s: float = 0.02) -> None:
    """NMT start every node of every channel and wait until all report OPERATIONAL; meanwhile
    a hold command with zero setpoint goes to every valve every ``keepalive_s`` (each valve's
    RPDO timeout runs from its OPERATIONAL, so none may wait for the others' start)."""
    commanded = time.monotonic()
    for m in masters:
        for link in m.links:
            link.node.nmt.send_command(NMT_START)
    holds = [m.hold_command for m in masters if m.valve_rpdo]

    def keepalive() -> None:
        for hold in holds:
            hold()

    wait_links([l for m in masters for l in m.links], 5, timeout_s,
               keepalive if holds else None, keepalive_s, since=commanded)


def wait_links(links, state: int, timeout_s: float, keepalive=None, keepalive_s: float = 0.02,
               since: float | None = None) -> None:
    """Wait until the heartbeat of every node of ``links`` reports ``state`` (see
    :meth:`StandMaster.wait_state`)."""
    deadline = time.monotonic() + timeout_s
    next_keepalive = time.monotonic()
    fresh = (lambda l: True) if since is None else (
        lambda l: l.last_heartbeat is not None and l.last_heartbeat > since)
    while time.monotonic() < deadline:
        if keepalive is not None and time.monotonic() >= next_keepalive:
            keepalive()
            next_keepalive += keepalive_s
        if all(l.nmt_state == state and fresh(l) for l in links):
            return
        time.sleep(0.001)
    for link in links:
        if link.nmt_state != state:
            raise NodeError(link.id, f"{link.role} node {link.id} did not report "
                                     f"{_NMT_NAMES.get(state, state)} within {timeout_s:g} s "
                                     f"(last heartbeat state: {_NMT_NAMES.get(link.nmt_state, link.nmt_state)})")
