"""How long a CAN frame occupies the bus, worst case, and how loaded a bus is by frames sent
every cycle (ISO 11898-1:2015; 11-bit identifiers).

Classic CAN, a data frame with ``n`` data bytes: 47 + 8n bits, the 3-bit interframe space
included; bit stuffing covers SOF to the end of the CRC (34 + 8n bits) and adds at most
⌊(34 + 8n − 1)/4⌋ bits. A SYNC with its counter (n = 1) takes 65 bits, an 8-byte frame 135
(../shared/notes/rig.md).

CAN FD (FDF set; with ``data_bitrate`` the BRS bit set: the data phase runs at that rate):

* nominal rate: SOF, identifier, RRS, IDE, FDF, res, BRS (17 bits), the CRC delimiter, ACK
  slot and delimiter, EOF and interframe space (13 bits), and the stuff bits of the arbitration
  part (at most ⌊16/4⌋ = 4);
* data rate: ESI, DLC (5 bits), the data (8n, n up to 64 in the DLC's steps), the stuff count
  (4 bits), the CRC (17 bits up to 16 data bytes, 21 above), the fixed stuff bits of the count
  and the CRC (one per 4 bits: ⌈(4 + CRC)/4⌉), and the dynamic stuff bits of the data phase
  (at most ⌊(5 + 8n)/4⌋).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable

#: the payload lengths a CAN FD DLC can say (a frame is padded to the next one)
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


def classic_frame_bits(n: int) -> int:
    """Worst-case bits of a classic CAN data frame with ``n`` (0..8) data bytes, 11-bit id,
    interframe space included."""
    if not 0 <= n <= 8:
        raise ValueError(f"a classic CAN frame carries 0 to 8 data bytes, not {n}")
    return 47 + 8 * n + (34 + 8 * n - 1) // 4


def fd_padded(n: int) -> int:
    """The payload a CAN FD frame carrying ``n`` bytes sends (the next DLC step)."""
    for length in FD_LENGTHS:
        if length >= n:
            return length
    raise ValueError(f"a CAN FD frame carries at most 64 data bytes, not {n}")


def fd_frame_time_s(n: int, bitrate: int, data_bitrate: int | None = None) -> float:
    """Worst-case time (s) of a CAN FD data frame with ``n`` data bytes, 11-bit id, at the
    nominal ``bitrate`` and, with BRS, the data phase at ``data_bitrate`` (None: no switch)."""
    n = fd_padded(n)
    crc = 17 if n <= 16 else 21
    nominal = 17 + 13 + 16 // 4
    data = 5 + 8 * n + 4 + crc + math.ceil((4 + crc) / 4) + (5 + 8 * n) // 4
    rate = data_bitrate or bitrate
    return nominal / bitrate + data / rate


def frame_time_s(n: int, bitrate: int, fd: bool = False, data_bitrate: int | None = None) -> float:
    """Worst-case time (s) a data frame with ``n`` bytes holds the bus."""
    if fd:
        return fd_frame_time_s(n, bitrate, data_bitrate)
    return classic_frame_bits(n) / bitrate


@dataclass(frozen=True)
class Traffic:
    """Frames on a bus: ``count`` frames of ``data_bytes`` every ``every_s`` seconds."""

    what: str
    data_bytes: int
    count: int
    every_s: float
    #: sent as classic frames even on a CAN FD bus (a CANopen stack's heartbeats, SDO, EMCY)
    classic: bool = False


@dataclass(frozen=True)
class BusLoad:
    """How much of a bus's time the traffic takes, worst case."""

    busy_s_per_s: float           #: seconds of bus time per second: the load as a fraction
    frames_per_s: float
    bitrate: int
    fd: bool

    @property
    def load_pct(self) -> float:
        return 100.0 * self.busy_s_per_s

    @property
    def bits_per_s(self) -> float:
        """The load as nominal bits per second (what a classic bus of ``bitrate`` carries)."""
        return self.busy_s_per_s * self.bitrate


def bus_load(traffic: Iterable[Traffic], bitrate: int, fd: bool = False,
             data_bitrate: int | None = None) -> BusLoad:
    """The worst-case load of ``traffic`` on a bus of ``bitrate`` (CAN FD with ``fd``)."""
    busy = frames = 0.0
    for t in traffic:
        busy += t.count * frame_time_s(t.data_bytes, bitrate, fd and not t.classic,
                                       data_bitrate) / t.every_s
        frames += t.count / t.every_s
    return BusLoad(busy, frames, bitrate, fd)
