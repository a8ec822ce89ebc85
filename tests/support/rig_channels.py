"""A rig of several channels for the end-to-end tests (no tests here): a rig file on private
loopback buses, and one emulator process per channel (the channels uncoupled, G diagonal),
each with its own node ids and initial force, until the coupled rig emulator is merged."""
from __future__ import annotations

import uuid
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np

from gateway.capture import read_capture
from rig.config import RigConfig, load_rig_file


@dataclass(frozen=True)
class Channel:
    name: str
    bus: str
    valve_id: int
    dynamometer_id: int
    initial_kgf: float = 0.0
    force_limit_kgf: float | None = None


#: 4 channels on 2 buses, two per bus (nodes 1/2 and 3/4 on each)
FOUR = (Channel("a", "can0", 1, 2), Channel("b", "can0", 3, 4),
        Channel("c", "can1", 1, 2), Channel("d", "can1", 3, 4))


def write_rig(path: Path, channels=FOUR, buses=("can0", "can1"), period_ms: float = 2.0,
              extra: str = "") -> RigConfig:
    """A rig file on private loopback channels (one per bus, unique to this call)."""
    tag = uuid.uuid4().hex[:8]
    text = [f'name = "test rig {tag}"', f"period_ms = {period_ms}", extra]
    for bus in buses:
        text += ["[[bus]]", f'name = "{bus}"', f'spec = "udp_loopback:rig-{bus}-{tag}"']
    for c in channels:
        text += ["[[channel]]", f'name = "{c.name}"', f'bus = "{c.bus}"',
                 f"valve_id = {c.valve_id}", f"dynamometer_id = {c.dynamometer_id}"]
        if c.force_limit_kgf is not None:
            text.append(f"force_limit_kgf = {c.force_limit_kgf}")
    path.write_text("\n".join(text) + "\n")
    return load_rig_file(path)


def start_channels(start_emulator, rig: RigConfig, channels=FOUR, seed: int = 1,
                   model: str = "base") -> dict:
    """One lockstep emulator per channel on its bus, with the channel's node ids and initial
    force. The emulators do not busy-poll (``busy_poll_us=0``): five processes polling on two
    cores take each other's time."""
    from concurrent.futures import ThreadPoolExecutor

    def start(k: int):
        c = channels[k]
        spec = rig.bus(c.bus).spec + ",busy_poll_us=0"
        return start_emulator(
            None, lockstep=True, seed=seed + k, bus=spec,
            extra_args=["--valve-id", str(c.valve_id), "--dynamometer-id", str(c.dynamometer_id),
                        "--model", model, "--set", f"initial.force_kgf={c.initial_kgf}"])

    with ThreadPoolExecutor(2) as pool:     # two at a time: each start is mostly imports
        procs = list(pool.map(start, range(len(channels))))
    return {c.name: p for c, p in zip(channels, procs)}


def syncs(capture: Path) -> tuple[np.ndarray, np.ndarray]:
    """Send stamps (s) and counters of the SYNCs in a capture."""
    frames = [(m.timestamp, m.data[0] if m.data else 0) for m in read_capture(capture)
              if m.arbitration_id == 0x80 and not m.is_error_frame]
    return np.array([f[0] for f in frames]), np.array([f[1] for f in frames])


def rpdo_words(capture: Path, valve_id: int) -> list[tuple[float, int, int]]:
    """(stamp, control word, setpoint counts) of every RPDO to a valve in a capture."""
    out = []
    for m in read_capture(capture):
        if m.arbitration_id == 0x200 + valve_id and len(m.data) >= 4:
            cw = int.from_bytes(m.data[0:2], "little")
            sp = int.from_bytes(m.data[2:4], "little", signed=True)
            out.append((m.timestamp, cw, sp))
    return out


def node_ids(capture: Path) -> set[int]:
    """The node ids (low 7 bits) of every TPDO in a capture."""
    return {m.arbitration_id & 0x7F for m in read_capture(capture)
            if 0x180 <= m.arbitration_id < 0x200}


def ratio_deviation(y: np.ndarray, y0: np.ndarray) -> np.ndarray:
    """Per cycle and channel, ``y_i − σ·y0_i`` with ``σ`` the least-squares common scale
    (rows: cycles, columns: channels): computed here apart from the gateway's own measure."""
    sigma = (y @ y0) / (y0 @ y0)
    return y - sigma[:, None] * y0[None, :]


def sniff(spec: str) -> can.BusABC:
    """A raw listener on a bus (for frames that must not be sent)."""
    from standbus import open_bus
    return open_bus(spec)
