"""The emulator's CANopen side, as a network holds nodes: each bus with its acceptance filter
and the channels on it, each channel a valve node (CiA 408) and a dynamometer node (CiA 404).

The plant behind them and the time (lockstep or real time) are :mod:`plant_emulator.emulated_rig`'s.
"""
from __future__ import annotations

import time
import zlib
from dataclasses import dataclass
from typing import Callable, Sequence

import can
import canopen

from dbc import profile as P
from devices import DeviceSet, default_devices
from plant.sensor import Dynamometer
from standbus import wire

from .dynamometer import DynamometerNode
from .heartbeats import PeriodicFrames
from .lss import LSS_MASTER
from .node import slave_frame_filter
from .valve import ServoValveNode


@dataclass(frozen=True)
class ChannelSetup:
    """What the emulator needs of one channel besides its plant model."""

    name: str
    bus: str                       #: the name of the channel's bus
    valve_id: int
    dynamometer_id: int
    sensor: Dynamometer            #: the dynamometer's noise, resolution and range
    initial_force_kgf: float = 0.0
    #: which devices the two nodes are (their EDS and roles; default: the emulated pair)
    devices: DeviceSet | None = None
    #: both nodes start without a node id, answering LSS only, until LSS gives them one
    unconfigured: bool = False


def _serial(setup: ChannelSetup, role: str) -> int:
    """A serial number of its own for each node started without a node id: its LSS address
    (vendor, product, revision, serial) must be unique on the bus."""
    return zlib.crc32(f"{setup.bus}/{setup.name}/{role}".encode())


class _Network(canopen.Network):
    """A canopen network whose periodic frames (the nodes' heartbeats) go out from the
    emulator's one thread (:mod:`plant_emulator.heartbeats`), not a thread each."""

    def __init__(self, bus: can.BusABC, periodic: PeriodicFrames, send: Callable[[list], None]) -> None:
        super().__init__(bus)
        self._periodic, self._send = periodic, send

    def send_periodic(self, can_id: int, data, period: float, remote: bool = False):
        if remote:
            return super().send_periodic(can_id, data, period, remote)
        return self._periodic.task(self._send, can_id, data, period)


class EmulatedBus:
    """One CAN bus: its canopen network behind an acceptance filter for the nodes on it, the
    channels on it, and (lockstep) its SYNCs not yet matched by every other bus's.
    ``periodic``: where the nodes' heartbeats are sent from (the emulator's one thread)."""

    def __init__(self, name: str, bus: can.BusABC, node_ids: Sequence[int],
                 cyclic_flags: int, periodic: PeriodicFrames) -> None:
        self.name = name
        self.bus = bus
        self.network = _Network(bus, periodic, self.send_frames)
        #: the wire flags of the synchronous TPDOs: classic, or on a CAN FD bus FD frames
        self.cyclic_flags = cyclic_flags
        #: frames dropped before the stack (wrong DLC on NMT/SYNC/SDO, error/remote/ext frames,
        #: and FD frames on a classic bus)
        self.frame_filter = slave_frame_filter(self.network, tuple(node_ids),
                                               fd=bool(cyclic_flags & wire.FLAG_FD))
        self.channels: list[EmulatedChannel] = []
        #: lockstep: SYNCs received on this bus whose cycle has not completed yet
        self.pending_syncs = 0
        #: the counter of the last SYNC (None: SYNC without counter)
        self.counter: int | None = None

    def register(self, node) -> None:
        """Let ``node``'s frames through the filter: its SDO requests, its guard requests
        (remote frames), LSS while it has no node id."""
        if node.configured:
            self.frame_filter.expect(P.SDO_RX_BASE + node.id, 8)
            if node.guarding is not None:
                self.frame_filter.accept_remote(P.HEARTBEAT_BASE + node.id, node.guarding.on_request)
        if node.lss is not None:
            self.frame_filter.expect(LSS_MASTER, 8)

    def send_frames(self, frames: list) -> None:
        """Raw frames (:mod:`standbus.wire`) sent at one instant (the answers to a SYNC): one
        datagram where the bus takes a batch, else one ``send`` each."""
        if not frames:
            return
        bus = self.bus
        with self.network.send_lock:
            if getattr(bus, "raw_frames", False):
                bus.send_frames(frames)
            else:
                stamp = time.time()
                for frame in frames:
                    bus.send(wire.message(stamp, frame, None, False))


class EmulatedChannel:
    """One loading channel on its bus: the two nodes, the dynamometer's sensor and the spool
    command the valve applies now (what the plant sees)."""

    def __init__(self, index: int, setup: ChannelSetup, on_bus: EmulatedBus, lockstep: bool) -> None:
        self.index = index                   #: the channel's row in the plant's G
        self.name = setup.name
        self.on_bus = on_bus
        self.sensor = setup.sensor
        devices = setup.devices or default_devices()
        serials = ((_serial(setup, "valve"), _serial(setup, "dynamometer")) if setup.unconfigured
                   else (None, None))
        self.valve = ServoValveNode(on_bus.network, setup.valve_id, devices.valve, lockstep, serials[0])
        self.dynamometer = DynamometerNode(on_bus.network, setup.dynamometer_id, devices.dynamometer,
                                           serials[1])
        for node in self.nodes:
            node.cyclic_flags = on_bus.cyclic_flags
            on_bus.register(node)
            node.id_changed = on_bus.register
        #: the spool command the valve applies, % (updated after every change of the valve)
        self.command = 0.0
        on_bus.channels.append(self)

    @property
    def nodes(self) -> tuple[ServoValveNode, DynamometerNode]:
        return self.valve, self.dynamometer

    def answer_sync(self, reading_kgf: float, over_range: bool, counter: int | None,
                    sync_stamp: float | None = None, out: list | None = None) -> None:
        """Publish the force reading and the valve's outputs, then send both nodes' synchronous
        TPDOs due at this SYNC (only while OPERATIONAL; in real time, with the SYNC's wall-clock
        ``sync_stamp``, only within its synchronous window: :meth:`EmulatedNode.on_sync`); with
        ``out``, append them there as raw frames (the bus's answers go out together)."""
        self.dynamometer.publish(reading_kgf, over_range)
        self.valve.update_outputs(self.command)
        self.valve.on_sync(counter, sync_stamp, out)
        self.dynamometer.on_sync(counter, sync_stamp, out)
