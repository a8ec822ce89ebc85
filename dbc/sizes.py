"""How many data bytes the stand's PDOs carry, read from the EDS files' default mappings (the
mapping the master reads back from each node; CiA 301: each entry 0xIIIISSLL, LL its bits)."""
from __future__ import annotations

import configparser
import functools
from pathlib import Path

from . import DYNAMOMETER_EDS, VALVE_EDS

#: mapping parameter objects: RPDO1, TPDO1
RPDO1_MAPPING, TPDO1_MAPPING = 0x1600, 0x1A00


@functools.lru_cache(maxsize=None)
def pdo_bytes(eds: Path, mapping: int) -> int:
    """Data bytes of the PDO whose mapping parameter is ``mapping`` in ``eds``, by default."""
    cp = configparser.ConfigParser(interpolation=None)
    cp.read(eds)
    section = f"{mapping:04X}"
    count = int(cp[f"{section}sub0"]["DefaultValue"], 0)
    bits = sum(int(cp[f"{section}sub{i}"]["DefaultValue"], 0) & 0xFF for i in range(1, count + 1))
    return bits // 8


def channel_pdo_bytes() -> dict[str, int]:
    """What one loading channel sends per cycle: the valve's command (RPDO1), its status and
    spool (TPDO1), the dynamometer's force (TPDO1)."""
    return {"valve command": pdo_bytes(VALVE_EDS, RPDO1_MAPPING),
            "valve status": pdo_bytes(VALVE_EDS, TPDO1_MAPPING),
            "force": pdo_bytes(DYNAMOMETER_EDS, TPDO1_MAPPING)}
