"""The emulated dynamometer: a CiA 404 measuring amplifier as its device file describes it.

Every SYNC it samples the plant's force through :class:`plant.sensor.Dynamometer` (noise,
resolution, range) and publishes the process value in every form its EDS has (CiA 404:
0x9130:01 INTEGER32, 0x7130:01 INTEGER16, 0x6130:01 REAL32), in the unit of 0x6131 with the
0x6132 decimal digits (or those its device file gives; the emulated default: N with one
decimal, 0.1 N per count), plus the AI status 0x6150:01. An integer form is clipped to its
type's range. Leaving the measuring range sets the overload bits and sends EMCY 0xFF10 once;
coming back sends the recovery EMCY 0x0000. EMCYs go out in PRE-OPERATIONAL and OPERATIONAL
(CiA 301); a condition that began while the node could not signal it is signalled as soon as
it can (e.g. after a reset with the force still beyond the range).
"""
from __future__ import annotations

import math

from canopen.objectdictionary import INTEGER16, REAL32

from dbc import profile as P
from devices import Device
from devices.device import find_variable
from devices.roles import role
from devices.units import kgf_per_count, unit_name_of_code

from .node import EmulatedNode

_AI_STATUS = P.AI_STATUS
_isfinite = math.isfinite
_LIMITS = {INTEGER16: 2**15 - 1}
_INT32 = 2**31 - 1


class DynamometerNode(EmulatedNode):
    def __init__(self, network, node_id: int, device: Device,
                 unconfigured_serial: int | None = None) -> None:
        super().__init__(network, node_id, device, unconfigured_serial)
        od = self.local.object_dictionary
        #: the process value's forms the device has: key → (REAL32?, limit of an integer form);
        #: the device file's (mapped, sent every cycle) is kept live, the others made when read
        self._forms = {}
        primary = device.key("process_value")
        for key in (primary, *role("dynamometer", "process_value").candidates):
            var = find_variable(od, key)
            if var is not None and key not in self._forms:
                self._forms[key] = (var.data_type == REAL32, _LIMITS.get(var.data_type, _INT32))
        self._primary = (primary, *self._forms[primary])
        self._counts = 0
        self.over_range = False
        self.over_range_events = 0
        self._signalled = False      # what the last EMCY said: over range or not
        #: kgf per count of an integer form, kgf per unit of a REAL32 form
        self._scales: tuple[float, float] | None = None
        self.publish(0.0, False)

    def on_boot(self) -> None:
        self._scales = None
        self._signalled = False      # a reset clears the error history

    def _scale(self) -> tuple[float, float]:
        """(kgf per count, kgf per unit): the device file's unit and decimals, else those of
        0x6131/0x6132 as they are now; a unit the emulator cannot express stays 0.1 N."""
        if self._scales is None:
            device = self.device
            try:
                unit = device.unit or unit_name_of_code(int(self.value(*device.key("pv_unit"))))
                key = device.key("pv_decimals")
                decimals = device.decimals if device.decimals is not None else (
                    int(self.value(*key)) if key is not None else 0)
                self._scales = (kgf_per_count(unit, decimals, True), kgf_per_count(unit, 0, False))
            except (ValueError, TypeError):
                self._scales = (kgf_per_count("N", 1, True), kgf_per_count("N", 0, False))
        return self._scales

    def _form(self, counts: int, real: bool, limit: int):
        """The process value in one of its forms: a REAL32 in the unit, or clipped counts."""
        if real:
            per_count, per_unit = self._scales or self._scale()
            return counts * per_count / per_unit
        return limit if counts > limit else -limit if counts < -limit else counts

    def _read_live(self, index: int, subindex: int, od):
        form = self._forms.get((index, subindex))
        if form is not None and (index, subindex) != self._primary[0]:
            return self._form(self._counts, *form)        # another form, read over SDO
        return super()._read_live(index, subindex, od)

    def on_object_written(self, index, sub, value) -> None:
        if (index, sub) in (self.device.key("pv_unit"), self.device.key("pv_decimals")):
            self._scales = None

    def publish(self, reading_kgf: float, over_range: bool) -> None:
        """Set the process value and status from one reading; EMCY on range transitions."""
        per_count = (self._scales or self._scale())[0]
        counts = self._counts = int(round(reading_kgf / per_count)) if _isfinite(reading_kgf) else 0
        live = self.live
        key, real, limit = self._primary
        live[key] = self._form(counts, real, limit) if real or not -limit <= counts <= limit else counts
        status = 0
        if over_range:
            status = P.AI_STATUS_POSITIVE_OVERLOAD if reading_kgf > 0 else P.AI_STATUS_NEGATIVE_OVERLOAD
        live[_AI_STATUS] = status
        self.over_range = over_range
        if over_range != self._signalled and self.nmt_state in ("PRE-OPERATIONAL", "OPERATIONAL"):
            self._signalled = over_range
            if over_range:
                self.over_range_events += 1
                self.local.emcy.send(P.EMCY_FORCE_OVER_RANGE, 0x01)
            else:
                self.local.emcy.reset()
