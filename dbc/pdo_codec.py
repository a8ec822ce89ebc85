"""Compile a PDO mapping (as canopen reads it) into one ``struct`` for the per-cycle hot path.

canopen's ``PdoMap`` is the source of truth for which objects a PDO carries (read from the
device over SDO or from the EDS); encoding every cycle through its ``Variable`` objects costs tens
of microseconds, so the control loop and the emulator use this precompiled codec instead.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

from canopen import objectdictionary as od

_CODES = {
    od.BOOLEAN: "?", od.INTEGER8: "b", od.UNSIGNED8: "B", od.INTEGER16: "h",
    od.UNSIGNED16: "H", od.INTEGER32: "i", od.UNSIGNED32: "I", od.REAL32: "f",
    od.INTEGER64: "q", od.UNSIGNED64: "Q", od.REAL64: "d",
}


class PdoLayoutError(ValueError):
    """The mapping cannot be handled by a byte-aligned struct codec."""


@dataclass(frozen=True)
class PdoLayout:
    """Byte-aligned little-endian layout of one PDO: ``keys[i]`` is ``(index, subindex)``."""

    cob_id: int
    keys: tuple[tuple[int, int], ...]
    codec: struct.Struct

    @classmethod
    def from_entries(cls, cob_id: int, entries: list[tuple[int, int, int, int]]) -> "PdoLayout":
        """``entries``: ``(index, subindex, bit_length, data_type)`` in mapping order."""
        fmt = "<"
        keys = []
        for index, sub, bits, dtype in entries:
            code = _CODES.get(dtype)
            if code is None or struct.calcsize("<" + code) * 8 != bits:
                raise PdoLayoutError(
                    f"0x{index:04X}:{sub:02X} ({bits} bits, type {dtype}) is not a byte-aligned "
                    "number this codec supports")
            fmt += code
            keys.append((index, sub))
        return cls(cob_id, tuple(keys), struct.Struct(fmt))

    @classmethod
    def from_map(cls, pdo_map) -> "PdoLayout":
        """From a canopen ``PdoMap`` after ``read()``/``save()``."""
        entries = [(v.index, v.subindex, v.length, v.od.data_type) for v in pdo_map.map if v.length]
        return cls.from_entries(pdo_map.cob_id, entries)

    @property
    def size(self) -> int:
        return self.codec.size

    def position(self, index: int, subindex: int = 0) -> int:
        try:
            return self.keys.index((index, subindex))
        except ValueError:
            raise KeyError(f"0x{index:04X}:{subindex:02X} is not mapped in PDO 0x{self.cob_id:X}") from None

    def decode(self, data: bytes | bytearray) -> tuple:
        """Unpack a received PDO; raises ``struct.error`` if the length is wrong."""
        return self.codec.unpack(bytes(data))

    def encode(self, *values) -> bytes:
        return self.codec.pack(*values)
