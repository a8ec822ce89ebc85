"""The emulated dynamometer (CiA 404 analog input, force in newtons).

Every SYNC it samples the plant's force through :class:`plant.sensor.Dynamometer` (noise,
resolution, range) and publishes the process value 0x9130:01 (INT32) in the unit 0x6131 with
0x6132 decimal digits (default N with one decimal: 0.1 N per count), plus the AI status 0x6150:01.
Leaving the measuring range sets the overload bits and sends EMCY 0xFF10 once; coming back sends
the recovery EMCY 0x0000. EMCYs go out in PRE-OPERATIONAL and OPERATIONAL (CiA 301); a condition
that began while the node could not signal it is signalled as soon as it can (e.g. after a reset
with the force still beyond the range).
"""
from __future__ import annotations

import math

from dbc import profile as P

from .node import EmulatedNode

_INT32 = 2**31 - 1
_PV_INT32, _PV_REAL32, _AI_STATUS, _N_PER_KGF = P.PV_INT32, P.PV_REAL32, P.AI_STATUS, P.N_PER_KGF
_isfinite = math.isfinite


class DynamometerNode(EmulatedNode):
    def __init__(self, network, node_id: int, eds) -> None:
        super().__init__(network, node_id, eds)
        self.over_range = False
        self.over_range_events = 0
        self._signalled = False      # what the last EMCY said: over range or not
        self._scale_kgf = None
        self.publish(0.0, False)

    def on_boot(self) -> None:
        self._scale_kgf = None
        self._signalled = False      # a reset clears the error history

    def _scale(self) -> float:
        if self._scale_kgf is None:
            unit = int(self.value(*P.PV_UNIT))
            decimals = int(self.value(*P.PV_DECIMALS))
            try:
                self._scale_kgf = P.force_scale_kgf(unit, decimals)
            except ValueError:  # a unit we cannot express: stay in 0.1 N
                self._scale_kgf = P.force_scale_kgf(P.UNIT_N_DEFAULT, 1)
        return self._scale_kgf

    def on_object_written(self, index, sub, value) -> None:
        if (index, sub) in (P.PV_UNIT, P.PV_DECIMALS):
            self._scale_kgf = None

    def publish(self, reading_kgf: float, over_range: bool) -> None:
        """Set the process value and status from one reading; EMCY on range transitions."""
        scale = self._scale_kgf or self._scale()
        counts = int(round(reading_kgf / scale)) if _isfinite(reading_kgf) else 0
        if counts > _INT32:
            counts = _INT32
        elif counts < -_INT32:
            counts = -_INT32
        status = 0
        if over_range:
            status = P.AI_STATUS_POSITIVE_OVERLOAD if reading_kgf > 0 else P.AI_STATUS_NEGATIVE_OVERLOAD
        live = self.live
        live[_PV_INT32] = counts
        live[_PV_REAL32] = float(counts * scale * _N_PER_KGF)
        live[_AI_STATUS] = status
        self.over_range = over_range
        if over_range != self._signalled and self.nmt_state in ("PRE-OPERATIONAL", "OPERATIONAL"):
            self._signalled = over_range
            if over_range:
                self.over_range_events += 1
                self.local.emcy.send(P.EMCY_FORCE_OVER_RANGE, 0x01)
            else:
                self.local.emcy.reset()
