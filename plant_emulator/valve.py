"""The emulated servo-valve drive (CiA 408 device behaviour).

Device state machine (status word 0x6041 bits 0-3, see :class:`dbc.profile.ValveState`)::

    boot ─▶ INIT ─(control word D)─▶ DISABLED ◀─▶ HOLD ◀─▶ ACTIVE
                                          ▲
    any fault ─▶ FAULT_REACTION ─▶ FAULT_HOLD ─(reset-fault edge)─┘

The spool command that reaches the hydraulics:

* ACTIVE with device mode 1: the bus setpoint 0x6300:01, clipped to the limits 0x6320/0x6321
  (status bit 10 "limit reached" while clipping);
* HOLD and FAULT_HOLD: the hold setpoint 0x6314 (default 0: no flow);
* INIT, DISABLED, FAULT_*: the fail-safe position, zero flow.

Faults: RPDO timeout (EMCY 0x8250; the timer runs from entering OPERATIONAL, so a master that
dies before its first command is caught too; in lockstep it counts the stand's time, one period
per SYNC, see :mod:`plant_emulator.stand`), NMT leaving OPERATIONAL while ACTIVE (goes to
HOLD). A fault holds until a rising edge of the reset-fault bit (recovery EMCY 0x0000); an RPDO
of the wrong length is never applied (EMCY 0x8210, see :mod:`plant_emulator.node`).
"""
from __future__ import annotations

import logging
from typing import Any

from canopen.objectdictionary import ODVariable, UNSIGNED8

from dbc import profile as P
from devices import Device, DeviceError
from devices.device import find_variable
from devices.units import FULL_SCALE_DEFAULT, SetpointScale

from .node import EmulatedNode

log = logging.getLogger(__name__)

#: each state's status word bits and whether it is a fault (enum properties cost ~1 µs a read)
_STATE_BITS = {s: (int(s.value), bool(s.is_fault)) for s in P.ValveState}
_DISABLE, _HOLD, _ACTIVE, _RESET_FAULT = (int(b) for b in (
    P.ControlBit.DISABLE, P.ControlBit.HOLD, P.ControlBit.ACTIVE, P.ControlBit.RESET_FAULT))
_ERROR_KEY = (P.ERROR_REGISTER, 0)
_LIMIT_REACHED = P.STATUS_LIMIT_REACHED


def add_clock_object(od) -> None:
    """The emulator's one object of its own, 0x2100 (0: real time, 1: lockstep; read-only), added
    to whatever device it impersonates: how the master tells an emulated stand that advances
    one period per SYNC from a real one (which has no such object)."""
    if P.EMULATOR_CLOCK in od:
        obj = od[P.EMULATOR_CLOCK]
        if not (isinstance(obj, ODVariable) and obj.data_type == UNSIGNED8):
            raise DeviceError(f"the EDS already has an object 0x{P.EMULATOR_CLOCK:04X} of its own: "
                             "the emulator cannot impersonate it (it uses that index for its clock)")
        return
    var = ODVariable("hydrostand emulator clock", P.EMULATOR_CLOCK, 0)
    var.data_type, var.access_type, var.default = UNSIGNED8, "ro", 0
    od.add_object(var)


class ServoValveNode(EmulatedNode):
    """A CiA 408 valve drive: its roles' objects from its device file (:mod:`devices.roles`)."""

    def __init__(self, network, node_id: int, device: Device, lockstep: bool,
                 unconfigured_serial: int | None = None) -> None:
        super().__init__(network, node_id, device, unconfigured_serial)
        od = self.local.object_dictionary
        self._status_key = device.key("status_word")
        self._spool_key = device.key("actual_spool")
        self._mode_key = device.key("device_mode")
        self._hold_key = device.key("hold_setpoint")
        self._setpoint_key = device.key("setpoint")
        #: the command RPDO's objects in the profile's order (its fast path)
        self._command_keys = (device.key("control_word"), self._setpoint_key)
        self._limits = all(i in od for i in (P.LOWER_LIMIT, P.UPPER_LIMIT))
        full = device.setpoint_full_scale
        reference = device.key("setpoint_reference")
        if full is None and reference is not None:
            full = int(find_variable(od, reference).default or 0) or None
        #: counts at 100 % of the setpoint and the actual spool position
        self.scale = SetpointScale(full or FULL_SCALE_DEFAULT, device.type_bits("setpoint"))
        self.lockstep = lockstep
        self.state = P.ValveState.INIT
        self.setpoint_counts = 0
        self._control_word = 0
        self.limit_reached = False
        self.faults = 0
        #: hooks for the stand: integrate up to now before, re-read the command after a change
        self.before_change = lambda: None
        self.after_change = lambda: None
        #: (position mode, lower and upper limit, hold setpoint), read from the objects once
        #: after they change (the spool command is asked after every command)
        self._spool_objects: tuple[bool, int, int, int] | None = None
        #: the spool command the outputs were last set for
        self._outputs_of: float | None = None
        self._refresh()

    def prepare_od(self, od) -> None:
        add_clock_object(od)

    # -- what the hydraulics see ----------------------------------------------------------------
    def spool_command_percent(self) -> float:
        """The command the valve applies now, in % (positive: force rising)."""
        S = P.ValveState
        objects = self._spool_objects
        if objects is None:
            limit = self.scale.limit
            objects = self._spool_objects = (
                self._mode_key is None or int(self.value(*self._mode_key)) == 1,
                int(self.value(P.LOWER_LIMIT)) if self._limits else -limit,
                int(self.value(P.UPPER_LIMIT)) if self._limits else limit,
                int(self.value(*self._hold_key)) if self._hold_key is not None else 0)
        position, lower, upper, hold = objects
        if self.state is S.ACTIVE and position:
            counts = min(max(self.setpoint_counts, lower), upper)
            self.limit_reached = counts != self.setpoint_counts
            return self.scale.percent(counts)
        self.limit_reached = False
        if self.state in (S.HOLD, S.FAULT_HOLD):
            return self.scale.percent(hold)
        return 0.0

    def stored_changed(self) -> None:
        self._spool_objects = None

    # -- state machine ------------------------------------------------------------------------
    def on_boot(self) -> None:
        self.before_change()
        self.state = P.ValveState.INIT
        self.setpoint_counts = 0
        self._control_word = 0
        self.live[P.EMULATOR_CLOCK, 0] = 1 if self.lockstep else 0
        self._refresh()
        self.after_change()

    def on_leave_operational(self) -> None:
        self.before_change()
        if self.state is P.ValveState.ACTIVE:
            self.state = P.ValveState.HOLD
        self._refresh()
        self.after_change()

    def on_object_written(self, index: int, sub: int, value: Any) -> None:
        self.on_objects_written([((index, sub), value)])

    def rpdo_taker(self, cfg):
        """The command RPDO as the profile maps it (control word, setpoint): stored and applied
        as :meth:`on_objects_written` applies it, without the generic loop."""
        if cfg.layout.keys != self._command_keys or type(self).on_objects_written is not ServoValveNode.on_objects_written:
            return super().rpdo_taker(cfg)
        rpdo_values, stored = self._rpdo_values, self._stored
        word_key, setpoint_key = self._command_keys
        apply = self._apply_control_word

        def take(values) -> None:
            word, setpoint = values
            rpdo_values[word_key] = stored[word_key] = word
            rpdo_values[setpoint_key] = stored[setpoint_key] = setpoint
            self.before_change()
            apply(int(word))
            self.setpoint_counts = int(setpoint)
            self._refresh()
            self.after_change()
        return take

    def on_objects_written(self, changes) -> None:
        """One command (an RPDO: control word and setpoint) changes the spool once."""
        self.before_change()
        word_key, setpoint_key = self._command_keys
        for key, value in changes:
            if key == word_key:
                self._apply_control_word(int(value))
            elif key == setpoint_key:
                self.setpoint_counts = int(value)
        self._refresh()
        self.after_change()

    def _apply_control_word(self, word: int) -> None:
        S = P.ValveState
        # the control bits as plain ints (IntFlag's operators cost ~1 µs each, 16 valves a cycle)
        rising_reset = bool(word & _RESET_FAULT) and not (self._control_word & _RESET_FAULT)
        self._control_word = word
        if _STATE_BITS[self.state][1]:         # a fault state
            if rising_reset:
                self.state = S.DISABLED
                self.local.emcy.reset()
            return
        if not word & _DISABLE:
            if self.state is not S.INIT:
                self.state = S.DISABLED
            return
        if word & _ACTIVE and word & _HOLD:
            self.state = S.ACTIVE
        elif word & _HOLD:
            self.state = S.HOLD
        else:
            self.state = S.DISABLED

    def fault(self, emcy_code: int) -> None:
        """Fault reaction: spool to the hold setpoint, EMCY with the cause."""
        with self.lock:
            if self.state.is_fault:
                return
            self.before_change()
            self.faults += 1
            log.warning("valve node %d: fault 0x%04X (%s) -> FAULT_HOLD", self.id, emcy_code,
                        P.emcy_text(emcy_code))
            self.state = P.ValveState.FAULT_HOLD
            self._refresh()
            self.after_change()
            self.local.emcy.send(emcy_code, 0x01)

    def life_guard_lost(self) -> None:
        """Node guarding: the master is gone; the valve goes to its own safe state."""
        self.fault(P.EMCY_HEARTBEAT)

    def _refresh(self) -> None:
        status, fault = _STATE_BITS[self.state]
        if self.limit_reached:
            status |= _LIMIT_REACHED
        live = self.live
        live[self._status_key] = status
        live[_ERROR_KEY] = 0x01 if fault else 0

    def update_outputs(self, spool_percent: float) -> None:
        """Refresh the values the TPDO carries (status word, actual spool position)."""
        self._refresh()
        if spool_percent != self._outputs_of and self._spool_key is not None:
            self._outputs_of = spool_percent
            self.live[self._spool_key] = self.scale.counts(spool_percent)
