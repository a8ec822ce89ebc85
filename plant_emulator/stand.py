"""The emulated stand: both CANopen nodes wired to one plant model, on any python-can bus.

The one-channel case of :class:`plant_emulator.emulated_rig.EmulatedRig` (one bus, one
channel, the plant uncoupled: :class:`plant.rig.RigModel` of one channel runs the plant model
bit for bit). Time:

* **lockstep** — the plant advances exactly one communication cycle period (0x1006, written by
  the master) per SYNC, in sub-steps of at most ``step_s``; the command received after SYNC k
  acts over [t_k, t_k+1]. A run is as fast as the bus and reproducible bit for bit with a seed.
  The periods within the transport delay are computed ahead in one block
  (:mod:`plant_emulator.lockstep_plant`).
* **real time** — the plant integrates on the wall clock in steps of ``step_s``; a command acts
  from the moment it is received; each SYNC samples the force at that instant.

Every SYNC: advance the plant, sample the dynamometer, refresh the valve's outputs, send the
synchronous TPDOs of both nodes (only while OPERATIONAL).

The valve's RPDO timeout counts the stand's time: the wall clock in real time (a thread polls
it), in lockstep the stand's own time, one period per SYNC (checked at each SYNC). In lockstep
nothing moves between SYNCs, so a host that stalls the gateway or the emulator for longer than
the timeout is no fault; a master that goes on sending SYNCs without commands is.

A different force source overrides :meth:`EmulatedStand.advance_plant`,
:meth:`EmulatedStand.measure_force` and :meth:`EmulatedStand.run_started` (e.g. a replayed
capture, :mod:`plant_emulator.replayed`).
"""
from __future__ import annotations

import can

from core.errors import ParameterError
from plant.config import PlantConfig
from plant.rig import RigModel

from .channel import ChannelSetup, EmulatedChannel
from .emulated_rig import EmulatedRig, EmulatorOptions

__all__ = ["EmulatedStand", "EmulatorOptions"]

#: the one bus's name inside the emulator
BUS_NAME = "stand"


class EmulatedStand(EmulatedRig):
    """The valve and the dynamometer on ``bus`` with ``config``'s plant behind them."""

    def __init__(self, bus: can.BusABC, config: PlantConfig, options: EmulatorOptions) -> None:
        config.validate()
        if options.valve_id == options.dynamometer_id:
            raise ValueError("the valve and the dynamometer need different node ids")
        if set(options.unconfigured) - {BUS_NAME}:
            raise ParameterError(f"unconfigured: a stand's one channel is {BUS_NAME!r}")
        setup = ChannelSetup(BUS_NAME, BUS_NAME, options.valve_id, options.dynamometer_id,
                             config.dynamometer(options.seed), config.initial_force_kgf,
                             options.devices, BUS_NAME in options.unconfigured)
        super().__init__({BUS_NAME: bus}, [setup], RigModel([config.model]), options)
        self.bus = bus
        self.config = config
        self.model = config.model
        self.channel = self.channels[0]
        self.network = self.buses[0].network
        #: frames dropped before the stack (wrong DLC on NMT/SYNC/SDO, error/remote/ext/FD frames)
        self.frame_filter = self.buses[0].frame_filter
        self.valve = self.channel.valve
        self.dynamometer = self.channel.dynamometer
        self.sensor = self.channel.sensor

    @property
    def force_kgf(self) -> float:
        return self.force_of(0)

    @property
    def _syncs(self) -> int:
        """Lockstep: the SYNCs answered (one cycle each on one bus)."""
        return self.cycles

    # -- the one-channel hooks -------------------------------------------------------------------
    def channel_started(self, channel: EmulatedChannel) -> None:
        self.run_started()

    def run_started(self) -> None:
        """Hook: the master started the nodes (NMT OPERATIONAL), i.e. a run begins. The plant
        goes on (force, spool, delay line) but its clock restarts, as the run's record does: an
        effect of the time since a run began (``gain_drift``, ``null_drift``) counts from here. A different
        force source (a replayed capture) restarts its replay here."""
        super().channel_started(self.channel)

    def measure(self, channel: EmulatedChannel) -> tuple[float, bool]:
        return self.measure_force()

    def measure_force(self) -> tuple[float, bool]:
        """The dynamometer's reading (kgf) at this SYNC and whether it is over range."""
        return super().measure(self.channel)
