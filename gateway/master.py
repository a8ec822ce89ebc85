"""The gateway as CANopen master of a channel: NMT, identity check, configuration (CiA 301/302).

Each node is the device its device file describes (:mod:`devices`: the EDS and the role
table; by default the emulated valve and dynamometer of dbc/). Start-up, in the order a careful
master does it:

1. reset the nodes (NMT reset node) and wait for their boot-up messages;
2. read the identity object 0x1018 over SDO and compare it with the device's EDS and the
   revisions its file accepts (a wrong node id or device is refused with a message naming the
   node and what was expected);
3. configure each node from its plan (:func:`devices.plan.plan_node`, carried out by
   :mod:`gateway.configure`): error control (heartbeat producer, or node guarding where the
   device has no heartbeat: :mod:`gateway.guarding`), the period, the device mode, the cyclic
   PDOs written where the mapping is dynamic and checked where it is static, every one read
   back; the RPDO timeout where the valve has one;
4. read the amplifier's unit and decimals (or take its device file's) to scale its process value
   to kgf, and the valve's setpoint reference;
5. NMT start, and confirm OPERATIONAL from the heartbeats (or guard answers); meanwhile a hold
   command (zero setpoint) goes to the valve every 20 ms, so its RPDO timeout (armed when it
   enters OPERATIONAL) never fires before the control loop's first command.

Only frames from the two nodes reach the canopen stack: the master declares their ids and data
lengths to the network's acceptance filter (EMCY 8, SDO 8, heartbeat 1, each TPDO its mapped
size once read); anything else is counted and dropped (:class:`gateway.capture.TappedNetwork`).
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field

import canopen
from canopen.objectdictionary import REAL32

from dbc import profile as P
from dbc.pdo_codec import PdoLayout
from devices import DYNAMOMETER, VALVE, Device, DeviceSet, default_devices, plan_node
from devices.units import SetpointScale

from . import configure as C
from .capture import TappedNetwork
from .config import SDO_TIMEOUT_S
from .errors import NodeError
from .guarding import NodeGuarding

log = logging.getLogger(__name__)

NMT_START, NMT_PREOP, NMT_RESET_NODE = P.NMT_START, P.NMT_PREOP, P.NMT_RESET_NODE
_NMT_NAMES = P.NMT_STATE_NAMES
_SDO_ERRORS = (canopen.SdoCommunicationError, canopen.SdoAbortedError)


@dataclass
class NodeLink:
    """What the master knows about one node."""

    role: str                     #: "valve" or "dynamometer"
    node: canopen.RemoteNode
    device: Device = field(default_factory=lambda: default_devices().valve)
    identity: dict = field(default_factory=dict)
    last_heartbeat: float | None = None   #: monotonic time of the last heartbeat (or guard answer)
    nmt_state: int | None = None
    booted: threading.Event = field(default_factory=threading.Event)
    #: what the start-up set on the node and what it lacks (:class:`gateway.configure.NodeSetup`)
    setup: C.NodeSetup = field(default_factory=C.NodeSetup)
    #: node guarding: ask the node for its state now (None: it sends heartbeats)
    poll: object = None
    #: node guarding: the last answer's toggle bit, and answers whose toggle did not alternate
    toggle: int | None = None
    toggle_errors: int = 0

    @property
    def guarded(self) -> bool:
        return self.device.error_control == "guarding"

    @property
    def label(self) -> str:
        return C.node_label(self.role, self.id, self.device)

    @property
    def id(self) -> int:
        return self.node.id


class StandMaster:
    """Master of the valve and dynamometer nodes of one channel on one :class:`TappedNetwork`;
    ``devices``: which devices they are (default: the emulated pair of dbc/)."""

    def __init__(self, network: TappedNetwork, valve_id: int, dynamometer_id: int,
                 sdo_timeout_s: float = SDO_TIMEOUT_S, devices: DeviceSet | None = None) -> None:
        if valve_id == dynamometer_id:
            raise NodeError(valve_id, "the valve and the dynamometer cannot have the same node id")
        for nid in (valve_id, dynamometer_id):
            if not 1 <= nid <= 127:
                raise NodeError(nid, f"node id {nid} is outside 1..127")
        self.network = network
        self.devices = devices = devices or default_devices()
        self.valve = NodeLink(VALVE, canopen.RemoteNode(valve_id, str(devices.valve.eds)), devices.valve)
        self.dynamometer = NodeLink(DYNAMOMETER, canopen.RemoteNode(dynamometer_id, str(devices.dynamometer.eds)),
                                    devices.dynamometer)
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
        #: the positions in those layouts of what the loop reads and writes (``spool_pos`` None:
        #: the valve's actual spool position is not received)
        self.force_pos = self.status_pos = self.cw_pos = self.setpoint_pos = 0
        self.spool_pos: int | None = None
        #: a REAL32 process value: counts of one last digit per unit (y_counts), else None
        self.force_counts_per_unit: float | None = None
        #: the valve's setpoint (and actual spool position) in counts: 100 % = its full scale
        self.setpoint = SetpointScale()
        self.lockstep_capable: bool | None = None
        #: the stand's clock object 0x2100 (0 real time, 1 lockstep), None if it has none
        self.stand_clock: int | None = None
        self.guarding: NodeGuarding | None = None

    def _heartbeat_callback(self, link: NodeLink):
        def on_heartbeat(can_id: int, data: bytes, timestamp: float) -> None:
            if len(data) != 1:
                return
            state = data[0] & 0x7F
            link.last_heartbeat = time.monotonic()
            link.nmt_state = state
            if state == 0:
                link.toggle = None      # a boot-up: guarding's toggle starts again at 0
                link.booted.set()
            elif link.poll is not None:                 # a guard answer: its toggle alternates
                toggle = data[0] >> 7
                if link.toggle is not None and toggle == link.toggle:
                    link.toggle_errors += 1
                link.toggle = toggle
        return on_heartbeat

    # -- 1. boot ----------------------------------------------------------------------------------
    def boot(self, timeout_s: float = 5.0) -> None:
        """Reset both nodes and wait for their boot-up messages."""
        boot_links(self.links, timeout_s)

    # -- 2. identity --------------------------------------------------------------------------------
    def check_identity(self) -> None:
        for link in self.links:
            link.identity = link.setup.identity = C.check_identity(link.node, link.role, link.device)

    # -- 3./4. configuration ------------------------------------------------------------------------
    def configure(self, period_s: float, heartbeat_ms: int, rpdo_timeout_ms: int,
                  life_time_factor: int = 3) -> None:
        """Configure both nodes from their device files (the module doc's steps 3-4); a
        guarded node's life time is ``life_time_factor`` guard times (``heartbeat_ms``)."""
        for link in self.links:
            plan = self._plan(link, period_s, heartbeat_ms, rpdo_timeout_ms, life_time_factor)
            C.write_plan(link.node, link.label, plan)
            setup = link.setup
            setup.plan = plan
            setup.tpdo = C.read_back(link.node, link.label, plan.tpdo)
            setup.rpdo = C.read_back(link.node, link.label, plan.rpdo) if plan.rpdo else None
            setup.notes = list(plan.notes)
        guarded = [link for link in self.links if link.guarded]
        if guarded:
            self.guarding = NodeGuarding(self.network, guarded, heartbeat_ms / 1000.0).start()
        self._set_layouts()
        self.force_scale_kgf = C.force_scale(self.dynamometer.node, DYNAMOMETER, self.devices.dynamometer)
        self.setpoint = C.setpoint_scale(self.valve.node, VALVE, self.devices.valve)
        self.stand_clock = self._stand_clock()
        self.lockstep_capable = self.stand_clock == 1

    def _plan(self, link: NodeLink, period_s: float, heartbeat_ms: int, rpdo_timeout_ms: int,
              life_time_factor: int = 3):
        try:
            return plan_node(link.device, link.id, period_s=period_s, heartbeat_ms=heartbeat_ms,
                             rpdo_timeout_ms=rpdo_timeout_ms if link.role == VALVE else 0,
                             life_time_factor=life_time_factor, od=link.node.object_dictionary)
        except NodeError:
            raise
        except Exception as exc:          # a DeviceError: the device cannot give what is needed
            raise NodeError(link.id, f"{link.label}: {exc}") from None

    def _stand_clock(self) -> int | None:
        """The emulator's clock object 0x2100 (0 real time, 1 lockstep), read whether or not
        the device's EDS lists it (the emulator adds it to whatever device it impersonates); None
        for a device without it (a real one)."""
        try:
            data = self.valve.node.sdo.upload(P.EMULATOR_CLOCK, 0)
        except (*_SDO_ERRORS, KeyError):
            return None
        return data[0] if len(data) == 1 else None

    def configure_from_eds(self, period_s: float = 0.002, heartbeat_ms: int = 100) -> None:
        """Set up the PDO layouts and the scales from the device files' defaults, without
        talking to the nodes (offline use: fuzzing the frame handling, replaying captures)."""
        for link in self.links:
            plan = self._plan(link, period_s, heartbeat_ms, 0)
            link.setup.plan = plan
            link.setup.tpdo = plan.tpdo.layout()
            link.setup.rpdo = plan.rpdo.layout() if plan.rpdo else None
        self._set_layouts()
        self.force_scale_kgf = self.devices.dynamometer.nominal_kgf_per_count()
        self._set_counts_per_unit()
        self.setpoint = SetpointScale(self.devices.valve.setpoint_full_scale or 16384,
                                      self.devices.valve.type_bits("setpoint"))
        self.lockstep_capable = False

    def _set_counts_per_unit(self) -> None:
        dyn = self.devices.dynamometer
        if dyn.types["process_value"] == REAL32:     # y_counts: the value in its unit's last digit
            decimals = dyn.decimals if dyn.decimals is not None else 3
            self.force_counts_per_unit = 10.0 ** decimals
        else:
            self.force_counts_per_unit = None

    def _set_layouts(self) -> None:
        """The control loop's PDO layouts as read back, and the positions of the roles in them;
        the frame filter then accepts exactly those TPDOs."""
        valve, dyn = self.devices.valve, self.devices.dynamometer
        self.valve_tpdo = self._checked(self.valve, self.valve.setup.tpdo, ("status_word",))
        self.valve_rpdo = self._checked(self.valve, self.valve.setup.rpdo, ("control_word", "setpoint"))
        self.force_tpdo = self._checked(self.dynamometer, self.dynamometer.setup.tpdo, ("process_value",))
        self.status_pos = self.valve_tpdo.position(*valve.key("status_word"))
        spool = valve.key("actual_spool")
        self.spool_pos = (self.valve_tpdo.position(*spool)
                          if spool is not None and spool in self.valve_tpdo.keys else None)
        self.cw_pos = self.valve_rpdo.position(*valve.key("control_word"))
        self.setpoint_pos = self.valve_rpdo.position(*valve.key("setpoint"))
        self.force_pos = self.force_tpdo.position(*dyn.key("process_value"))
        self._set_counts_per_unit()
        self._rpdo_two = len(self.valve_rpdo.keys) == 2 and (self.cw_pos, self.setpoint_pos) == (0, 1)
        self._cyclic_flags = getattr(self.network, "cyclic_flags", 0)
        self._last_command = self._last_frame = None
        if hasattr(self.network, "expect"):
            for layout in (self.valve_tpdo, self.force_tpdo):
                self.network.expect(layout.cob_id, layout.size)

    def _checked(self, link: NodeLink, layout: PdoLayout | None, roles) -> PdoLayout:
        if layout is None:
            raise NodeError(link.id, f"{link.label}: no PDO was set up for {', '.join(roles)}")
        for role in roles:
            key = link.device.key(role)
            if tuple(key) not in layout.keys:
                raise NodeError(link.id, f"{link.label}: PDO 0x{layout.cob_id:X} does not map "
                                         f"0x{key[0]:04X}:{key[1]:02X}, which the control loop needs")
        return layout

    def notes(self) -> list[str]:
        """What the devices lack and what the run then cannot do (one line each, named)."""
        return [f"{link.role} node {link.id}: {note}" for link in self.links for note in link.setup.notes]

    def describe(self) -> dict:
        """For run.json: each node's device file, identity and the configuration it was given."""
        out = {}
        for link in self.links:
            entry = link.device.describe()
            if link.setup.plan is not None:
                entry["configuration"] = link.setup.plan.describe()
            out[link.role] = entry
        return out

    def declare_run(self, period_s: float, sync_window_s: float = 0.0) -> None:
        """At each run start, make the run's capture self-describing: write the communication
        cycle period 0x1006 again (which period the SYNCs stand for), and on a stand that can run
        in lockstep read its clock 0x2100 (whether they stand for wall-clock time at all). Then
        the synchronous window 0x1007 (0: none): a node that would answer a SYNC later than
        that discards the answer (CiA 301); a node without the object keeps answering late."""
        for link in self.links:
            with sdo_errors(link, "cannot declare the run (0x1006/0x1007) over SDO"):
                if P.COMM_CYCLE_PERIOD in link.node.object_dictionary:
                    link.node.sdo[P.COMM_CYCLE_PERIOD].raw = int(round(period_s * 1e6))
                if P.SYNC_WINDOW in link.node.object_dictionary:
                    link.node.sdo[P.SYNC_WINDOW].raw = int(round(sync_window_s * 1e6))
        if self.stand_clock is not None:  # only a stand that has the object (the emulator)
            with sdo_errors(self.valve, "cannot read its clock (0x2100) over SDO"):
                self.valve.node.sdo.upload(P.EMULATOR_CLOCK, 0)

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
        self.network.send_message(rpdo.cob_id, self._command_data(control_word, setpoint_counts))

    def _command_data(self, control_word: int, setpoint_counts: int) -> bytes:
        """The command RPDO's data: control word and setpoint, every other mapped object 0."""
        rpdo = self.valve_rpdo
        if self._rpdo_two:               # control word, setpoint (the profile's order)
            return rpdo.codec.pack(control_word, setpoint_counts)
        values = [0] * len(rpdo.keys)
        values[self.cw_pos] = int(control_word)
        values[self.setpoint_pos] = setpoint_counts
        return rpdo.encode(*values)

    def valve_frame(self, control_word: int, setpoint_counts: int) -> tuple[int, int, int, bytes]:
        """One valve RPDO as a raw frame (:mod:`standbus.wire`) for
        :meth:`~gateway.capture.TappedNetwork.send_frames`: the bytes of
        :meth:`send_valve_command`, an FD frame on a CAN FD bus."""
        key = (control_word, setpoint_counts)
        if key == self._last_command:    # a held command: the same frame again
            return self._last_frame
        data = self._command_data(control_word, setpoint_counts)
        self._last_command = key
        self._last_frame = frame = (self._cyclic_flags, self.valve_rpdo.cob_id, len(data), data)
        return frame

    def hold_command(self) -> None:
        """One valve RPDO: control word HOLD, setpoint 0 (zero flow)."""
        self.send_valve_command(P.CW_HOLD, 0)

    def enter_preoperational(self, timeout_s: float = 1.0) -> None:
        for link in self.links:
            link.node.nmt.send_command(NMT_PREOP)

    def close(self) -> None:
        """Stop guarding the nodes (a guarded node then goes to its own safe state once its
        life time passes, as when the master dies)."""
        if self.guarding is not None:
            self.guarding.stop()
            self.guarding = None

    # -- 6. faults ------------------------------------------------------------------------------
    def valve_state(self) -> P.ValveState | None:
        """The valve's device state from its status word 0x6041 (read by SDO; None if unknown)."""
        with sdo_errors(self.valve, "cannot read its status word over SDO"):
            state = int(C.sdo_variable(self.valve.node, self.devices.valve.key("status_word")).raw) & 0xF
        return P.ValveState(state) if state in P.ValveState._value2member_map_ else None

    def reset_valve_fault(self) -> str | None:
        """CiA 408 fault reset: a rising edge of the reset-fault bit of the control word 0x6040,
        written by SDO (so it works in PRE-OPERATIONAL, between runs). A valve in FAULT_HOLD goes
        to DISABLED. Returns what was reset (``"FAULT_HOLD -> DISABLED"``), None if the valve had
        no fault. Raises :class:`NodeError` if the fault stays (its cause is still there)."""
        before = self.valve_state()
        if before is None or not before.is_fault:
            return None
        word = C.sdo_variable(self.valve.node, self.devices.valve.key("control_word"))
        with sdo_errors(self.valve, "cannot write its control word over SDO"):
            word.raw = 0                       # the edge needs the bit low first
            word.raw = int(P.ControlBit.RESET_FAULT)
            word.raw = int(P.CW_DISABLED)
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


def sdo_errors(link: NodeLink, what: str):
    """An SDO timeout or abort on ``link`` as a :class:`NodeError` that names the node and
    says what the master was doing (:func:`gateway.configure.sdo_errors`)."""
    return C.sdo_errors(link.label, link.node, what)


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
    guarded = [l for l in links if l.poll is not None]    # ask them: they send no heartbeat
    while time.monotonic() < deadline:
        if time.monotonic() >= next_keepalive:
            if keepalive is not None:
                keepalive()
            for link in guarded:
                if not (link.nmt_state == state and fresh(link)):
                    link.poll()
            next_keepalive += keepalive_s
        if all(l.nmt_state == state and fresh(l) for l in links):
            return
        time.sleep(0.001)
    for link in links:
        if link.nmt_state != state:
            hint = (": the device does not take the master's NMT start; look for its EMCY in the "
                    "run's capture (it begins with the start-up), and whether it must be enabled by "
                    "its own tool or input first" if state == 5 else "")
            raise NodeError(link.id, f"{link.label} did not report "
                                     f"{_NMT_NAMES.get(state, state)} within {timeout_s:g} s "
                                     f"(last heartbeat state: {_NMT_NAMES.get(link.nmt_state, link.nmt_state)})"
                                     + hint)
