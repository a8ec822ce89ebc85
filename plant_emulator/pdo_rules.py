"""What an emulated node's SDO server refuses when a master changes its PDOs (CiA 301 §7.5.2.35
ff.), so the gateway's configuration is checked against a device as strict as a real one.

* a PDO's COB-ID may not change while the PDO is valid (bit 31 clear): abort 0x06090030;
* a mapping entry may be written only while the mapping count (sub-index 0) is 0: 0x08000022;
* an entry must name an object the device has (0x06020000 / 0x06090011), that may be mapped
  (PDOMapping=1: 0x06040041), with its own length (0x06040041), readable for a TPDO and
  writable for an RPDO (0x06040041);
* the count may not make the PDO longer than 64 bits (0x06040042), nor name an empty entry;
* the transmission type may not be a reserved one (241-251): 0x06090030.

Each rule raises canopen's :class:`SdoAbortedError`, which its SDO server sends as the abort.
"""
from __future__ import annotations

from canopen import objectdictionary as od_module
from canopen.sdo import SdoAbortedError

from devices.device import find_variable

PDO_INVALID = 1 << 31
_COM = {0x1400: "rpdo", 0x1800: "tpdo"}
_MAP = {0x1600: "rpdo", 0x1A00: "tpdo"}
MAX_PDO_BITS = 64


def _kind(index: int, table: dict[int, str]) -> str | None:
    for base, kind in table.items():
        if base <= index < base + 0x200:
            return kind
    return None


def check_pdo_write(node, index: int, sub: int, value: int) -> None:
    """Refuse a write to a PDO parameter that CiA 301 does not allow (see the module doc);
    ``node`` an :class:`~plant_emulator.node.EmulatedNode` (its current values)."""
    com = _kind(index, _COM)
    if com is not None:
        if sub == 1:
            current = int(node.value(index, 1))
            if not current & PDO_INVALID and not value & PDO_INVALID \
                    and (current & 0x1FFFFFFF) != (value & 0x1FFFFFFF):
                raise SdoAbortedError(0x06090030)     # the id of a valid PDO cannot change
        elif sub == 2 and 241 <= value <= 251:
            raise SdoAbortedError(0x06090030)         # reserved transmission types
        return
    kind = _kind(index, _MAP)
    if kind is None:
        return
    od = node.local.object_dictionary
    if sub == 0:
        bits = 0
        for i in range(1, value + 1):
            entry = int(node.value(index, i))
            if entry & 0xFF == 0:
                raise SdoAbortedError(0x06040041)     # an empty entry counted in
            bits += entry & 0xFF
        if bits > MAX_PDO_BITS:
            raise SdoAbortedError(0x06040042)
        return
    if int(node.value(index, 0)) != 0:
        raise SdoAbortedError(0x08000022)             # entries change only with the count at 0
    target, target_sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
    if value == 0:
        return
    if target not in od:
        raise SdoAbortedError(0x06020000)
    var = find_variable(od, (target, target_sub))
    if var is None:
        raise SdoAbortedError(0x06090011)
    if not var.pdo_mappable or len(var) != bits or var.data_type not in od_module.NUMBER_TYPES \
            and var.data_type != od_module.BOOLEAN:
        raise SdoAbortedError(0x06040041)
    if (kind == "tpdo" and not var.readable) or (kind == "rpdo" and not var.writable):
        raise SdoAbortedError(0x06040041)
