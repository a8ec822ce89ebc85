r"""The emulated rig: every bus of a rig, every channel's valve and dynamometer on its bus, and
the coupled plant behind them (:class:`plant.rig.RigModel`,
:math:`\dot y = G\,w(t-\tau) + \Delta`). The one-channel stand
(:class:`plant_emulator.stand.EmulatedStand`) is the case of one bus and one channel.

Time:

* **lockstep** — the plant advances exactly one communication cycle period (0x1006, written by
  the master, read from the first channel's valve) when the SYNC of that cycle has arrived on
  *every* bus with a channel on it (the master sends one SYNC per bus per cycle, back to
  back); then every bus's synchronous TPDOs go out. SYNCs are counted per bus: a bus whose SYNC came early waits for the
  others (its surplus counts towards the next cycle), and a master that stops sending SYNC on
  one bus stops the whole rig, as lockstep stops a stand. The command received after cycle k's
  SYNC acts over [t_k, t_k+1]; a channel's command travels on its own bus before that bus's next
  SYNC, so every command of a cycle is in before the cycle's last SYNC. The periods within the
  shortest transport delay are computed ahead in one block
  (:class:`plant_emulator.lockstep_plant.LockstepRig`). A run is as fast as the buses and
  reproducible bit for bit with a seed.
* **real time** — the plant integrates on the wall clock in steps of ``step_s``; a command acts
  from the step it is received in (the plant is brought up to that moment with the command
  before); the steps within the shortest transport delay are computed ahead in blocks as in
  lockstep (:class:`~plant_emulator.lockstep_plant.LockstepRig` with one step a period: the
  coupled plant of 8 channels cost 0.75 ms per advance call, made at every SYNC and every
  command), the next block at a quiet moment between a cycle's commands and its next SYNC,
  before the blocks ahead run out (:meth:`EmulatedRig._when_quiet`); each SYNC on a bus
  samples the forces of that bus's channels at that instant and sends that bus's TPDOs.

Each valve keeps its own RPDO watchdog (event timer 0x1400:05), counted on the stand's time:
the wall clock in real time (one thread polls every valve), in lockstep the stand's own time,
one period per cycle (checked at each cycle). A channel whose commands stop goes to its own
safe state (FAULT_HOLD, EMCY 0x8250) while the others go on; a master that dies leaves every
valve safe.
"""
from __future__ import annotations

import functools
import logging
import math
import select
import threading
import time
from dataclasses import dataclass
from typing import Mapping, Sequence

import can
import numpy as np

from core.errors import ParameterError
from dbc import profile as P
from devices import DeviceSet
from plant.rig import RigModel
from plant.sensor import SensorBank
from rig.config import RigConfig, RigError
from rig.emulated import channel_seed, emulated_plant
from standbus import LOCKSTEP_BUSY_POLL_S, HandoverNotifier, prefer_busy_poll, wire
from standbus.handover import handover_many

from .channel import ChannelSetup, EmulatedBus, EmulatedChannel
from .heartbeats import PeriodicFrames
from .lockstep_plant import LockstepRig
from .scheduled_faults import FaultSchedule, ScheduledFault

log = logging.getLogger(__name__)

#: a watchdog poll this much later than asked means the process was not running, s
_STALL_S = 0.02
#: how long the watchdog waits for frames already in the socket before declaring a timeout, s
_MAX_DEFERRAL_S = 0.02
#: real time: the buses this long without a frame are quiet (a cycle's frames are in), s
_QUIET_S = 0.0002
#: real time: the plant's next block is computed at a quiet moment once fewer than this many
#: cycles are computed ahead (the next quiet moment is a cycle away)
_PREFETCH_CYCLES = 3
#: the cycle period assumed for that before the master has written one (0x1006), s
_PREFETCH_UNKNOWN_PERIOD_S = 0.01


@dataclass
class EmulatorOptions:
    """How the emulator runs: lockstep or real time, the noise seed, the one-channel stand's
    node ids, the plant's integration step ``step_s`` (s), the real-time watchdog's poll
    ``watchdog_poll_s`` (s) and the faults it makes at scheduled stand times
    (:mod:`plant_emulator.scheduled_faults`)."""

    lockstep: bool = False
    seed: int | None = None
    #: the one-channel stand's node ids (a rig's come from its file)
    valve_id: int = P.VALVE_NODE_ID
    dynamometer_id: int = P.DYNAMOMETER_NODE_ID
    step_s: float = 0.0005
    watchdog_poll_s: float = 0.005
    faults: tuple[ScheduledFault, ...] = ()
    #: the one-channel stand's devices (a rig's come from its file; None: the emulated pair)
    devices: "DeviceSet | None" = None
    #: the channels whose nodes start without a node id (LSS only: :mod:`plant_emulator.lss`)
    unconfigured: tuple[str, ...] = ()


def fd_flags(rig: RigConfig) -> dict[str, int]:
    """The wire flags of each bus's cyclic frames: CAN FD buses send FD frames, with the
    bit-rate switch where the data phase is faster (docs/rig.md, "CAN FD")."""
    out = {}
    for b in rig.buses:
        if b.fd:
            brs = bool(b.data_bitrate) and b.data_bitrate != b.bitrate
            out[b.name] = wire.FLAG_FD | (wire.FLAG_BRS if brs else 0)
    return out


class EmulatedRig:
    """Owns the buses' networks, every channel's two nodes and the coupled plant. Call
    :meth:`start`, then :meth:`stop` (or use as a context manager).

    ``buses``: the opened python-can buses by name; ``channels``: in the order of ``model``'s
    rows, each on one of ``buses``."""

    def __init__(self, buses: Mapping[str, can.BusABC], channels: Sequence[ChannelSetup],
                 model: RigModel, options: EmulatorOptions,
                 cyclic_flags: Mapping[str, int] | None = None) -> None:
        channels = list(channels)
        if len(channels) != model.n:
            raise ValueError(f"{len(channels)} channel(s) for a plant of {model.n}")
        ids: dict[str, list[int]] = {name: [] for name in buses}
        for c in channels:
            if c.bus not in ids:
                raise ValueError(f"channel {c.name}: no bus {c.bus!r} (buses: {', '.join(buses)})")
            if c.valve_id == c.dynamometer_id:
                raise ValueError("the valve and the dynamometer need different node ids")
            ids[c.bus] += [c.valve_id, c.dynamometer_id]
        for name, on_bus in ids.items():
            if len(set(on_bus)) != len(on_bus):
                raise ValueError(f"bus {name}: node ids {on_bus} are not all different")
        self.options = options
        self.rig_model = model
        self.lock = threading.RLock()         # one lock for the whole rig
        flags = dict(cyclic_flags or {})
        #: every node's heartbeat, from one thread (:mod:`plant_emulator.heartbeats`)
        self.periodic = PeriodicFrames()
        self.buses = [EmulatedBus(name, bus, ids[name], flags.get(name, 0), self.periodic)
                      for name, bus in buses.items()]
        by_name = {b.name: b for b in self.buses}
        self.channels = [EmulatedChannel(i, c, by_name[c.bus], options.lockstep)
                         for i, c in enumerate(channels)]
        for ch in self.channels:
            for node in ch.nodes:
                node.lock = self.lock
            ch.valve.before_change = self._catch_up
            ch.valve.after_change = functools.partial(self._command_changed, ch)
            ch.dynamometer.started_listeners.append(functools.partial(self._started, ch))
        for b in self.buses:
            b.network.subscribe(P.SYNC_COB_ID, functools.partial(self._on_sync, b))
        #: lockstep: the buses whose SYNC a cycle waits for (a bus without channels has none)
        self._gated = [b for b in self.buses if b.channels]
        self._several_buses = len(self._gated) > 1
        #: the node whose communication cycle period (0x1006, written by the master) is the
        #: stand's period: the first that has the object
        self._period_node = next((n for ch in self.channels for n in ch.nodes
                                  if P.COMM_CYCLE_PERIOD in n.local.object_dictionary), None)
        if self._period_node is None and options.lockstep:
            raise ParameterError("lockstep needs the period the master writes to 0x1006, and no "
                             "emulated device has that object: run the emulator in real time")
        self._plant_dt = options.step_s
        y0 = [c.initial_force_kgf for c in channels]
        # compile (or load) the models' compiled loops now, not at the first SYNC of a run
        model.simulate(np.zeros((model.n, 8)), self._plant_dt, y0=y0)
        #: real time: the plant on the wall clock's step grid, computed ahead in blocks
        self.realtime_plant = LockstepRig(model, y0, options.step_s)
        #: lockstep: the plant one period per cycle, computed ahead in blocks
        self.lockstep_plant = LockstepRig(model, y0, options.step_s)
        self._t_plant = time.monotonic()
        #: lockstep: cycles completed (every bus's SYNC of the cycle arrived)
        self.cycles = 0
        #: lockstep: the stand's own time (s), one communication cycle period per cycle; the
        #: valves' RPDO timeouts count on it
        self.stand_time_s = 0.0
        if options.lockstep:
            for ch in self.channels:
                for node in ch.nodes:
                    node.clock = self._stand_time
        self.faults = FaultSchedule(options.faults)
        #: a scheduled spike per channel index, added to its next reading (kgf)
        self._spikes: dict[int, float] = {}
        #: lockstep: every channel's dynamometer read at once, each its own noise stream
        self._sensor_bank = SensorBank([ch.sensor for ch in self.channels])
        #: real time: the wall-clock stamp of the last SYNC, and what a prefetch of the plant
        #: took lately (s): :meth:`_when_quiet`
        self._last_sync_stamp = 0.0
        self._prefetch_s = 0.0
        self._stop = threading.Event()
        self._watchdog: threading.Thread | None = None
        self._reader: threading.Thread | None = None
        self.errors: list[str] = []

    @classmethod
    def from_rig(cls, buses: Mapping[str, can.BusABC], rig: RigConfig,
                 options: EmulatorOptions) -> "EmulatedRig":
        """The emulator of ``rig`` (its plants, ranges and node ids) on its opened ``buses``
        (by the rig's bus names); :class:`rig.config.RigError` when the rig cannot be emulated
        (a channel without a plant, a structure no stiffness gives). Each channel's
        dynamometer draws its own noise stream from ``options.seed``."""
        plant = emulated_plant(rig)
        unknown = set(options.unconfigured) - set(rig.names)
        if unknown:
            raise RigError(f"--unconfigured {', '.join(sorted(unknown))}: no such channel; the "
                           f"rig has {', '.join(rig.names)}")
        setups = [ChannelSetup(c.name, c.bus, c.valve_id, c.dynamometer_id,
                               p.dynamometer(channel_seed(options.seed, i)), p.initial_force_kgf,
                               c.devices, c.name in options.unconfigured)
                  for i, (c, p) in enumerate(zip(rig.channels, plant.plants))]
        return cls(buses, setups, plant.model, options, cyclic_flags=fd_flags(rig))

    def _stand_time(self) -> float:
        return self.stand_time_s

    # -- lifecycle -------------------------------------------------------------------------------
    def start(self) -> None:
        """Listen on every bus, then boot every node (boot-up messages, heartbeats).

        One bus: its reader thread (a python-can Notifier). Several: one thread reads them all
        (:func:`standbus.handover.handover_many`), so the frames of a cycle (every bus's SYNC,
        then the commands) are handled one after the other without a GIL hand-off between
        reader threads, each taking the rig's lock in turn: with a thread per bus, 8 channels
        on 2 buses fell behind the master's frames by seconds in real time."""
        spin = LOCKSTEP_BUSY_POLL_S if self.options.lockstep else 0.0
        if len(self.buses) == 1:
            b = self.buses[0]
            if spin:   # the next SYNC follows the answer within ~0.1 ms: poll
                prefer_busy_poll(b.bus, spin)
            b.network.notifier = HandoverNotifier(b.bus, b.network.listeners, 0.1)
        else:
            for b in self.buses:
                b.network.notifier = HandoverNotifier(b.bus, b.network.listeners, 0.005)
        for b in self.buses:      # the cyclic frames taken raw, before the canopen stack
            notifier = b.network.notifier
            notifier.fast_fd = bool(b.cyclic_flags & wire.FLAG_FD)
            notifier.fast[P.SYNC_COB_ID] = functools.partial(self._fast_sync, b)
            for ch in b.channels:
                for node in ch.nodes:
                    node.fast_rx = notifier.fast
        notifiers = [b.network.notifier for b in self.buses]
        self._reader = threading.Thread(target=self._read_buses, args=(notifiers, spin),
                                        name="emulator-buses", daemon=True)
        self._reader.start()
        self._t_plant = time.monotonic()
        for ch in self.channels:
            ch.valve.boot()
            ch.dynamometer.boot()
        guarded = [n for ch in self.channels for n in ch.nodes if n.guarding is not None]
        if not self.options.lockstep:     # lockstep: checked at each cycle, on the stand's time
            self._watchdog = threading.Thread(target=self._watch, name="emulator-watchdog", daemon=True)
            self._watchdog.start()
        elif guarded:                     # life guarding counts the wall clock, as its master
            self._watchdog = threading.Thread(target=self._watch_lives, args=(guarded,),
                                              name="emulator-life-guarding", daemon=True)
            self._watchdog.start()

    def _read_buses(self, notifiers: list[HandoverNotifier], spin_s: float) -> None:
        """Receive and handle every bus's frames; in real time, once the frames stop for
        :data:`_QUIET_S` (a cycle's commands are in, its next SYNC not yet), do the plant's
        work that can wait (:meth:`_when_quiet`)."""
        quiet = None if self.options.lockstep else self._when_quiet
        try:
            with handover_many(notifiers, spin_s) as pump:
                busy = False
                while not self._stop.is_set():
                    if pump(_QUIET_S if busy else 0.05) is not None:
                        busy = quiet is not None
                    elif busy:
                        busy = False
                        quiet()
        except Exception as exc:  # never silently: the rig would stop answering
            log.exception("reading the buses failed")
            self.errors.append(repr(exc))

    def stop(self) -> None:
        self._stop.set()
        if self._watchdog is not None:
            self._watchdog.join(1.0)
        if self._reader is not None:
            self._reader.join(1.0)
        for ch in self.channels:
            for node in ch.nodes:
                node.local.nmt.stop_heartbeat()
        self.periodic.close()
        for b in self.buses:
            if b.network.notifier is not None:
                b.network.notifier.stop(1.0)

    def __enter__(self) -> "EmulatedRig":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def force_of(self, index: int) -> float:
        """The true force of channel ``index`` now (kgf): at the end of the last cycle in
        lockstep, at the last catch-up in real time."""
        if self.options.lockstep:
            return self.lockstep_plant.forces[index]
        return float(self.realtime_plant.forces[index])

    # -- plant time ------------------------------------------------------------------------------
    def _commands(self) -> list[float]:
        return [ch.command for ch in self.channels]

    def _catch_up(self) -> None:
        """Real time: integrate up to now with the commands held so far."""
        if self.options.lockstep:
            return
        now = time.monotonic()
        steps = int((now - self._t_plant) / self._plant_dt)
        if steps > 0:
            self.realtime_plant.hold(steps, self._plant_dt, self._commands())
            self._t_plant += steps * self._plant_dt

    def _when_quiet(self) -> None:
        """Real time, between a cycle's frames and its next SYNC: compute the plant's next
        block now if the periods computed ahead would run out within :data:`_PREFETCH_CYCLES`
        cycles (:meth:`LockstepRig.prefetch`), so that no SYNC waits for one: computed at the
        SYNC that found none ahead, a 16-channel rig's block (0.5-1.7 ms) made that SYNC's
        answers miss its synchronous window, 1-2 % of the cycles stale."""
        with self.lock:
            self._catch_up()
            period = self._cycle_period()
            if not (period > 0 and math.isfinite(period)):
                period = _PREFETCH_UNKNOWN_PERIOD_S
            steps = math.ceil(_PREFETCH_CYCLES * period / self._plant_dt)
            if self.realtime_plant.periods_ahead >= steps:
                return
            # not where the next SYNC would come before it is done: at the next quiet moment
            # (what it takes is expected smaller each time it waits, so it does not wait for
            # ever after one that was preempted)
            if self._last_sync_stamp + period - time.time() < 1.5 * self._prefetch_s + _QUIET_S:
                self._prefetch_s *= 0.7
                return
            start = time.perf_counter()
            if self.realtime_plant.prefetch(self._commands(), steps):
                took = time.perf_counter() - start
                self._prefetch_s += 0.3 * (took - self._prefetch_s)

    def _cycle_period(self) -> float:
        """The communication cycle period 0x1006 the master wrote, s (NaN: no device has it)."""
        if self._period_node is None:
            return math.nan
        return int(self._period_node.value(P.COMM_CYCLE_PERIOD)) * 1e-6

    def _lockstep_cycle(self) -> None:
        """Lockstep: one communication cycle period per cycle (none before the first)."""
        self.cycles += 1
        if self.cycles == 1:
            return
        period = self._cycle_period()
        if not (period > 0 and math.isfinite(period)):
            return
        self.lockstep_plant.step(period, self._commands())

    # -- bus events ------------------------------------------------------------------------------
    def _fast_sync(self, on_bus: EmulatedBus, data: bytes, timestamp: float) -> bool:
        """A SYNC taken raw by the bus's notifier; one of a wrong length is left to the
        acceptance filter (dropped and counted there, as before)."""
        if len(data) > 1:
            return False
        self._on_sync(on_bus, P.SYNC_COB_ID, data, timestamp)
        return True

    def _on_sync(self, on_bus: EmulatedBus, can_id: int, data: bytes, timestamp: float) -> None:
        try:
            with self.lock:
                on_bus.counter = data[0] if len(data) >= 1 else None
                stamp = None              # lockstep: the stand's time, not the wall clock's
                if self.options.lockstep:
                    answering = self._complete_cycle(on_bus)
                    if not answering:
                        return
                    self.advance_plant()
                    self._lockstep_watchdog()
                else:
                    answering = (on_bus,)
                    stamp = self._last_sync_stamp = timestamp
                    self.advance_plant()
                self._make_faults()
                spikes = self._spikes
                readings, overs = self._readings(answering)
                for b in answering:          # a bus's answers in one batch
                    frames: list = []
                    counter = b.counter
                    for ch in b.channels:
                        i = ch.index
                        reading = readings[i]
                        if spikes:
                            reading += spikes.pop(i, 0.0)
                        ch.answer_sync(reading, overs[i], counter, stamp, frames)
                    b.send_frames(frames)
        except Exception as exc:  # never let the notifier swallow it silently
            log.exception("SYNC handling failed")
            self.errors.append(repr(exc))

    def _readings(self, answering: Sequence[EmulatedBus]) -> tuple[list, list]:
        """The dynamometers' readings (kgf) and over-range flags at this SYNC, by channel index,
        of the channels on the ``answering`` buses: in lockstep (every channel answers every
        cycle) all at once from the :class:`~plant.sensor.SensorBank`, in real time one bus's,
        each by :meth:`measure` (or its override: a replayed capture's forces)."""
        if self.options.lockstep and type(self).measure is EmulatedRig.measure:
            readings, overs = self._sensor_bank.read(self.lockstep_plant.forces)
            return readings.tolist(), overs.tolist()
        measure = self.measure
        readings: list = [0.0] * len(self.channels)
        overs: list = [False] * len(self.channels)
        for b in answering:
            for ch in b.channels:
                readings[ch.index], overs[ch.index] = measure(ch)
        return readings, overs

    def _complete_cycle(self, on_bus: EmulatedBus) -> Sequence[EmulatedBus]:
        """Lockstep: count this bus's SYNC; the buses to answer when every bus's SYNC of the
        cycle is in (all of them), else none."""
        if not on_bus.channels:
            return ()
        on_bus.pending_syncs += 1
        if self._several_buses:
            for b in self._gated:
                if b.pending_syncs == 0:
                    return ()
        for b in self._gated:
            b.pending_syncs -= 1
        return self._gated

    def _make_faults(self) -> None:
        """The scheduled faults whose stand time has come (:mod:`plant_emulator.scheduled_faults`)."""
        plant = self.lockstep_plant if self.options.lockstep else self.realtime_plant
        for fault in self.faults.due(plant.stand_time_s):
            log.warning("scheduled fault: %s", fault.text([c.name for c in self.channels]))
            if fault.kind == "spike":
                self._spikes[fault.channel] = self._spikes.get(fault.channel, 0.0) + fault.value_kgf
            else:
                self.channels[fault.channel].valve.silence_heartbeat(fault.duration_s)

    def _command_changed(self, channel: EmulatedChannel) -> None:
        """Called by a valve after its effective command may have changed."""
        channel.command = channel.valve.spool_command_percent()

    def _started(self, channel: EmulatedChannel) -> None:
        self.channel_started(channel)

    # -- the steps of a cycle that a different force source (a replayed capture) overrides -------
    def channel_started(self, channel: EmulatedChannel) -> None:
        """Hook: the master started ``channel``'s dynamometer (NMT OPERATIONAL), i.e. a run
        begins on it. The plant goes on (forces, spools, delay lines) but the channel's clock
        restarts, as the run's record does: an effect of the time since a run began
        (``gain_drift``, ``null_drift``) counts from here."""
        with self.lock:
            if self.options.lockstep:
                self.lockstep_plant.restart_clock([channel.index])
            else:
                self._catch_up()
                self.realtime_plant.restart_clock([channel.index])

    def advance_plant(self) -> None:
        """Bring the plant to the time of this cycle (lockstep: one period; real time: now)."""
        if self.options.lockstep:
            self._lockstep_cycle()
        else:
            self._catch_up()

    def measure(self, channel: EmulatedChannel) -> tuple[float, bool]:
        """``channel``'s dynamometer reading (kgf) at this SYNC and whether it is over range."""
        return channel.sensor.read(self.force_of(channel.index))

    # -- the valves' watchdogs -------------------------------------------------------------------
    def _lockstep_watchdog(self) -> None:
        """Lockstep: the stand's time advances by one period at this cycle; every valve's RPDO
        timeout is checked on it (the command of the period that just ended still counts)."""
        period = self._cycle_period()
        if period > 0 and math.isfinite(period):
            self.stand_time_s += period
        now = self.stand_time_s
        for ch in self.channels:
            valve = ch.valve
            if valve.rpdo_timeout_due(now) and valve.check_rpdo_timeout(now):
                valve.fault(P.EMCY_RPDO_TIMEOUT)

    def _watch(self) -> None:
        """Real time: every valve's RPDO watchdog (event timer 0x1400:05), polled every
        ``watchdog_poll_s``; a coupled plant is also caught up at each poll (its step-by-step
        integration then never has a long gap to make up at a SYNC).

        A real valve counts the timeout in its own firmware, which never stops. This emulator
        is a process on a shared machine: when the whole process was not scheduled for a while,
        commands that arrived meanwhile are still waiting in the socket. So a timeout is not
        declared in a poll that itself came late, nor while frames are waiting to be read on
        the valve's bus (for at most :data:`_MAX_DEFERRAL_S`), which keeps a loaded machine
        from faking a dead master without hiding a real one."""
        poll = self.options.watchdog_poll_s
        last = time.monotonic()
        deferred_since: float | None = None
        skipped = 0
        guarded = [n for ch in self.channels for n in ch.nodes if n.guarding is not None]
        while not self._stop.wait(poll):
            now = time.monotonic()
            stalled = now - last > poll + _STALL_S
            last = now
            if stalled and skipped < 3:      # never more than 3 polls in a row
                skipped += 1
                continue
            skipped = 0
            with self.lock:
                if self.rig_model.coupled:
                    self._catch_up()
                self._check_lives(guarded, now)
                due = [ch for ch in self.channels if ch.valve.rpdo_timeout_due(now)]
            if not due:
                deferred_since = None
                continue
            waiting = any(self._frames_waiting(ch.on_bus.bus) for ch in due)
            if waiting and (deferred_since is None or now - deferred_since < _MAX_DEFERRAL_S):
                deferred_since = deferred_since or now
                continue
            deferred_since = None
            with self.lock:
                for ch in due:
                    if ch.valve.check_rpdo_timeout(time.monotonic()):
                        ch.valve.fault(P.EMCY_RPDO_TIMEOUT)

    def _watch_lives(self, guarded) -> None:
        """Lockstep with guarded nodes: their life guarding on the wall clock (the master guards
        on it), polled every 20 ms."""
        while not self._stop.wait(0.02):
            with self.lock:
                self._check_lives(guarded, time.monotonic())

    @staticmethod
    def _check_lives(guarded, now: float) -> None:
        """Node guarding: each guarded node whose master stopped asking within its life time
        reacts (:meth:`~plant_emulator.node.EmulatedNode.life_guard_lost`)."""
        for node in guarded:
            if node.guarding.life_expired(now):
                log.warning("node %d: life guarding: no guard request within %g s", node.id,
                            node.guarding.life_time_s() or 0)
                node.life_guard_lost()

    @staticmethod
    def _frames_waiting(bus: can.BusABC) -> bool:
        try:
            ready, _, _ = select.select([bus.fileno()], [], [], 0)
        except (AttributeError, NotImplementedError, OSError, ValueError, TypeError):
            return False
        return bool(ready)
