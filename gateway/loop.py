"""The control loop: one SYNC per period, force in, command out, one recorded row per cycle.

Each cycle::

    SYNC(counter) ─▶ wait for the valve and force TPDOs ─▶ supervisor check ─▶ experiment.step
        ─▶ shaped command ─▶ valve RPDO ─▶ record the row

* **real time**: SYNCs on an absolute schedule (no drift); the TPDOs are awaited until 80 % of
  the period; a late or missing force PDO makes the cycle *stale* (the last reading is reused
  and counted); a cycle that starts later than one period is an *overrun* (counted).
* **lockstep**: the next SYNC goes out as soon as the cycle is complete; the stand (emulator
  with ``--lockstep``) advances one period per SYNC, so a run takes as long as the bus needs.

The TPDO callbacks run on the canopen Notifier thread; they only decode with the precompiled
PDO layouts and hand the values over through a queue.
"""
from __future__ import annotations

import math
import queue
import struct
import time
from dataclasses import dataclass, field

import can

from dbc import profile as P

from .capture import TappedNetwork
from .errors import SafetyStop
from .experiments import Experiment
from .master import StandMaster
from .recorder import RunRecorder
from .supervisor import Supervisor

SYNC_COB_ID = 0x80


@dataclass
class LoopStats:
    cycles: int = 0
    stale_cycles: int = 0
    overruns: int = 0
    bad_frames: int = 0
    late_frames: int = 0
    max_lateness_s: float = 0.0
    wall_s: float = 0.0
    #: real time only: SYNC send time minus its scheduled time, s (one per cycle)
    sync_jitter_s: list = field(default_factory=list)


@dataclass
class LoopOutcome:
    status: str                   #: "complete" or "stopped"
    reason: str | None            #: machine-readable reason the run ended early
    message: str | None
    stats: LoopStats


class ControlLoop:
    """Runs experiments against the stand behind ``master`` (configured and booted)."""

    def __init__(self, network: TappedNetwork, master: StandMaster, supervisor: Supervisor,
                 period_s: float, lockstep: bool, lockstep_timeout_s: float = 2.0) -> None:
        self.network = network
        self.master = master
        self.supervisor = supervisor
        self.period_s = period_s
        self.lockstep = lockstep
        self.lockstep_timeout_s = lockstep_timeout_s
        self._arrivals: queue.SimpleQueue = queue.SimpleQueue()
        self._force_layout = master.force_tpdo
        self._valve_layout = master.valve_tpdo
        self._rpdo = master.valve_rpdo
        self._force_pos = self._force_layout.position(*P.PV_INT32)
        self._status_pos = self._valve_layout.position(P.STATUS_WORD, 0)
        self._spool_pos = self._valve_layout.position(*P.ACTUAL_VALUE)
        self._rpdo_cw = self._rpdo.position(P.CONTROL_WORD, 0)
        self._rpdo_sp = self._rpdo.position(*P.SETPOINT)
        self.stats = LoopStats()
        self._subscribed = False

    # -- frames from the Notifier thread ----------------------------------------------------------
    def _on_tpdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        layout = self._force_layout if can_id == self._force_layout.cob_id else self._valve_layout
        try:
            values = layout.decode(data)
        except struct.error:
            self.stats.bad_frames += 1      # wrong DLC for a known frame: counted, never decoded
            return
        self._arrivals.put((can_id, values, time.monotonic()))

    def _subscribe(self) -> None:
        if not self._subscribed:
            self.network.subscribe(self._force_layout.cob_id, self._on_tpdo)
            self.network.subscribe(self._valve_layout.cob_id, self._on_tpdo)
            self._subscribed = True

    def close(self) -> None:
        if self._subscribed:
            self.network.unsubscribe(self._force_layout.cob_id, self._on_tpdo)
            self.network.unsubscribe(self._valve_layout.cob_id, self._on_tpdo)
            self._subscribed = False

    # -- helpers ---------------------------------------------------------------------------------
    def send_command(self, control_word: int, u_pct: float) -> float:
        """Send the valve RPDO; returns the command as it went on the wire (quantized, %)."""
        values = [0] * len(self._rpdo.keys)
        values[self._rpdo_cw] = int(control_word)
        values[self._rpdo_sp] = counts = P.percent_to_counts(u_pct)
        self.network.send_message(self._rpdo.cob_id, self._rpdo.encode(*values))
        return P.counts_to_percent(counts)

    def safe_state(self) -> None:
        """Zero flow, valve to HOLD (hold setpoint), sent twice in case one frame is lost."""
        for _ in range(2):
            try:
                self.send_command(P.CW_HOLD, 0.0)
            except can.CanError:
                pass

    def _drain(self) -> None:
        while True:
            try:
                self._arrivals.get_nowait()
            except queue.Empty:
                return
            self.stats.late_frames += 1

    # -- the loop --------------------------------------------------------------------------------
    def run(self, experiment: Experiment, recorder: RunRecorder | None, progress=None) -> LoopOutcome:
        """Run ``experiment`` to its end or until the supervisor stops it. The valve is left
        in HOLD with zero command either way."""
        self._subscribe()
        self.supervisor.reset()
        experiment.abort = None
        experiment.configure(self.period_s, self.supervisor.limits.force_limit_kgf)
        stats = self.stats = LoopStats()
        T = self.period_s
        force_cob = self._force_layout.cob_id
        scale = self.master.force_scale_kgf
        counter = 0
        y = math.nan
        y_counts = 0
        spool = math.nan
        status = 0
        reason = message = None
        self._drain()
        stats.late_frames = 0
        # Enable the valve with a zero command before the first SYNC.
        self.send_command(P.CW_ACTIVE, 0.0)
        wall0 = time.monotonic()
        t_start = time.perf_counter()
        next_sync = t_start
        cycle = 0
        try:
            while True:
                if not self.lockstep:
                    _sleep_until(next_sync)
                    now = time.perf_counter()
                    stats.sync_jitter_s.append(now - next_sync)
                    if now - next_sync > T:
                        missed = int((now - next_sync) / T)
                        stats.overruns += missed
                        next_sync += missed * T
                    t = next_sync - t_start
                    deadline = next_sync + 0.8 * T
                else:
                    t = cycle * T
                    deadline = time.perf_counter() + self.lockstep_timeout_s
                self._drain()
                counter = counter % P.SYNC_COUNTER_OVERFLOW + 1
                sync_wall = time.time()
                self.network.send_message(SYNC_COB_ID, bytes((counter,)))
                got_force = got_valve = False
                while not (got_force and got_valve):
                    remaining = deadline - time.perf_counter()
                    if remaining <= 0:
                        break
                    try:
                        cob, values, _ = self._arrivals.get(timeout=remaining)
                    except queue.Empty:
                        break
                    if cob == force_cob:
                        y_counts = values[self._force_pos]
                        y = y_counts * scale
                        got_force = True
                    else:
                        status = values[self._status_pos]
                        spool = P.counts_to_percent(values[self._spool_pos])
                        got_valve = True
                stale = not got_force
                if stale:
                    stats.stale_cycles += 1
                verdict = self.supervisor.check(y, stale)
                if verdict is None and self.lockstep and not (got_force and got_valve):
                    link = self.master.valve if got_force else self.master.dynamometer
                    verdict = ("no_answer_to_sync",
                               f"{link.role} node {link.id} did not answer SYNC within "
                               f"{self.lockstep_timeout_s:g} s (is the emulator running with "
                               "--lockstep on this bus?)")
                if verdict is not None:
                    reason, message = verdict
                    self.safe_state()
                    break
                if cycle == 0:
                    experiment.begin(y)
                if experiment.finished(t, y):
                    break
                u_req, r = experiment.step(t, y)
                if experiment.abort is not None:
                    reason, message = experiment.abort
                    self.safe_state()
                    break
                u = self.send_command(P.CW_ACTIVE, self.supervisor.shape_command(u_req))
                if recorder is not None:
                    recorder.append(t, u, y, r, cycle, y_counts, spool, status, stale, sync_wall)
                cycle += 1
                stats.cycles = cycle
                if progress is not None:
                    progress(t)
                next_sync += T
        except BaseException:
            self.safe_state()
            raise
        self.safe_state()
        stats.wall_s = time.monotonic() - wall0
        return LoopOutcome("complete" if reason is None else "stopped", reason, message, stats)


def _sleep_until(target: float) -> None:
    """Sleep to ~0.3 ms before ``target`` (perf_counter time), then spin: sub-0.1 ms accuracy
    without burning a core for the whole period."""
    while True:
        remaining = target - time.perf_counter()
        if remaining <= 0:
            return
        if remaining > 0.0003:
            time.sleep(remaining - 0.0003)
