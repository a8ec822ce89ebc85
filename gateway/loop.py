"""The control loop: one SYNC per period, force in, command out, one recorded row per cycle.

Each cycle::

    SYNC(counter) ─▶ wait for the valve and force TPDOs ─▶ supervisor check ─▶ experiment.step
        ─▶ error detector ─▶ shaped command ─▶ valve RPDO ─▶ record the row

* **real time**: SYNCs on an absolute schedule (no drift); the TPDOs are awaited until the
  cycle's reserve for its own work; a late or missing force PDO makes the cycle *stale* (the
  last reading is reused and counted). A synchronous TPDO does not say which SYNC it answers,
  so when the bus stamps frames with wall-clock time (udp_loopback, SocketCAN) a TPDO sent
  before this cycle's SYNC is an old answer that was delayed: counted as late, never taken as
  fresh. The nodes get a synchronous window (0x1007, :func:`sync_window_s`) and discard an
  answer they could not send within it, so none is sent after the next SYNC; one sent within
  the window after the SYNC before is old too (a late SYNC follows its predecessor by less
  than a period). A cycle that starts later than one period is an *overrun* (counted), and one
  later than ``overrun_limit_s`` stops the run.
* **lockstep**: the next SYNC goes out as soon as the cycle is complete; the stand (emulator
  with ``--lockstep``) advances one period per SYNC, so a run takes as long as the bus needs.
  While waiting for an answer the loop checks the heartbeats and EMCYs every 20 ms, so a dead
  or frozen stand is noticed within the heartbeat timeout, not only after the answer timeout.

When the supervisor trips (:mod:`gateway.supervisor`) the cycle's command is the safe one
(hold: control word HOLD with zero setpoint; zero: DISABLED with zero setpoint), the row of
that cycle is recorded with it, and the run ends — or, for a controlled unload, the
supervisor's unload loop drives the remaining cycles until the force is about zero, then hold.
Every command sent is either the experiment's command shaped by the supervisor or a safe one.

**A rig** (many channels on one or several buses) runs in the same loop: each cycle one SYNC per
bus (the same counter, sent back to back, so the buses' cycles are aligned), every channel's two
TPDOs awaited, every channel's supervisor asked, N commands sent, one row recorded. A trip on
any channel acts on every channel: hold all, zero all, or unload all keeping the load ratios
(:mod:`gateway.unload`), the channel whose valve or communication failed held apart
(:class:`RigSafety`). A one-channel stand is the rig of one channel. The experiment drives
its channels one by one (per-channel drivers, each its own copy; the others hold a zero command)
or all at once (a :class:`~gateway.experiments.rig.RigExperiment`: N forces in, N commands and
N references out per cycle, each channel's supervisor and the rig's safety the same).

The TPDOs are taken raw by their own handlers in each bus's notifier, before canopen (no
python-can Message, no dispatch), decoded with the precompiled PDO layouts and handed over
through a queue; a cycle's commands go out as one send per bus (on udp_loopback one datagram:
:mod:`standbus.wire`), FD frames on a CAN FD bus. In lockstep they go out with the next
cycle's SYNC, in the same send, before it, as soon as they are made: the stand takes them
before that SYNC all the same, a cycle costs one datagram a bus fewer, and the stand computes
the next cycle while the loop records this one. A rig's supervisors are asked together in a
quiet cycle (:class:`~gateway.supervisor.SupervisorBank`), one by one in any other. In lockstep, and in real time on a rig, the loop takes its buses over for the run
(:class:`standbus.HandoverNotifier`) and receives on its own thread: no thread hand-off, no
wake-up of a reader thread and no GIL hand-off per frame (a rig's 16 answers a cycle on 2
buses made the reader threads compete with the loop for the GIL). In lockstep it polls briefly
before it sleeps; in real time it sleeps in ``select`` and, between a cycle's end and the next
SYNC, keeps receiving (heartbeats, EMCY, late answers: every frame still reaches every
listener on the way). A one-channel stand in real time keeps the canopen Notifier thread.
"""
from __future__ import annotations

import contextlib
import gc
import itertools
import logging
import math
import queue
import struct
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import can

from dbc import profile as P
from standbus import LOCKSTEP_BUSY_POLL_S
from standbus.handover import handover_many

from .capture import TappedNetwork, send_together
from .errors import ParameterError
from .experiments import Experiment
from .experiments.rig import RigExperiment, is_rig_experiment
from .master import StandMaster
from .recorder import RunRecorder
from .supervisor import Supervisor, SupervisorBank, Trip
from .unload import RatioUnloader

if TYPE_CHECKING:
    import numpy as np

log = logging.getLogger(__name__)

SYNC_COB_ID = 0x80
#: lockstep: how often the loop looks at heartbeats/EMCYs while it waits for an answer, s
WAIT_SLICE_S = 0.02
#: the last part of the wait for a SYNC's time, spent polling the clock, s
_SPIN_S = 0.0003
#: real time: what a cycle keeps after its answers' deadline for its own work, as parts of the
#: period (least and most), and how it follows the work: 1.5 × the 95th percentile of the last
#: 256 cycles' work + 0.1 ms, looked at every 64 cycles
WORK_RESERVE_MIN, WORK_RESERVE_MAX = 0.2, 0.5
WORK_MARGIN, WORK_SLACK_S = 1.5, 0.0001
WORK_WINDOW, WORK_EVERY = 256, 64
WORK_RANK = int(0.95 * WORK_WINDOW)
#: a TPDO stamped more than this before the SYNC went out answers an earlier SYNC, s
STAMP_SKEW_S = 0.0005


@dataclass
class LoopStats:
    cycles: int = 0
    stale_cycles: int = 0
    overruns: int = 0
    #: TPDOs of a known layout with the wrong length (never decoded)
    bad_frames: int = 0
    late_frames: int = 0
    max_lateness_s: float = 0.0
    wall_s: float = 0.0
    #: frames the acceptance filter dropped during the run: on ids of no configured node,
    #: with a wrong DLC for their id, or not classic data frames (error/remote/extended/FD)
    unexpected_frames: int = 0
    wrong_dlc_frames: int = 0
    not_classic_frames: int = 0
    #: cycles whose command the supervisor clamped or rate-limited
    shaped_commands: int = 0
    #: indicate-only limit events (run.json ``events``)
    limit_events: int = 0
    #: real time only: SYNC send time minus its scheduled time, s (one per cycle)
    sync_jitter_s: list = field(default_factory=list)
    #: real time only: how long after this cycle's SYNC time the cycle before ended, s (0: in
    #: time; one per cycle): a SYNC late because of the loop's own work, not its wake-up
    behind_s: list = field(default_factory=list)
    #: real time only: the shortest time after a SYNC the loop waited for its answers, s
    answer_window_min_s: float = math.inf
    #: the loop thread's own CPU time over the run, s (its share of the cores: per cycle over
    #: the period)
    loop_cpu_s: float = 0.0


@dataclass
class LoopOutcome:
    status: str                   #: "complete" or "stopped"
    reason: str | None            #: machine-readable reason the run ended early
    message: str | None
    stats: LoopStats
    #: how the run was brought to its safe state (run.json ``safety``), None if it completed
    safety: dict | None = None
    #: a rig: what the loop counted per channel (run.json ``rig.loop``), None for one channel
    rig: dict | None = None


@dataclass
class LoopChannel:
    """One loading channel as the loop drives it: its nodes' master, its supervisor (its own
    limits and detectors), the bus it is on (index into the loop's networks)."""

    name: str
    master: StandMaster
    supervisor: Supervisor
    bus: int = 0
    range_kgf: float = math.nan


@dataclass
class RigSafety:
    """What a trip on one channel does to the rig (docs/safety.md, "A rig").

    ``fault_action``: what a channel's communication or valve fault (heartbeat, EMCY, stale
    reading, valve fault, no answer) does to the other channels: ``hold`` them all, or
    ``unload`` them keeping the load ratios while the faulty channel, whose valve is in (or is
    left to) its own safe state, holds. Force-limit and error trips act with their own actions
    (``--limit-action``, ``--error-action``) on every channel. ``G``: the rig's coupling, if
    known (the unload's gains and feedforward, :mod:`gateway.unload`)."""

    fault_action: str = "hold"
    G: "np.ndarray | None" = None


#: trips after which the channel cannot take part in an unload: its valve is in its own safe
#: state, or its readings or its commands do not get through
CHANNEL_FAULTS = frozenset({"force_pdo_stale", "heartbeat_lost", "nmt_state", "emcy", "valve_fault",
                            "valve_not_active", "no_answer_to_sync"})
#: bus key stride: a TPDO's key is its COB-ID + bus index × this (bus 0: the COB-ID itself)
KEY_STRIDE = 0x800


class ControlLoop:
    """Runs experiments against the stand behind ``master`` (configured and booted), or, with
    ``channels``/``networks``, against every channel of a rig at once: one SYNC per bus per
    cycle (the same counter, sent back to back), N forces in, N commands out, one row.

    A one-channel stand is the rig of one channel on one bus (``channels=None``)."""

    def __init__(self, network: TappedNetwork, master: StandMaster, supervisor: Supervisor,
                 period_s: float, lockstep: bool, lockstep_timeout_s: float = 2.0, *,
                 channels: list[LoopChannel] | None = None,
                 networks: list[TappedNetwork] | None = None,
                 rig_safety: RigSafety | None = None) -> None:
        if channels is None:
            channels = [LoopChannel("", master, supervisor, 0)]
            networks = [network]
        self.channels = channels
        self.networks = networks or [network]
        self.rig = len(channels) > 1 or bool(channels[0].name)
        self.rig_safety = rig_safety or RigSafety()
        self.network = self.networks[0]
        self.master = channels[0].master
        self.supervisor = channels[0].supervisor
        self.period_s = period_s
        self.lockstep = lockstep
        self.lockstep_timeout_s = lockstep_timeout_s
        self._arrivals: queue.SimpleQueue = queue.SimpleQueue()
        #: TPDO key (COB-ID + bus × KEY_STRIDE) → (channel index, is the force)
        self._route: dict[int, tuple[int, bool]] = {}
        self._layouts: list[dict[int, object]] = [{} for _ in self.networks]
        self._force_pos, self._status_pos, self._spool_pos = [], [], []
        for i, ch in enumerate(channels):
            m = ch.master
            for layout, is_force in ((m.force_tpdo, True), (m.valve_tpdo, False)):
                self._route[layout.cob_id + ch.bus * KEY_STRIDE] = (i, is_force)
                self._layouts[ch.bus][layout.cob_id] = layout
            self._force_pos.append(m.force_pos)
            self._status_pos.append(m.status_pos)
            self._spool_pos.append(m.spool_pos)
        self._callbacks = [self._tpdo_callback(b) for b in range(len(self.networks))]
        #: per bus, the TPDOs' own handlers for the bus's notifier (raw frames, no Message)
        self._fast = [{cob: self._fast_tpdo(b, cob, layout) for cob, layout in layouts.items()}
                      for b, layouts in enumerate(self._layouts)]
        self.stats = LoopStats()
        self._subscribed = False
        #: lockstep: receives one frame on the loop's own thread (the reader threads parked)
        self._pump = None

    # -- frames from the Notifier threads ---------------------------------------------------------
    def _tpdo_callback(self, bus: int):
        layouts = self._layouts[bus]
        offset = bus * KEY_STRIDE
        put = self._arrivals.put

        def on_tpdo(can_id: int, data: bytes, timestamp: float) -> None:
            try:
                values = layouts[can_id].decode(data)
            except struct.error:
                self.stats.bad_frames += 1      # wrong DLC for a known frame: counted, never decoded
                return
            put((can_id + offset, values, timestamp))
        return on_tpdo

    def _fast_tpdo(self, bus: int, cob: int, layout):
        """A TPDO's handler in its bus's notifier: decoded from the raw frame, no Message and
        no canopen dispatch; a frame of another length is left to the acceptance filter
        (counted there as a wrong DLC, as before)."""
        size, unpack = layout.size, layout.codec.unpack
        key = cob + bus * KEY_STRIDE
        put = self._arrivals.put

        def on_tpdo(data: bytes, stamp: float) -> bool:
            if len(data) != size:
                return False
            put((key, unpack(data), stamp))
            return True
        return on_tpdo

    def _subscribe(self) -> None:
        if not self._subscribed:
            for net, layouts, callback, fast in zip(self.networks, self._layouts, self._callbacks,
                                                    self._fast):
                for cob in layouts:
                    net.subscribe(cob, callback)
                notifier = getattr(net, "notifier", None)
                if isinstance(getattr(notifier, "fast", None), dict):
                    notifier.fast.update(fast)
                    notifier.fast_fd = bool(getattr(net, "cyclic_flags", 0))
            self._subscribed = True

    def close(self) -> None:
        if self._subscribed:
            for net, layouts, callback, fast in zip(self.networks, self._layouts, self._callbacks,
                                                    self._fast):
                for cob in layouts:
                    net.unsubscribe(cob, callback)
                notifier = getattr(net, "notifier", None)
                if isinstance(getattr(notifier, "fast", None), dict):
                    for cob in fast:
                        notifier.fast.pop(cob, None)
            self._subscribed = False

    # -- helpers ---------------------------------------------------------------------------------
    def send_command(self, control_word: int, u_pct: float, channel: int = 0) -> float:
        """Send a valve RPDO; returns the command as it went on the wire (quantized, %)."""
        setpoint = self.channels[channel].master.setpoint
        counts = setpoint.counts(u_pct)
        self.channels[channel].master.send_valve_command(control_word, counts)
        return setpoint.percent(counts)

    def safe_state(self, action: str = "hold", channels=None) -> float:
        """Zero setpoint and every valve (or those of ``channels``) to HOLD (its hold setpoint:
        zero flow) or, for the ``zero`` action, to DISABLED (spool to its fail-safe position);
        sent twice in case one frame is lost. Returns the wall-clock time of the first send
        (NaN if no bus took it)."""
        word = P.CW_DISABLED if action == "zero" else P.CW_HOLD
        sent = math.nan
        which = range(len(self.channels)) if channels is None else channels
        for _ in range(2):
            for i in which:
                try:
                    self.send_command(word, 0.0, i)
                    if sent != sent:
                        sent = time.time()
                except can.CanError:
                    pass
        return sent

    def _next_arrival(self, timeout: float):
        """The next decoded TPDO ``(key, values, stamp)``; raises ``queue.Empty`` after
        ``timeout`` s. With the buses handed over (lockstep) this thread receives the frames
        itself, every one of them reaching all listeners (heartbeats, EMCY, capture) on the way."""
        pump = self._pump
        if pump is None:
            return self._arrivals.get(timeout=timeout)
        end = time.perf_counter() + timeout
        while True:
            try:
                return self._arrivals.get_nowait()
            except queue.Empty:
                pass
            remaining = end - time.perf_counter()
            if remaining <= 0:
                raise queue.Empty
            pump(remaining)

    def _drain(self) -> None:
        if self._arrivals.empty():
            return
        while True:
            try:
                self._arrivals.get_nowait()
            except queue.Empty:
                return
            self.stats.late_frames += 1

    def _filter_counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for net in self.networks:
            flt = getattr(net, "frame_filter", None)
            for key, value in (flt.counts() if flt is not None else {}).items():
                out[key] = out.get(key, 0) + value
        return out

    def _check_nodes(self, watched=None) -> Trip | None:
        """Every (watched) channel's communication watchdogs (EMCY, heartbeat, NMT state)."""
        for i, ch in enumerate(self.channels):
            if watched is not None and not watched[i]:
                continue
            trip = ch.supervisor.check_nodes()
            if trip is not None:
                return self._named(trip, i)
        return None

    def _named(self, trip: Trip, channel: int | None) -> Trip:
        if self.rig and channel is not None:
            trip.channel = self.channels[channel].name
        return trip

    def _handover(self, stack: contextlib.ExitStack) -> None:
        """Take the buses from their reader threads for the run (lockstep; in real time a
        rig, whose answers would otherwise keep its reader threads and the loop handing the
        GIL back and forth: a stand's loop in real time keeps its reader thread, as measured)."""
        nets = self.networks
        if not all(hasattr(net, "handover") for net in nets):
            return
        # lockstep: each answer follows its SYNC within ~0.1 ms, so poll for it before sleeping,
        # writing the captures' frames between polls (the capture threads do what is left)
        spin = LOCKSTEP_BUSY_POLL_S if self.lockstep else 0.0
        idle = _captures_writer(nets) if self.lockstep else None
        if len(nets) == 1:
            self._pump = stack.enter_context(nets[0].handover(spin, idle=idle))
        else:
            self._pump = stack.enter_context(handover_many([net.notifier for net in nets], spin,
                                                           idle=idle))

    # -- the loop --------------------------------------------------------------------------------
    def run(self, experiment: Experiment, recorder: RunRecorder | None, progress=None,
            drivers: dict[int, Experiment] | None = None) -> LoopOutcome:
        """Run ``experiment`` to its end or until a supervisor stops it. On a rig ``drivers``
        maps the channels the experiment drives to their own copy of it (default: channel 0
        runs ``experiment``); every other channel holds a zero command. A
        :class:`~gateway.experiments.rig.RigExperiment` drives every channel itself (no
        ``drivers``; its ``names`` must be the rig's, in order). The valves are left in
        HOLD (or DISABLED after a ``zero`` trip) with zero command either way. Call it inside
        :func:`steady_heap` entered before the nodes start (as :meth:`Gateway.run` does)."""
        vector = experiment if is_rig_experiment(experiment) else None
        if vector is not None:
            self._check_vector(vector, drivers)
        self._subscribe()
        with contextlib.ExitStack() as stack:
            if takes_buses_over(self.lockstep, self.rig):
                self._handover(stack)
            try:
                return self._run({} if vector else (drivers or {0: experiment}), recorder,
                                 progress, vector)
            finally:
                self._pump = None

    def _check_vector(self, vector: RigExperiment, drivers) -> None:
        """A rig experiment drives every channel of this rig, in its order, and nothing else."""
        names = [c.name for c in self.channels]
        if drivers:
            raise ParameterError(f"{vector.name}: a rig experiment drives every channel itself; "
                                 "give no per-channel drivers (--channel) with it")
        if not self.rig and len(getattr(vector, "names", names)) == 1:
            return                             # a one-channel stand's channel has no name here
        if list(getattr(vector, "names", names)) != names:
            raise ParameterError(f"{vector.name}: the experiment is for the channels "
                                 f"{', '.join(vector.names)}; the rig has {', '.join(names)}")

    def _run(self, drivers: dict[int, Experiment], recorder: RunRecorder | None,
             progress, vector: RigExperiment | None = None) -> LoopOutcome:
        chans = self.channels
        n = len(chans)
        sups = [c.supervisor for c in chans]
        wait_s = WAIT_SLICE_S if self.lockstep else 0.8 * self.period_s
        for i, sup in enumerate(sups):
            exp = vector if vector is not None else drivers.get(i)
            sup.reset(getattr(exp, "max_command_pct", None) if exp is not None else None)
            sup.wait_s = wait_s
        driven = sorted(drivers)
        for i in driven:
            drivers[i].abort = None
            drivers[i].configure(self.period_s, sups[i].limits.force_limit_kgf)
        if vector is not None:
            vector.abort = None
            vector.configure_rig(self.period_s, [s.limits.force_limit_kgf for s in sups])
        stats = self.stats = LoopStats()
        filter0 = self._filter_counts()
        T = self.period_s
        lockstep = self.lockstep
        route = self._route
        scales = [c.master.force_scale_kgf for c in chans]
        force_pos, status_pos, spool_pos = self._force_pos, self._status_pos, self._spool_pos
        masters = [c.master for c in chans]
        networks = self.networks
        one_bus = len(networks) == 1
        sync_flags = getattr(networks[0], "cyclic_flags", 0)
        # a rig's supervisors asked together in a quiet cycle (a stand's one as it always was)
        bank = SupervisorBank(sups) if n > 1 else None
        bus_of = [c.bus for c in chans]
        out_frames: list[list] = [[] for _ in networks]
        channels_of_bus = [[i for i in range(n) if bus_of[i] == b] for b in range(len(networks))]
        #: each channel's last shaped command, its counts and the command as recorded
        shaped = [math.nan] * n
        shaped_counts = [0] * n
        shaped_pct = [0.0] * n
        next_arrival = self._next_arrival
        take_arrival = self._arrivals.get_nowait
        overrun_limit = sups[0].limits.overrun_limit_s
        #: each channel's setpoint scale (counts at 100 %) and, for a REAL32 process value,
        #: its counts of one last digit (y_counts)
        to_counts = [c.master.setpoint.counts for c in chans]
        to_percent = [c.master.setpoint.percent for c in chans]
        real_counts = [c.master.force_counts_per_unit for c in chans]
        spool_scale = [c.master.setpoint.percent_per_count for c in chans]
        CW_ACTIVE = P.CW_ACTIVE
        wall_stamps: bool | None = None
        #: lockstep: the next cycle's SYNC, sent after this cycle's commands (its counter,
        #: wall-clock stamp and freshness bound)
        sent_ahead: tuple[int, float, float] | None = None

        def send_sync(counter: int, last_wall: float, with_commands: bool) -> tuple[int, float, float]:
            """The next cycle's SYNC on every bus, the frames that came late drained first;
            ``with_commands`` (lockstep): each bus's commands in ``out_frames`` in the same
            send, before it (the stand takes them before that SYNC all the same, and a cycle
            costs one datagram a bus fewer). Returns the SYNC's counter, its wall-clock stamp
            and the stamp before which an answer is old."""
            self._drain()
            counter = counter % P.SYNC_COUNTER_OVERFLOW + 1
            now_wall = time.time()
            fresh_from = now_wall - STAMP_SKEW_S
            if window and last_wall + window > fresh_from:
                fresh_from = last_wall + window
            if with_commands:
                sync = (sync_flags, SYNC_COB_ID, 1, bytes((counter,)))
                for net, frames in zip(networks, out_frames):
                    frames.append(sync)
                    net.send_frames(frames)
            elif one_bus:
                networks[0].send_frames([(sync_flags, SYNC_COB_ID, 1, bytes((counter,)))])
            else:                         # every bus's SYNC, back to back
                send_together(networks, SYNC_COB_ID, bytes((counter,)))
            return counter, now_wall, fresh_from
        # a TPDO stamped before ``fresh_from`` answers an earlier SYNC: before this SYNC (less
        # the stamps' tolerance), or within the nodes' synchronous window after the one before
        # (a late SYNC follows its predecessor by less than a period; real time only)
        window = sync_window_s(T, lockstep)
        sync_wall = -math.inf
        counter = 0
        ys = [math.nan] * n
        y_counts = [0] * n
        spools = [math.nan] * n
        statuses = [0] * n
        stale_by_channel = [0] * n
        trip: Trip | None = None          # what ended (or is unloading) the run
        unloader: RatioUnloader | None = None
        unload_note: str | None = None
        excluded: list[int] = []
        #: the channels still watched and awaited: all until a trip excludes one
        watched = [True] * n
        watched_idx = list(range(n))
        full = expected = 2 * n
        fresh_row = [False] * n           # stale flags of a cycle that got every answer
        drive_list = [(i, drivers[i]) for i in driven]
        one_driver = drive_list[0] if len(drive_list) == 1 else None
        final_action = "hold"
        all_channels = range(n)
        #: a recorder that wants to hear of a trip as it happens (an endurance session's)
        on_trip = getattr(recorder, "trip", None)
        self._drain()
        stats.late_frames = 0
        # Enable the valves with a zero command before the first SYNC.
        for i in all_channels:
            self.send_command(CW_ACTIVE, 0.0, i)
        wall0 = time.monotonic()
        cpu0 = time.thread_time()
        t_start = time.perf_counter()
        # real time: the SYNCs' grid, slot k at t_start + k·T; a row's t is k·T exactly (a
        # sum of periods in floats drifts off it by ns when perf_counter is large: long uptimes)
        slot = 0
        next_sync = t_start
        cycle = 0
        # real time: the wait for a cycle's answers ends ``reserve`` before the next SYNC, so
        # the cycle's own work (checks, commands, record) fits after it: a fifth of the period
        # (a stand's work is ~50 µs); on a rig more where the recent work's 95th percentile
        # needs it (8 channels: 0.2-0.5 ms at 2 ms), at most half the period (a percentile, not
        # the peak, so one host stall in a cycle's work does not shorten the window for
        # seconds; on a stand a starved host's stretched work made it trip on stale readings)
        work = [0.0] * WORK_WINDOW
        reserve = WORK_RESERVE_MIN * T
        adaptive = not lockstep and self.rig       # a stand's work (~50 µs) never needs more
        if not lockstep:
            stats.answer_window_min_s = T - reserve
        try:
            while True:
                late_trip = None
                if not lockstep:
                    behind = time.perf_counter() - next_sync
                    _sleep_until(next_sync, self._pump)
                    now = time.perf_counter()
                    late = now - next_sync
                    stats.sync_jitter_s.append(late)
                    stats.behind_s.append(behind if behind > 0 else 0.0)
                    if late > T:
                        missed = int(late / T)
                        stats.overruns += missed
                        slot += missed
                        next_sync = t_start + slot * T
                    if late > overrun_limit:
                        late_trip = sups[0].overrun(late, time.time() - late)
                    t = slot * T
                    deadline = next_sync + T - reserve
                else:
                    t = cycle * T
                    deadline = time.perf_counter() + self.lockstep_timeout_s
                if sent_ahead is not None:     # lockstep: sent with the last cycle's commands
                    counter, sync_wall, fresh_from = sent_ahead
                    sent_ahead = None
                else:
                    counter, sync_wall, fresh_from = send_sync(counter, sync_wall, False)
                got_force = [False] * n
                got_valve = [False] * n
                missing = expected
                wait_trip = None
                while missing:
                    remaining = deadline - time.perf_counter()
                    if remaining <= 0:
                        break
                    try:       # what a datagram already brought, taken at once
                        key, values, stamp = take_arrival()
                    except queue.Empty:
                        try:
                            key, values, stamp = next_arrival(min(remaining, WAIT_SLICE_S))
                        except queue.Empty:
                            if recorder is not None:
                                recorder.poll()
                            wait_trip = self._check_nodes(watched)
                            if wait_trip is not None:
                                break
                            continue
                    if wall_stamps is None:      # first frame: does the bus stamp wall-clock time?
                        wall_stamps = abs(stamp - time.time()) < 1.0
                    if wall_stamps and stamp < fresh_from:
                        stats.late_frames += 1   # sent before this SYNC: an old answer, delayed
                        continue
                    i, is_force = route[key]
                    if is_force:
                        c = values[force_pos[i]]
                        ys[i] = c * scales[i]
                        y_counts[i] = c if real_counts[i] is None else _real_counts(c, real_counts[i])
                        if not got_force[i]:
                            got_force[i] = True
                            missing -= watched[i]
                    else:
                        statuses[i] = values[status_pos[i]]
                        if spool_pos[i] is not None:
                            spools[i] = values[spool_pos[i]] * spool_scale[i]
                        if not got_valve[i]:
                            got_valve[i] = True
                            missing -= watched[i]
                answered = time.perf_counter()
                if missing or expected < full:
                    stale = [not g for g in got_force]
                    any_stale = False
                    for i in all_channels:
                        if stale[i]:
                            any_stale = True
                            stale_by_channel[i] += 1
                    if any_stale:
                        stats.stale_cycles += 1
                else:
                    stale = fresh_row
                rs = [math.nan] * n
                new = late_trip or wait_trip
                if new is None and not (bank is not None and stale is fresh_row and unloader is None
                                        and len(watched_idx) == n and bank.quiet(ys, statuses)):
                    for i in watched_idx:
                        new = sups[i].check(ys[i], stale[i], statuses[i], sync_wall,
                                            force=unloader is None)
                        if new is not None:
                            self._named(new, i)
                            break
                if new is None and lockstep and missing:
                    i = next(k for k in all_channels
                             if watched[k] and not (got_force[k] and got_valve[k]))
                    link = masters[i].valve if got_force[i] else masters[i].dynamometer
                    new = self._named(sups[i].make_trip(
                        "no_answer_to_sync", f"{link.role} node {link.id} did not answer SYNC "
                        f"within {self.lockstep_timeout_s:g} s (is the emulator running with "
                        "--lockstep on this bus?)", sync_wall), i)
                    new.bound_s = self.lockstep_timeout_s + T
                if unloader is not None:
                    # -- controlled unload: the supervisors' loop drives, any fault → hold all
                    if new is not None:
                        unload_note = f"unload interrupted after {unloader.t:.2f} s: {new.message}"
                        if new.channel is not None:
                            unload_note += f" (channel {new.channel})"
                        log.warning("%s; hold", unload_note)
                        unloader.outcome = "interrupted"
                        us = self._end(trip, "hold")
                    else:
                        fresh = not any(stale[i] for i in all_channels if unloader.active[i])
                        u_un, rs = unloader.step(ys, fresh)
                        if unloader.done:
                            us = self._end(trip, "hold")
                        else:
                            us = self._send_unload(u_un, unloader.active)
                elif trip is None and new is None:
                    if vector is not None:
                        # -- a rig experiment: every channel's force in, every command out
                        if cycle == 0:
                            vector.begin_rig(ys)
                        if vector.finished_rig(t, ys):
                            break
                        us_req, rs_v = vector.step_rig(t, ys)
                        us_req, rs = [float(u) for u in us_req], [float(r) for r in rs_v]
                        if vector.abort is not None:
                            k = vector.abort_channel
                            reason, message = vector.abort
                            new = self._named(sups[k or 0].make_trip(
                                str(reason), str(message), sync_wall, vector.abort_action), k)
                        else:
                            for i in watched_idx:
                                new = sups[i].check_error(rs[i], ys[i], stale[i], sync_wall)
                                if new is not None:
                                    self._named(new, i)
                                    break
                    else:
                        # -- the experiment drives its channels, the others hold a zero command
                        if cycle == 0:
                            for i, exp in drive_list:
                                exp.begin(ys[i])
                        if one_driver is not None:
                            if one_driver[1].finished(t, ys[one_driver[0]]):
                                break
                        elif all(exp.finished(t, ys[i]) for i, exp in drive_list):
                            break
                        us_req = [0.0] * n
                        for i, exp in drive_list:
                            if one_driver is None and exp.finished(t, ys[i]):
                                continue
                            us_req[i], rs[i] = exp.step(t, ys[i])
                            if exp.abort is not None:
                                reason, message = exp.abort
                                new = self._named(sups[i].make_trip(str(reason), str(message),
                                                                    sync_wall), i)
                                break
                            new = sups[i].check_error(rs[i], ys[i], stale[i], sync_wall)
                            if new is not None:
                                self._named(new, i)
                                break
                    if new is None:
                        us = [0.0] * n
                        # a bus's commands in one batch; in real time sent as soon as they are
                        # shaped (the stand takes the first bus's while the next bus's are
                        # made), in lockstep with the next cycle's SYNC, at once
                        for net, frames, on_bus in zip(networks, out_frames, channels_of_bus):
                            frames.clear()
                            for i in on_bus:
                                v = sups[i].shape_command(us_req[i])
                                if v != shaped[i]:       # (a held command: its counts as before)
                                    shaped[i] = v
                                    shaped_counts[i] = to_counts[i](v)
                                    shaped_pct[i] = to_percent[i](shaped_counts[i])
                                frames.append(masters[i].valve_frame(CW_ACTIVE, shaped_counts[i]))
                                us[i] = shaped_pct[i]
                            if frames and not lockstep:
                                net.send_frames(frames)
                        if lockstep:     # the stand works on the next cycle while this one's row is kept
                            sent_ahead = send_sync(counter, sync_wall, True)
                if trip is None and new is not None:
                    trip = new
                    log.warning("cycle %d (t = %.3f s): %s%s: %s -> %s", cycle, t,
                                f"channel {trip.channel}: " if trip.channel else "", trip.reason,
                                trip.message, trip.action)
                    if on_trip is not None:
                        on_trip(trip)
                    excluded = self._excluded(trip)
                    action = self._rig_action(trip, excluded)
                    active = [i not in excluded for i in all_channels]
                    if action == "unload":       # the excluded: no longer watched nor awaited
                        watched = active
                        watched_idx = [i for i in all_channels if active[i]]
                        expected = 2 * sum(active)
                    if action == "unload" and any(active) and \
                            not any(stale[i] for i in all_channels if active[i]):
                        trip.action = "unload"
                        unloader = RatioUnloader(list(ys), active, [s.limits for s in sups], T,
                                                 [c.name for c in chans], self._coupling())
                        if excluded:
                            self.safe_state("hold", excluded)
                        u_un, rs = unloader.step(ys)
                        us = self._send_unload(u_un, active)
                        trip.safe_wall = time.time()
                    else:
                        final_action = trip.action if trip.action == "zero" else "hold"
                        us = self._end(trip, final_action)
                if recorder is not None:
                    recorder.append_cycle(t, cycle, sync_wall, us, ys, rs, y_counts, spools,
                                          statuses, stale)
                cycle += 1
                stats.cycles = cycle
                if progress is not None:
                    progress(t)
                if trip is not None and (unloader is None or unloader.done or unload_note):
                    break
                if adaptive:
                    work[cycle % WORK_WINDOW] = time.perf_counter() - answered
                    if cycle % WORK_EVERY == WORK_EVERY - 1:
                        high = sorted(work)[WORK_RANK]
                        reserve = min(WORK_RESERVE_MAX * T,
                                      max(WORK_RESERVE_MIN * T, WORK_MARGIN * high + WORK_SLACK_S))
                        stats.answer_window_min_s = min(stats.answer_window_min_s, T - reserve)
                slot += 1
                next_sync = t_start + slot * T
        except BaseException:
            self.safe_state(final_action)
            raise
        self.safe_state(final_action)
        stats.wall_s = time.monotonic() - wall0
        stats.loop_cpu_s = time.thread_time() - cpu0
        if stats.sync_jitter_s:
            stats.max_lateness_s = max(stats.sync_jitter_s)
        stats.shaped_commands = sum(s.clamped for s in sups)
        stats.limit_events = sum(len(s.events) for s in sups)
        after = self._filter_counts()
        stats.unexpected_frames = after.get("unexpected_id", 0) - filter0.get("unexpected_id", 0)
        stats.wrong_dlc_frames = (after.get("wrong_dlc", 0) - filter0.get("wrong_dlc", 0)) + stats.bad_frames
        stats.not_classic_frames = after.get("not_classic", 0) - filter0.get("not_classic", 0)
        rig = {"stale_cycles": {c.name: k for c, k in zip(chans, stale_by_channel)}} if self.rig else None
        if trip is None:
            return LoopOutcome("complete", None, None, stats, rig=rig)
        safety = trip.record()
        message = trip.message
        if trip.channel is not None:
            message = f"channel {trip.channel}: {message}"
        if self.rig:
            safety["rig"] = self._rig_record(trip, excluded, ys, statuses)
        if unloader is not None:
            safety["unload"] = unloader.record(ys, [c.range_kgf for c in chans])
            if unload_note:
                safety["unload"]["note"] = unload_note
                message += f"; {unload_note}"
            elif n == 1:
                message += f"; unloaded ({unloader.outcome}) to {ys[0]:.0f} kgf in {unloader.t:.2f} s, then hold"
            else:
                message += "; " + _unload_text(safety["unload"], unloader, excluded, chans)
        elif self.rig:
            message += f"; every channel held ({final_action})"
        return LoopOutcome("stopped", trip.reason, message, stats, safety, rig=rig)

    # -- the rig's reaction to one channel's trip -------------------------------------------------
    def _excluded(self, trip: Trip) -> list[int]:
        """The channels that cannot unload: the one whose valve or communication failed."""
        if trip.channel is None or trip.reason not in CHANNEL_FAULTS:
            return []
        return [i for i, c in enumerate(self.channels) if c.name == trip.channel]

    def _rig_action(self, trip: Trip, excluded: list[int]) -> str:
        if trip.action in ("unload", "zero"):
            return trip.action
        if self.rig and self.rig_safety.fault_action == "unload" and len(excluded) < len(self.channels) \
                and (trip.reason in CHANNEL_FAULTS or trip.reason == "overrun"):
            return "unload"
        return trip.action

    def _coupling(self):
        G = self.rig_safety.G
        return None if G is None or len(self.channels) < 2 else G

    def _send_unload(self, u_un: list[float], active: list[bool]) -> list[float]:
        """The unload's commands to the unloading channels; the excluded ones are kept in HOLD
        (their valves fed, so none drops out by its RPDO timeout meanwhile). Returns the
        commands as recorded."""
        us = [0.0] * len(u_un)
        for i, a in enumerate(active):
            if a:
                us[i] = self.send_command(P.CW_ACTIVE, u_un[i], i)
            else:
                self.send_command(P.CW_HOLD, 0.0, i)
        return us

    def _rig_record(self, trip: Trip, excluded: list[int], ys: list[float],
                    statuses: list[int]) -> dict:
        chans = self.channels
        out = {"action": trip.action, "acted_on": "every channel",
               "fault_action": self.rig_safety.fault_action,
               "forces_at_end_kgf": {c.name: ys[i] for i, c in enumerate(chans)}}
        if excluded and trip.action == "unload":
            out["excluded"] = [{"channel": chans[i].name, "reason": trip.reason,
                                "last_valve_state": _state_name(statuses[i]),
                                "why": _why_excluded(trip.reason)} for i in excluded]
        return out

    def _end(self, trip: Trip, action: str) -> list[float]:
        """Send the safe command for ``trip`` to every channel (first time only: note when);
        returns the commands as recorded (0 %)."""
        sent = self.safe_state(action)
        if trip.safe_wall is None:
            trip.safe_wall = sent
        return [0.0] * len(self.channels)


def _why_excluded(reason: str) -> str:
    if reason in ("valve_fault", "emcy", "valve_not_active"):
        return ("its valve left ACTIVE for its own safe state (or reported a fault): it is held "
                "(HOLD, zero setpoint) while the others unload")
    return ("it cannot be read or does not answer: it is sent HOLD (zero setpoint) and its valve's "
            "own RPDO watchdog takes it to its safe state if the commands do not reach it; the "
            "others unload")


def _state_name(status: int) -> str:
    state = status & 0xF
    return P.ValveState(state).name if state in P.ValveState._value2member_map_ else f"0x{status:04X}"


def _unload_text(record: dict, unloader: RatioUnloader, excluded: list[int],
                 chans: list[LoopChannel]) -> str:
    n = sum(unloader.active)
    text = (f"unloaded {n} channel(s) keeping the load ratios" if unloader.outcome == "unloaded"
            else f"unload of {n} channel(s) ended ({unloader.outcome})")
    text += f" in {unloader.t:.2f} s"
    big = record.get("largest_deviation")
    if big:
        text += (f", largest deviation from the ratios {big['kgf']:.1f} kgf "
                 f"({big['pct_of_range']:.2f} % of its range) on {big['channel']} at "
                 f"{big['at_s']:.2f} s")
    if excluded:
        text += f"; {', '.join(chans[i].name for i in excluded)} excluded (held)"
    return text + ", then hold"


def sync_window_s(period_s: float, lockstep: bool) -> float:
    """The synchronous window the nodes are given (0x1007, CiA 301), s: in real time an answer
    sent later than this after its SYNC would be stamped within :data:`STAMP_SKEW_S` of the
    next SYNC, or after it, and pass for that SYNC's answer, so the node discards it (the
    cycle is stale, counted, instead of every reading one period old); at least half the
    period. In lockstep none (0): the stand's time is not the wall clock's."""
    return 0.0 if lockstep else max(period_s - STAMP_SKEW_S, period_s / 2)


def takes_buses_over(lockstep: bool, rig: bool) -> bool:
    """Whether the loop takes its buses from their reader threads for a run and receives on
    its own thread (:meth:`ControlLoop._handover`): in lockstep, and in real time on a rig; a
    one-channel stand in real time keeps its reader thread."""
    return lockstep or rig


@contextlib.contextmanager
def steady_heap():
    """Freeze everything alive for the run, so the garbage collector only ever scans what the
    run itself allocates. A full collection of a large heap (a notebook, a long test session)
    otherwise stalls the loop for tens to hundreds of ms: measured 60 ms with 100,000 objects,
    longer than the valve's 100 ms RPDO timeout in bigger sessions. Only the young generations
    are collected first: a full collection here cost 58 ms per run of a campaign, and old
    garbage frozen with the rest is freed by the first full collection after the run."""
    gc.collect(1)
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def _captures_writer(networks):
    """``idle()`` for the lockstep loop's polls: write one queued item of the networks'
    captures (:meth:`gateway.capture.BusCapture.write_one`, the next capture each time);
    whether one was written. None without captures."""
    captures = [c for c in (getattr(net, "capture", None) for net in networks) if c is not None]
    if not captures:
        return None
    turn = itertools.cycle(captures)
    count = len(captures)

    def idle() -> bool:
        for _ in range(count):
            if next(turn).write_one():
                return True
        return False
    return idle


def _sleep_until(target: float, pump=None) -> None:
    """Sleep to ~0.3 ms before ``target`` (perf_counter time), then spin: sub-0.1 ms accuracy
    without burning a core for the whole period. With the buses taken over, the sleep is
    ``pump`` receiving what arrives meanwhile."""
    if pump is not None:
        while True:
            remaining = target - time.perf_counter() - _SPIN_S
            if remaining <= 0:
                break
            pump(remaining)
    while True:
        remaining = target - time.perf_counter()
        if remaining <= 0:
            return
        if remaining > _SPIN_S:
            time.sleep(remaining - _SPIN_S)


_INT32_MAX = 2**31 - 1


def _real_counts(value: float, per_unit: float) -> int:
    """A REAL32 process value as the run's ``y_counts``: in its unit's last digit, rounded and
    clipped to INT32 (NaN or infinite: 0)."""
    if not math.isfinite(value):
        return 0
    return int(max(-_INT32_MAX, min(_INT32_MAX, round(value * per_unit))))
