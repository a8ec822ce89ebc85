"""CAN bus budget: bits and frames per second the control loop needs at the default period,
against the physical limit of a 1 Mbit/s classic CAN bus (worst-case bit stuffing), for this
stand and for a rig of 24 loading channels. Frame sizes come from dbc/stand.dbc."""
from __future__ import annotations

import cantools

from dbc import STAND_DBC

from .table import Row

ORDER = 60
BITRATE = 1_000_000
PERIOD_S = 0.002
HEARTBEAT_S = 0.1


def frame_bits(data_bytes: int) -> int:
    """Classic CAN, 11-bit id, worst-case stuffing: 55 + 10·n bits (135 for 8 bytes)."""
    return 55 + 10 * data_bytes


def budget(channels: int, period_s: float = PERIOD_S) -> dict:
    db = cantools.database.load_file(str(STAND_DBC))
    size = {m.name: m.length for m in db.messages}
    per_channel = [size["TPDO1_Valve"], size["TPDO1_Dynamometer"], size["RPDO1_Valve"]]
    cycle_bits = frame_bits(size["SYNC"]) + channels * sum(frame_bits(n) for n in per_channel)
    cycle_frames = 1 + channels * len(per_channel)
    hb_bits = 2 * channels * frame_bits(size["Heartbeat_Valve"]) / HEARTBEAT_S
    bits_s = cycle_bits / period_s + hb_bits
    frames_s = cycle_frames / period_s + 2 * channels / HEARTBEAT_S
    max_frames_8 = BITRATE / frame_bits(8)
    return {"bits_s": bits_s, "frames_s": frames_s, "load": bits_s / BITRATE,
            "max_frames_8": max_frames_8, "min_period_s": (cycle_bits / (BITRATE - hb_bits))}


def run(quick: bool) -> list[Row]:
    rows = []
    for channels in (1, 24):
        b = budget(channels)
        fits = b["load"] <= 1.0
        rows.append(Row(
            f"CAN budget, {channels} channel{'s' if channels > 1 else ''} at 2 ms",
            f"{b['frames_s']:,.0f} frames/s, {b['bits_s'] / 1e3:,.0f} kbit/s = {100 * b['load']:.0f} % bus load",
            f"1 Mbit/s: {b['max_frames_8']:,.0f} 8-byte frames/s worst case", f"{b['load']:.2f}",
            "fits" if fits else f"does not fit one bus: period >= {b['min_period_s'] * 1e3:.1f} ms, "
                                f"or {int(-(-b['load'] // 1))} buses, or CAN FD"))
    return rows
