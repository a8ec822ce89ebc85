"""The emulated stand: both CANopen nodes wired to one plant model, on any python-can bus.

Time:

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
"""
from __future__ import annotations

import logging
import math
import select
import threading
import time
from dataclasses import dataclass

import can
import canopen
import numpy as np

from dbc import DYNAMOMETER_EDS, VALVE_EDS
from dbc import profile as P
from plant.config import PlantConfig
from standbus import LOCKSTEP_BUSY_POLL_S, prefer_busy_poll

from .dynamometer import DynamometerNode
from .lockstep_plant import LockstepPlant
from .node import slave_frame_filter
from .valve import ServoValveNode

log = logging.getLogger(__name__)

_MAX_BLOCK = 200_000  # steps per numpy block when catching up a long gap in real time
#: a watchdog poll this much later than asked means the process was not running, s
_STALL_S = 0.02
#: how long the watchdog waits for frames already in the socket before declaring a timeout, s
_MAX_DEFERRAL_S = 0.02


@dataclass
class EmulatorOptions:
    lockstep: bool = False
    seed: int | None = None
    valve_id: int = P.VALVE_NODE_ID
    dynamometer_id: int = P.DYNAMOMETER_NODE_ID
    step_s: float = 0.0005
    watchdog_poll_s: float = 0.005


class EmulatedStand:
    """Owns the network, the two emulated nodes and the plant. Call :meth:`start`, then
    :meth:`stop` (or use as a context manager)."""

    def __init__(self, bus: can.BusABC, config: PlantConfig, options: EmulatorOptions) -> None:
        config.validate()
        if options.valve_id == options.dynamometer_id:
            raise ValueError("the valve and the dynamometer need different node ids")
        self.bus = bus
        self.config = config
        self.options = options
        self.model = config.model
        self.sensor = config.dynamometer(options.seed)
        self.network = canopen.Network(bus)
        #: frames dropped before the stack (wrong DLC on NMT/SYNC/SDO, error/remote/ext/FD frames)
        self.frame_filter = slave_frame_filter(self.network, (options.valve_id, options.dynamometer_id))
        self.valve = ServoValveNode(self.network, options.valve_id, VALVE_EDS, options.lockstep)
        self.dynamometer = DynamometerNode(self.network, options.dynamometer_id, DYNAMOMETER_EDS)
        self.lock = threading.RLock()
        self.valve.lock = self.lock          # one lock for the whole stand
        self.dynamometer.lock = self.lock
        self.valve.before_change = self._catch_up
        self.valve.after_change = self.command_changed
        self.dynamometer.started_listeners.append(self.run_started)
        self.network.subscribe(P.SYNC_COB_ID, self._on_sync)
        self._plant_dt = options.step_s
        # compile (or load) the model's compiled loops now, not at the first SYNC of a run
        self.model.simulate(np.zeros(8), self._plant_dt, y0=config.initial_force_kgf)
        self._plant = self.model.new_state(1, self._plant_dt, y0=config.initial_force_kgf)
        #: lockstep: the plant one period per SYNC, computed ahead in blocks
        self.lockstep_plant = LockstepPlant(self.model, config.initial_force_kgf, options.step_s)
        self._command = 0.0
        self._t_plant = time.monotonic()
        self._syncs = 0
        #: lockstep: the stand's own time (s), one communication cycle period per SYNC; the
        #: valve's RPDO timeout counts on it
        self.stand_time_s = 0.0
        if options.lockstep:
            self.valve.clock = self.dynamometer.clock = lambda: self.stand_time_s
        self._stop = threading.Event()
        self._watchdog: threading.Thread | None = None
        self.errors: list[str] = []

    # -- lifecycle -------------------------------------------------------------------------------
    def start(self) -> None:
        if self.options.lockstep:   # the next SYNC follows the answer within ~0.1 ms: poll for it
            prefer_busy_poll(self.bus, LOCKSTEP_BUSY_POLL_S)
        self.network.notifier = can.Notifier(self.bus, self.network.listeners, 0.1)
        self._t_plant = time.monotonic()
        self.valve.boot()
        self.dynamometer.boot()
        if not self.options.lockstep:     # lockstep: checked at each SYNC, on the stand's time
            self._watchdog = threading.Thread(target=self._watch, name="emulator-watchdog", daemon=True)
            self._watchdog.start()

    def stop(self) -> None:
        self._stop.set()
        if self._watchdog is not None:
            self._watchdog.join(1.0)
        for node in (self.valve, self.dynamometer):
            node.local.nmt.stop_heartbeat()
        if self.network.notifier is not None:
            self.network.notifier.stop(1.0)

    def __enter__(self) -> "EmulatedStand":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def force_kgf(self) -> float:
        if self.options.lockstep:
            return self.lockstep_plant.force
        return float(self._plant.reading[0])

    # -- plant time ------------------------------------------------------------------------------
    def _advance(self, steps: int) -> None:
        """Real time: ``steps`` plant steps with the command held."""
        while steps > 0:
            k = min(steps, _MAX_BLOCK)
            self.model.advance(self._plant, np.full((1, k), self._command), self._plant_dt)
            steps -= k

    def _catch_up(self) -> None:
        """Real time: integrate up to now with the command held so far."""
        if self.options.lockstep:
            return
        now = time.monotonic()
        steps = int((now - self._t_plant) / self._plant_dt)
        if steps > 0:
            self._advance(steps)
            self._t_plant += steps * self._plant_dt

    def _lockstep_cycle(self) -> None:
        """Lockstep: one communication cycle period per SYNC (none before the first)."""
        self._syncs += 1
        if self._syncs == 1:
            return
        period = int(self.valve.value(P.COMM_CYCLE_PERIOD)) * 1e-6
        if not (period > 0 and math.isfinite(period)):
            return
        self.lockstep_plant.step(period, self._command)

    # -- bus events ------------------------------------------------------------------------------
    def _on_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        try:
            with self.lock:
                self.advance_plant()
                if self.options.lockstep:
                    self._lockstep_watchdog()
                reading, over = self.measure_force()
                self.dynamometer.publish(reading, over)
                self.valve.update_outputs(self._command)
                counter = data[0] if len(data) >= 1 else None
                self.valve.on_sync(counter)
                self.dynamometer.on_sync(counter)
        except Exception as exc:  # never let the notifier swallow it silently
            log.exception("SYNC handling failed")
            self.errors.append(repr(exc))

    # -- the two steps of a SYNC that a different force source (e.g. a replayed capture)
    # -- overrides -------------------------------------------------------------------------------
    def run_started(self) -> None:
        """Hook: the master started the nodes (NMT OPERATIONAL), i.e. a run begins. The plant
        goes on (force, spool, delay line) but its clock restarts, as the run's record does: an
        effect of the time since a run began (``gain_drift``, ``null_drift``) counts from here. A different
        force source (a replayed capture) restarts its replay here."""
        with self.lock:
            if self.options.lockstep:
                self.lockstep_plant.restart_clock()
            else:
                self._catch_up()
                self._plant.t[:] = 0.0

    def advance_plant(self) -> None:
        """Bring the plant to the time of this SYNC (lockstep: one period; real time: now)."""
        if self.options.lockstep:
            self._lockstep_cycle()
        else:
            self._catch_up()

    def measure_force(self) -> tuple[float, bool]:
        """The dynamometer's reading (kgf) at this SYNC and whether it is over range."""
        return self.sensor.read(self.force_kgf)

    def command_changed(self) -> None:
        """Called by the valve after its effective command may have changed."""
        self._command = self.valve.spool_command_percent()

    def _lockstep_watchdog(self) -> None:
        """Lockstep: the stand's time advances by one period at this SYNC; the valve's RPDO
        timeout is checked on it (the command of the period that just ended still counts)."""
        period = int(self.valve.value(P.COMM_CYCLE_PERIOD)) * 1e-6
        if period > 0 and math.isfinite(period):
            self.stand_time_s += period
        if self.valve.check_rpdo_timeout(self.stand_time_s):
            self.valve.fault(P.EMCY_RPDO_TIMEOUT)

    def _watch(self) -> None:
        """Real time: the valve's RPDO watchdog (event timer 0x1400:05), polled every
        ``watchdog_poll_s``.

        A real valve counts the timeout in its own firmware, which never stops. This emulator
        is a process on a shared machine: when the whole process was not scheduled for a while,
        commands that arrived meanwhile are still waiting in the socket. So a timeout is not
        declared in a poll that itself came late, nor while frames are waiting to be read
        (for at most :data:`_MAX_DEFERRAL_S`), which keeps a loaded machine from faking a dead
        master without hiding a real one."""
        poll = self.options.watchdog_poll_s
        last = time.monotonic()
        deferred_since: float | None = None
        skipped = 0
        while not self._stop.wait(poll):
            now = time.monotonic()
            stalled = now - last > poll + _STALL_S
            last = now
            if stalled and skipped < 3:      # never more than 3 polls in a row
                skipped += 1
                continue
            skipped = 0
            with self.lock:
                due = self.valve.rpdo_timeout_due(now)
            if not due:
                deferred_since = None
                continue
            if self._frames_waiting() and (deferred_since is None or now - deferred_since < _MAX_DEFERRAL_S):
                deferred_since = deferred_since or now
                continue
            deferred_since = None
            with self.lock:
                if self.valve.check_rpdo_timeout(time.monotonic()):
                    self.valve.fault(P.EMCY_RPDO_TIMEOUT)

    def _frames_waiting(self) -> bool:
        try:
            ready, _, _ = select.select([self.bus.fileno()], [], [], 0)
        except (AttributeError, NotImplementedError, OSError, ValueError, TypeError):
            return False
        return bool(ready)
