"""An emulated CANopen slave: what ``canopen.LocalNode`` does not do by itself.

``LocalNode`` gives us the object dictionary (from the EDS), the SDO server, heartbeat and EMCY
producers. This class adds, per CiA 301:

* the NMT state machine with boot-up (and boot-up again after reset node / reset communication);
* PDOs configured from the object dictionary *as the master wrote it over SDO* when the node
  enters OPERATIONAL, and only active while OPERATIONAL;
* synchronous TPDOs on SYNC (transmission types 1..240: every n-th SYNC);
* received RPDOs written into the object dictionary and handed to the device;
* RPDO length errors counted (and reported by EMCY 0x8210), never decoded as garbage;
* the RPDO timeout (event timer 0x1400+n sub 5) checked by :meth:`check_rpdo_timeout`; it runs
  from the moment the node enters OPERATIONAL, so a master that dies before its first command
  is caught too. It counts on :attr:`EmulatedNode.clock`: the wall clock by default, the
  stand's own time (advanced by SYNC) in lockstep;
* an acceptance filter (:func:`slave_frame_filter`) in front of the stack: NMT commands must
  have 2 bytes, SYNC 0 or 1, SDO requests 8; error, remote, extended-id and FD frames never
  reach it (counted and dropped, as a CAN controller's filter and a careful stack would), but
  for node guarding's remote frames, which go to the node's guarding (:mod:`.guarding`);
* the object dictionary of any device file's EDS (:class:`devices.Device`); error control as it
  has it: a heartbeat producer (0x1017), or node guarding (0x100C/0x100D) with life guarding;
* the SDO server as strict as CiA 301 asks of a PDO's configuration (:mod:`.pdo_rules`), on top
  of canopen's own aborts (no such object or sub-index, read-only, write-only, wrong length).

Device behaviour (valve, dynamometer) lives in subclasses.
"""
from __future__ import annotations

import logging
import operator
import struct
import threading
import time
from dataclasses import dataclass
from typing import Any

import canopen
from canopen.network import MessageListener
from canopen.nmt import NMT_STATES

from canopen.nmt import NmtBase

from dbc import profile as P
from dbc.pdo_codec import PdoLayout, PdoLayoutError
from devices import Device
from devices.device import find_variable
from standbus.faults import FrameFilter

from .guarding import GUARD_TIME, LIFE_TIME_FACTOR, GuardedNode
from .lss import LSS_MASTER, LssDevice
from .pdo_rules import check_pdo_write

log = logging.getLogger(__name__)

NMT_STATE_CODES = {name: code for code, name in NMT_STATES.items()}
NMT_START, NMT_STOP, NMT_PREOP, NMT_RESET_NODE, NMT_RESET_COMM = (
    P.NMT_START, P.NMT_STOP, P.NMT_PREOP, P.NMT_RESET_NODE, P.NMT_RESET_COMM)
EMCY_PDO_LENGTH = P.EMCY_PDO_LENGTH
PDO_DISABLED = 1 << 31


@dataclass
class PdoConfig:
    """One PDO as configured in the object dictionary."""

    layout: PdoLayout
    trans_type: int
    event_timer_ms: int

    def __post_init__(self) -> None:
        keys = self.layout.keys
        getter = operator.itemgetter(*keys) if keys else (lambda live: ())
        #: the mapped objects' values from a node's ``live`` (KeyError if one is not live)
        self.live_values = getter if len(keys) != 1 else (lambda live: (getter(live),))
        #: the layout's COB-ID, size and codec, looked up once (read every cycle)
        self.cob_id = self.layout.cob_id
        self.size = self.layout.size
        self.pack = self.layout.codec.pack
        self.unpack = self.layout.codec.unpack


def read_pdo_config(node: canopen.LocalNode, com_index: int, map_index: int) -> PdoConfig | None:
    """The PDO at ``com_index``/``map_index`` as currently stored in the node (None if disabled)."""
    sdo = node.sdo
    cob = sdo[com_index][1].raw
    if cob & PDO_DISABLED:
        return None
    trans = sdo[com_index][2].raw
    try:
        timer = sdo[com_index][5].raw
    except (KeyError, canopen.SdoAbortedError):
        timer = 0
    entries = []
    for sub in range(1, sdo[map_index][0].raw + 1):
        value = sdo[map_index][sub].raw
        index, subindex, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
        obj = node.object_dictionary[index]
        if not isinstance(obj, canopen.objectdictionary.ODVariable):
            obj = obj[subindex]
        entries.append((index, subindex, bits, obj.data_type))
    return PdoConfig(PdoLayout.from_entries(cob & 0x7FF, entries), trans, timer)


def slave_frame_filter(network: canopen.Network, node_ids, fd: bool = False) -> FrameFilter:
    """Put an acceptance filter in front of ``network``'s canopen stack (before ``connect`` or
    before the Notifier is made from ``network.listeners``) and return it. On a CAN FD bus
    (``fd``) FD data frames pass too."""
    flt = FrameFilter(MessageListener(network).on_message_received, fd=fd)
    flt.expect(P.NMT_COB_ID, 2)     # NMT: command, node id
    flt.expect(P.SYNC_COB_ID, (0, 1))   # SYNC, with or without counter
    for nid in node_ids:
        flt.expect(P.SDO_RX_BASE + nid, 8)  # SDO client → server
    network.listeners = [flt]
    return flt


class EmulatedNode:
    """A CANopen slave on ``network``: the device ``device`` describes (its EDS's object
    dictionary and error control)."""

    def __init__(self, network: canopen.Network, node_id: int, device: Device,
                 unconfigured_serial: int | None = None) -> None:
        self.id = node_id
        self.network = network
        self.device = device
        #: LSS (CiA 305): a node started without a node id answers only LSS until it is given
        #: one (``unconfigured_serial``: its serial number, its LSS address's last part)
        self.lss: LssDevice | None = None
        #: called with the node after it took a new node id (the bus's filter then expects it)
        self.id_changed = lambda node: None
        self.local = self._make_local(node_id, unconfigured_serial)
        od = self.local.object_dictionary
        #: the device's error control: a heartbeat producer, else node guarding
        self.has_heartbeat = 0x1017 in od
        self.guarding = GuardedNode(self) if GUARD_TIME in od and LIFE_TIME_FACTOR in od else None
        network.subscribe(0, self._on_nmt)      # we run the NMT state machine ourselves
        if unconfigured_serial is None:
            self._attach()
        else:
            identity = [int(find_variable(od, (0x1018, s)).default or 0) if find_variable(od, (0x1018, s))
                        else 0 for s in (1, 2, 3, 4)]
            self.lss = LssDevice(self, identity)
            network.subscribe(LSS_MASTER, self.lss.on_request)
        #: live values of objects the device computes (status word, process value, ...)
        self.live: dict[tuple[int, int], Any] = {}
        #: stored values already decoded (the SYNC path reads a few objects every cycle; through
        #: canopen's SDO layer a read costs ~10 µs). Kept exact: every SDO write updates it,
        #: PDO writes and resets drop what they change.
        self._stored: dict[tuple[int, int], Any] = {}
        #: values the RPDOs wrote last, by object: what an SDO read of the object returns (the
        #: read callback), until an SDO write or a reset replaces it. Kept decoded: encoding
        #: each into the object dictionary's store cost ~3 µs a value, 32 values a cycle
        self._rpdo_values: dict[tuple[int, int], Any] = {}
        #: called (no arguments) each time the node enters OPERATIONAL, after its own hook
        self.started_listeners: list = []
        self.tpdos: list[PdoConfig] = []
        self._every_sync = False
        self.rpdos: dict[int, PdoConfig] = {}
        #: (the RPDO configs it was computed from, the shortest event timer in s or None)
        self._rpdo_timers: tuple | None = None
        self._sync_count = 0
        #: synchronous TPDOs discarded because their SYNC's window (0x1007) had passed
        self.sync_window_discards = 0
        self.rpdo_length_errors = 0
        self.last_rpdo_time: float | None = None
        #: the clock the RPDO timeout counts on (s): the wall clock, or in lockstep the stand's
        #: own time, which only SYNCs advance (set by the stand)
        self.clock = time.monotonic
        self.lock = threading.RLock()
        #: its heartbeat is silenced (a scheduled fault: :meth:`silence_heartbeat`)
        self.heartbeat_silent = False
        #: the bus notifier's own handlers by arbitration id (``HandoverNotifier.fast``, set by
        #: the emulator once it listens): an RPDO is taken there, raw, without a Message and the
        #: canopen dispatch; None: through canopen only
        self.fast_rx: dict | None = None
        #: the wire flags of the synchronous TPDOs (an FD frame on a CAN FD bus)
        self.cyclic_flags = 0

    # -- the node id ---------------------------------------------------------------------------
    def _make_local(self, node_id: int, serial: int | None = None) -> canopen.LocalNode:
        """The device's canopen node at ``node_id`` (not yet on the network): its object
        dictionary from the EDS (with the node id in its $NODEID defaults), the serial number
        ``serial`` where given, the device's own objects (:meth:`prepare_od`)."""
        local = canopen.LocalNode(node_id, str(self.device.eds))
        od = local.object_dictionary
        if serial is not None and find_variable(od, (0x1018, 4)) is not None:
            od[0x1018][4].default = serial
        self.prepare_od(od)
        return local

    def _attach(self) -> None:
        """Put the canopen node on the network: its SDO server answers from now on."""
        self.network.add_node(self.local)
        # We run the NMT state machine ourselves (LocalNode does not reboot on reset).
        self.network.unsubscribe(0, self.local.nmt.on_command)
        self.local.add_read_callback(self._read_live)
        self.local.add_write_callback(self._on_sdo_write)

    @property
    def configured(self) -> bool:
        """It has a node id (a node started unconfigured has none until LSS gives it one)."""
        return self.lss is None or self.lss.configured

    def take_node_id(self, node_id: int) -> None:
        """LSS gave this node ``node_id``: it becomes that node (its object dictionary's
        $NODEID defaults with it) and boots."""
        with self.lock:
            if self.configured and self.local.id in self.network.nodes:
                self.local.nmt.stop_heartbeat()
                self.local.remove_network()
                del self.network.nodes[self.local.id]
            serial = int(self.value(0x1018, 4)) if find_variable(
                self.local.object_dictionary, (0x1018, 4)) is not None else None
            self.id = node_id
            self.local = self._make_local(node_id, serial)
            self._stored.clear()
            self._rpdo_values.clear()
            self._attach()
            self.id_changed(self)
            self.boot()

    def prepare_od(self, od) -> None:
        """A device's own changes to its object dictionary before the node uses it."""

    # -- NMT ----------------------------------------------------------------------------------
    @property
    def nmt_state(self) -> str:
        return self.local.nmt.state

    @property
    def operational(self) -> bool:
        return self.local.nmt._state == 5       # canopen's code of OPERATIONAL (nmt.state)

    def boot(self) -> None:
        """Power-on / reset: send the boot-up message and enter PRE-OPERATIONAL (a node
        without a node id stays silent: it answers LSS only)."""
        if not self.configured:
            return
        with self.lock:
            self._stop_pdos()
            self.local.nmt.send_command(NMT_RESET_NODE)   # INITIALISING, sends boot-up
            if self.has_heartbeat:
                self.local.nmt.send_command(NMT_PREOP)    # PRE-OPERATIONAL, starts heartbeat
            else:                                         # no producer to start (guarded)
                NmtBase.send_command(self.local.nmt, NMT_PREOP)
            if self.guarding is not None:
                self.guarding.reset()
            self.on_boot()

    def _on_nmt(self, can_id: int, data: bytes, timestamp: float) -> None:
        if len(data) < 2:
            return
        command, node_id = data[0], data[1]
        if node_id not in (0, self.id) or not self.configured:
            return
        with self.lock:
            if command in (NMT_RESET_NODE, NMT_RESET_COMM):
                self._stored.clear()
                self.stored_changed()
                if command == NMT_RESET_NODE:
                    self.local.data_store.clear()    # application parameters back to EDS values
                    self._rpdo_values.clear()
                else:
                    for index in [i for i in self.local.data_store if 0x1000 <= i < 0x2000]:
                        del self.local.data_store[index]
                    for key in [k for k in self._rpdo_values if 0x1000 <= k[0] < 0x2000]:
                        del self._rpdo_values[key]
                self.boot()
                return
            was_operational = self.operational
            before = self.nmt_state
            self.local.nmt.on_command(can_id, data, timestamp)
            if self.operational and not was_operational:
                self._start_pdos()
            elif was_operational and not self.operational:
                self._stop_pdos()
                self.on_leave_operational()
            if self.nmt_state != before:
                self._heartbeat_now()

    def _heartbeat_now(self) -> None:
        """A heartbeat right at a state change (as CANopenNode devices send one), so the master
        sees the new state at once instead of up to one heartbeat period later."""
        if self.has_heartbeat and int(self.value(0x1017)) > 0 and not self.heartbeat_silent:
            state = NMT_STATE_CODES[self.nmt_state]
            self.network.send_message(P.HEARTBEAT_BASE + self.id, bytes((state,)))

    def silence_heartbeat(self, duration_s: float) -> None:
        """No heartbeat for ``duration_s`` s of the wall clock, then heartbeats as before (a
        scheduled fault, :mod:`plant_emulator.scheduled_faults`); everything else goes on."""
        with self.lock:
            self.heartbeat_silent = True
            self.local.nmt.stop_heartbeat()

        def again() -> None:
            with self.lock:
                self.heartbeat_silent = False
                period_ms = int(self.value(0x1017)) if self.has_heartbeat else 0
                if period_ms > 0:
                    self.local.nmt.start_heartbeat(period_ms)
        timer = threading.Timer(duration_s, again)
        timer.daemon = True
        timer.start()

    def _start_pdos(self) -> None:
        od = self.local.object_dictionary
        self.tpdos = []
        for n in range(512):
            if 0x1800 + n not in od:
                break
            cfg = self._pdo(0x1800 + n, 0x1A00 + n)
            if cfg is not None:
                self.tpdos.append(cfg)
        self.rpdos = {}
        for n in range(512):
            if 0x1400 + n not in od:
                break
            cfg = self._pdo(0x1400 + n, 0x1600 + n)
            if cfg is not None:
                self.rpdos[cfg.layout.cob_id] = cfg
                self.network.subscribe(cfg.layout.cob_id, self._on_rpdo)
                if self.fast_rx is not None:
                    self.fast_rx[cfg.layout.cob_id] = self._fast_rpdo(cfg.layout.cob_id)
        self._sync_count = 0
        #: every TPDO is due at every SYNC (transmission type 0 or 1, the stand's)
        self._every_sync = all(cfg.trans_type in (0, 1) for cfg in self.tpdos)
        # The RPDO timeout runs from the start: a master that dies before its first command
        # is caught too.
        self.last_rpdo_time = self.clock()
        self.on_operational()
        for listener in self.started_listeners:
            listener()

    def _pdo(self, com: int, mapping: int) -> PdoConfig | None:
        try:
            return read_pdo_config(self.local, com, mapping)
        except (PdoLayoutError, KeyError, canopen.SdoAbortedError) as exc:
            log.error("node %d: PDO 0x%04X not usable: %s", self.id, com, exc)
            self.local.emcy.send(0x8200, 0x10)  # protocol error
            return None

    def _fast_rpdo(self, cob: int):
        """The RPDO's handler in the bus's notifier: :meth:`_on_rpdo`, its usual case (the
        configured RPDO of its length, the node OPERATIONAL) without the look-ups; anything else
        through :meth:`_on_rpdo` itself."""
        cfg = self.rpdos[cob]
        size, unpack = cfg.size, cfg.unpack
        nmt = self.local.nmt
        rpdos, lock, on_rpdo_ = self.rpdos, self.lock, self._on_rpdo
        take = self.rpdo_taker(cfg)

        def on_rpdo(data: bytes, stamp: float) -> bool:
            if len(data) != size or nmt._state != 5 or self.rpdos is not rpdos:
                on_rpdo_(cob, data, stamp)
                return True
            with lock:
                if nmt._state != 5:                  # (changed meanwhile by another thread)
                    on_rpdo_(cob, data, stamp)
                    return True
                self.last_rpdo_time = self.clock()
                take(unpack(data))
            return True
        return on_rpdo

    def rpdo_taker(self, cfg: PdoConfig):
        """``take(values)``: what :meth:`_on_rpdo` does with a well-formed RPDO of ``cfg``'s
        values once its time is noted (store them, tell the device); a device may give a faster
        one for a mapping it knows."""
        keys = cfg.layout.keys
        rpdo_values, stored = self._rpdo_values, self._stored

        def take(values) -> None:
            changes = list(zip(keys, values))
            for key, value in changes:
                rpdo_values[key] = stored[key] = value
            self.on_objects_written(changes)
        return take

    def _stop_pdos(self) -> None:
        for cob in list(self.rpdos):
            try:
                self.network.unsubscribe(cob, self._on_rpdo)
            except (KeyError, ValueError):
                pass
            if self.fast_rx is not None:
                self.fast_rx.pop(cob, None)
        self.rpdos = {}
        self.tpdos = []
        self._every_sync = False
        self.last_rpdo_time = None

    # -- PDO traffic --------------------------------------------------------------------------
    def on_sync(self, counter: int | None, sync_stamp: float | None = None,
                out: list | None = None) -> None:
        """Send the synchronous TPDOs due at this SYNC (the device refreshed ``live`` before);
        with ``out``, append them there as raw frames instead (the emulator sends a bus's
        answers to one SYNC together).
        With a synchronous window (0x1007, CiA 301) and the SYNC's wall-clock ``sync_stamp``, a
        device that got to this SYNC later than the window after it (a lagging node, a slow
        bus) discards its TPDOs instead of sending them: sent after the master's next SYNC, they
        would pass for answers to that one."""
        if self.local.nmt._state != 5:         # not OPERATIONAL
            return
        self._sync_count += 1
        if self._every_sync:
            if sync_stamp is None and out is not None:   # the usual case (lockstep), in one go
                live, flags = self.live, self.cyclic_flags
                for cfg in self.tpdos:
                    try:
                        data = cfg.pack(*cfg.live_values(live))
                    except KeyError:
                        self.transmit(cfg, out)
                        continue
                    out.append((flags, cfg.cob_id, cfg.size, data))
                return
            due = self.tpdos
        else:
            due = [cfg for cfg in self.tpdos
                   if cfg.trans_type == 0 or (1 <= cfg.trans_type <= 240
                                              and self._sync_count % cfg.trans_type == 0)]
        if not due:
            return
        window_us = int(self.value(P.SYNC_WINDOW)) if sync_stamp is not None else 0
        if window_us and time.time() - sync_stamp > window_us * 1e-6:
            self.sync_window_discards += len(due)
            return
        for cfg in due:
            self.transmit(cfg, out)

    def transmit(self, cfg: PdoConfig, out: list | None = None) -> None:
        live = self.live
        try:                 # a PDO of live values only (the stand's): one C call reads them
            values = cfg.live_values(live)
        except KeyError:
            value = self.value
            values = [live[key] if key in live else value(*key) for key in cfg.layout.keys]
        data = cfg.pack(*values)
        if out is None:
            self.network.send_message(cfg.cob_id, data)
        else:
            out.append((self.cyclic_flags, cfg.cob_id, len(data), data))

    def _on_rpdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self.lock:
            cfg = self.rpdos.get(can_id)
            if cfg is None or not self.operational:
                return
            if len(data) != cfg.layout.size:
                self.rpdo_length_errors += 1
                self.local.emcy.send(EMCY_PDO_LENGTH, 0x10, struct.pack("<H", len(data)))
                return
            self.last_rpdo_time = self.clock()
            changes = list(zip(cfg.layout.keys, cfg.layout.decode(data)))
            for (index, sub), value in changes:
                self.store_object(index, sub, value)
            self.on_objects_written(changes)

    def rpdo_timeout_due(self, now: float) -> bool:
        """True if an RPDO with an event timer is overdue (without reporting it). Asked at every
        SYNC, so the lock is taken only to read the timers again after the RPDOs changed."""
        last = self.last_rpdo_time
        if last is None:
            return False
        timeout = self._rpdo_timeout_s()
        # (1 ns of slack: the stand's time in lockstep is a sum of periods in floats)
        return (timeout is not None and now - last > timeout + 1e-9
                and self.local.nmt._state == 5)                    # OPERATIONAL

    def _rpdo_timeout_s(self) -> float | None:
        """The shortest event timer of the RPDOs as configured now (s), None without one."""
        timers = self._rpdo_timers
        if timers is None or timers[0] is not self.rpdos:
            with self.lock:
                ms = [c.event_timer_ms for c in self.rpdos.values() if c.event_timer_ms]
                timers = self._rpdo_timers = (self.rpdos, min(ms) / 1000.0 if ms else None)
        return timers[1]

    def check_rpdo_timeout(self, now: float) -> bool:
        """True once if an RPDO with an event timer has not arrived within it."""
        with self.lock:
            if not self.rpdo_timeout_due(now):
                return False
            self.last_rpdo_time = None  # report once until the next RPDO
            return True

    # -- object access ------------------------------------------------------------------------
    def value(self, index: int, sub: int = 0) -> Any:
        """Current value of an object: live value if the device computes it, else the stored one."""
        key = (index, sub)
        if key in self.live:
            return self.live[key]
        try:
            return self._stored[key]
        except KeyError:
            pass
        var = self.local.sdo[index]
        if sub or not isinstance(var, canopen.sdo.SdoVariable):
            var = var[sub]
        value = self._stored[key] = var.raw
        return value

    def store_object(self, index: int, sub: int, value: Any) -> None:
        """Store a value received by PDO (the device is told by the caller): it is the object's
        value for :meth:`value` and for an SDO read, until an SDO write or a reset."""
        self._rpdo_values[index, sub] = self._stored[index, sub] = value
        self.stored_changed()

    def _read_live(self, index: int, subindex: int, od: Any) -> Any:
        key = (index, subindex)
        value = self.live.get(key)
        return self._rpdo_values.get(key) if value is None else value

    def _on_sdo_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        # canopen calls this before it stores ``data``; the cache takes the new value at once
        # (under the lock), so no reader can cache the old one in between. A write CiA 301
        # forbids raises its abort here (canopen's server sends it; nothing is stored).
        with self.lock:
            value = od.decode_raw(data)
            if 0x1400 <= index < 0x1C00:
                check_pdo_write(self, index, subindex, int(value))
            self._rpdo_values.pop((index, subindex), None)
            if index >= 0x2000:
                self.on_object_written(index, subindex, value)
            self._stored[index, subindex] = value
            self.stored_changed()

    # -- device hooks -------------------------------------------------------------------------
    def stored_changed(self) -> None:
        """A stored object changed (an SDO write, a PDO's stored value, a reset): a device
        drops what it derived from them."""

    def on_boot(self) -> None:
        """After boot-up (power-on or reset)."""

    def life_guard_lost(self) -> None:
        """Node guarding: the master stopped asking within the life time (EMCY 0x8130, life
        guard error; a device reacts more in its subclass)."""
        self.local.emcy.send(P.EMCY_HEARTBEAT, 0x10)

    def on_operational(self) -> None:
        """After entering OPERATIONAL (PDOs are configured)."""

    def on_leave_operational(self) -> None:
        """After leaving OPERATIONAL (STOPPED or PRE-OPERATIONAL)."""

    def on_object_written(self, index: int, sub: int, value: Any) -> None:
        """A device object was written by RPDO or SDO."""

    def on_objects_written(self, changes: list[tuple[tuple[int, int], Any]]) -> None:
        """The objects of one RPDO were written, ``[((index, sub), value), ...]`` (by default
        :meth:`on_object_written` for each)."""
        for (index, sub), value in changes:
            self.on_object_written(index, sub, value)
