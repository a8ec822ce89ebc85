"""The bus budget of a rig: what each bus carries per control cycle, worst case, against what it
may (the rig's ``bus_load_limit``, 70 % by default), and what would fit when it does not.

Per cycle on every bus: one SYNC (with its counter); per channel on it: the valve's command
(RPDO), the valve's status (TPDO) and the force (TPDO); per heartbeat period: one heartbeat of
each node, or for a node guarded instead the master's remote frame and the node's answer. On a
CAN FD bus the cyclic frames are FD frames (the gateway and the emulator send them so) and the
heartbeats classic frames (the nodes' CANopen stack sends them so). Frame lengths come from the
PDOs the gateway sets up on each channel's devices (:func:`devices.plan.plan_node`; the largest
of a bus's channels), times from :mod:`standbus.budget` (worst-case bit stuffing; CAN FD
counted as CAN FD).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

from devices import DeviceSet, default_devices
from devices.plan import channel_pdo_bytes, plan_node
from standbus.budget import BusLoad, Traffic, bus_load

from .config import BusConfig, RigConfig

SYNC_BYTES = 1          #: the SYNC with its counter
HEARTBEAT_BYTES = 1


@dataclass(frozen=True)
class ChannelFrames:
    """What one channel puts on its bus: its cyclic PDOs' data bytes, and its error-control
    frames per heartbeat period (a heartbeat per node; two for a guarded one)."""

    pdo_bytes: tuple[tuple[str, int], ...]
    error_control_frames: int = 2

    @classmethod
    def of(cls, devices: DeviceSet) -> "ChannelFrames":
        plans = [plan_node(d, nid, period_s=0.002, heartbeat_ms=100)
                 for d, nid in ((devices.valve, 1), (devices.dynamometer, 2))]
        frames = sum(2 if d.error_control == "guarding" else 1 for d in (devices.valve, devices.dynamometer))
        return cls(tuple(channel_pdo_bytes(plans).items()), frames)

    def larger(self, other: "ChannelFrames") -> "ChannelFrames":
        """Each figure the larger of the two (the worst channel of a bus)."""
        mine, theirs = dict(self.pdo_bytes), dict(other.pdo_bytes)
        return ChannelFrames(tuple((k, max(v, theirs.get(k, 0))) for k, v in mine.items()),
                             max(self.error_control_frames, other.error_control_frames))


@functools.lru_cache(maxsize=1)
def default_frames() -> ChannelFrames:
    return ChannelFrames.of(default_devices())


def cycle_traffic(channels: int, period_s: float, heartbeat_s: float,
                  frames: ChannelFrames | None = None) -> list[Traffic]:
    """The frames of ``channels`` loading channels on one bus, each as ``frames`` (default:
    the emulated devices')."""
    frames = frames or default_frames()
    out = [Traffic("SYNC", SYNC_BYTES, 1, period_s)]
    out += [Traffic(what, n, channels, period_s) for what, n in frames.pdo_bytes]
    out.append(Traffic("heartbeats", HEARTBEAT_BYTES, frames.error_control_frames * channels,
                       heartbeat_s, classic=True))
    return out


def load_of(bus: BusConfig, channels: int, period_s: float, heartbeat_s: float,
            frames: ChannelFrames | None = None) -> BusLoad:
    return bus_load(cycle_traffic(channels, period_s, heartbeat_s, frames), bus.bitrate, bus.fd,
                    bus.data_bitrate)


@dataclass(frozen=True)
class BusBudget:
    """One bus of a rig: its load and whether it is within the limit."""

    bus: BusConfig
    channels: list[str]
    load: BusLoad
    limit: float                  #: the load allowed, fraction
    period_s: float
    max_channels: int             #: at this period, within the limit
    min_period_s: float           #: for these channels, within the limit

    @property
    def fits(self) -> bool:
        return self.load.busy_s_per_s <= self.limit

    def problem(self) -> str | None:
        """What is wrong and what would fit (None: it fits)."""
        if self.fits:
            return None
        hz = 1.0 / self.period_s
        kind = "CAN FD" if self.bus.fd else "classic CAN"
        return (f"bus {self.bus.name}: {len(self.channels)} channel(s) at {hz:g} Hz need "
                f"{_rate(self.load.bits_per_s)} of {_rate(self.bus.bitrate)} ({kind}, "
                f"{self.load.load_pct:.0f} %, the limit is {100 * self.limit:.0f} %); at most "
                f"{self.max_channels} channel(s) per bus at {hz:g} Hz, or a period of "
                f"{_ceil_ms(self.min_period_s)} ms")

    def to_dict(self) -> dict:
        return {"name": self.bus.name, "spec": self.bus.spec, "load_pct": self.load.load_pct,
                "bitrate": self.bus.bitrate, "fd": self.bus.fd,
                "data_bitrate": self.bus.data_bitrate, "channels": list(self.channels),
                "frames_per_s": self.load.frames_per_s, "limit_pct": 100 * self.limit,
                "max_channels": self.max_channels, "min_period_ms": 1e3 * self.min_period_s}


def bus_budgets(rig: RigConfig) -> list[BusBudget]:
    """Every bus of the rig at its period."""
    hb = rig.heartbeat_ms / 1e3
    out = []
    of_set: dict[int, ChannelFrames] = {}
    for bus in rig.buses:
        on_bus = rig.channels_on(bus.name)
        names = [c.name for c in on_bus]
        frames = None
        for c in on_bus:                       # the bus's worst channel, each device set once
            mine = of_set.get(id(c.devices)) or of_set.setdefault(id(c.devices), ChannelFrames.of(c.devices))
            frames = mine if frames is None else frames.larger(mine)
        frames = frames or default_frames()
        load = load_of(bus, len(names), rig.period_s, hb, frames)
        out.append(BusBudget(bus, names, load, rig.bus_load_limit, rig.period_s,
                             _max_channels(bus, rig.period_s, hb, rig.bus_load_limit, frames),
                             _min_period(bus, len(names), hb, rig.bus_load_limit, frames)))
    return out


def _max_channels(bus: BusConfig, period_s: float, hb: float, limit: float,
                  frames: ChannelFrames) -> int:
    n = 0
    while n < 1000 and load_of(bus, n + 1, period_s, hb, frames).busy_s_per_s <= limit:
        n += 1
    return n


def _min_period(bus: BusConfig, channels: int, hb: float, limit: float,
                frames: ChannelFrames) -> float:
    """The shortest period (s) at which ``channels`` fit: the per-cycle frames' time over what
    the limit leaves after the heartbeats."""
    per_cycle = load_of(bus, channels, 1.0, math.inf, frames).busy_s_per_s      # s of bus per cycle
    heartbeats = load_of(bus, channels, math.inf, hb, frames).busy_s_per_s      # s of bus per s
    room = limit - heartbeats
    return per_cycle / room if room > 0 else math.inf


def _rate(bits_s: float) -> str:
    return f"{bits_s / 1e6:.2f} Mbit/s" if bits_s >= 1e5 else f"{bits_s / 1e3:.0f} kbit/s"


def _ceil_ms(s: float) -> str:
    if not math.isfinite(s):
        return "none (the heartbeats alone exceed the limit)"
    return f"{math.ceil(s * 1e4) / 10:g}"
