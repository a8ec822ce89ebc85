"""Force units: what one count of an amplifier's process value is in kgf.

A CiA 404 amplifier states its unit in 0x6131 (CiA 303-2: the unit code in byte 2, the prefix
in byte 3; the newton is 0x21) and its decimal digits in 0x6132. The kilogram-force has no
CiA 303-2 code, so a device that reports kgf (or one without 0x6131) is given its unit in the
device file by name.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from dbc import profile as P

#: the force units a device file may name: newtons times this, or kgf times this
NEWTON_UNITS = {"N": 1.0, "daN": 10.0, "kN": 1e3, "MN": 1e6, "mN": 1e-3}
KGF_UNITS = {"kgf": 1.0, "tf": 1e3, "lbf": 0.45359237}    # tonne-force; pound-force (exact)
FORCE_UNITS = (*NEWTON_UNITS, *KGF_UNITS)
_PREFIX_NAMES = {0x00: "N", 0x03: "kN", 0xFD: "mN", 0x06: "MN", 0x01: "daN"}


def unit_name_of_code(code: int) -> str:
    """The name of a CiA 303-2 force unit code (0x6131); ValueError if it is not a force."""
    unit, prefix = (code >> 16) & 0xFF, (code >> 24) & 0xFF
    if unit != P.UNIT_NEWTON or prefix not in _PREFIX_NAMES:
        raise ValueError(f"unit code 0x{code:08X} (0x6131) is not a force this gateway knows "
                         "(newtons with no prefix, k, M, m or da); give the unit in the device "
                         "file (unit = \"kN\")")
    return _PREFIX_NAMES[prefix]


def kgf_per_count(unit: str, decimals: int, integer: bool) -> float:
    """kgf per count of a process value in ``unit`` with ``decimals`` decimal digits (an
    integer value: one count is 10^-decimals of the unit; a REAL32 value is in the unit
    itself, CiA 404). ValueError for an unknown unit or decimals outside 0..9."""
    if unit not in NEWTON_UNITS and unit not in KGF_UNITS:
        raise ValueError(f"unit {unit!r} is not a force unit: use one of {', '.join(FORCE_UNITS)}")
    if not 0 <= decimals <= 9:
        raise ValueError(f"decimal digits {decimals} out of range 0..9")
    step = 10.0 ** -decimals if integer else 1.0
    if unit in KGF_UNITS:
        return KGF_UNITS[unit] * step
    # the order of dbc.profile.force_scale_kgf, so a newton count is the same double as before
    return NEWTON_UNITS[unit] * step / P.N_PER_KGF


#: CiA 408's setpoint reference: 16384 counts are 100 % (10 V)
FULL_SCALE_DEFAULT = 16384
_TYPE_LIMITS = {16: 32767, 32: 2**31 - 1}


@dataclass(frozen=True)
class SetpointScale:
    """The valve's setpoint and actual spool position in counts: ``full_scale`` counts are
    100 % (CiA 408 0x6311, 16384 by default), clipped to ±100 % and to the object's type
    (``bits``). For 16384 the counts are :func:`dbc.profile.percent_to_counts`'s, bit for bit."""

    full_scale: int = FULL_SCALE_DEFAULT
    bits: int = 16

    def __post_init__(self) -> None:
        limit = _TYPE_LIMITS.get(self.bits, 32767)
        object.__setattr__(self, "limit", min(self.full_scale, limit))
        object.__setattr__(self, "per_percent", self.full_scale / 100)
        object.__setattr__(self, "percent_per_count", 100.0 / self.full_scale)

    def counts(self, u_percent: float) -> int:
        """Command in % → setpoint counts, rounded and clipped; NaN or infinite gives 0."""
        if not math.isfinite(u_percent):
            return 0
        limit = self.limit
        return int(max(-limit, min(limit, round(u_percent * self.per_percent))))

    def percent(self, counts: float) -> float:
        return counts * self.percent_per_count
