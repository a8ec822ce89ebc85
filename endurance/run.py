r"""The running endurance test: ``stand test start|resume|stop``.

A **session** is one gateway run (a start or a resume, until a stop, the target, an inspection
or a kill) that flies the flight sequence back to back (:class:`endurance.flights.FlightPlayer`)::

    control loop (its own thread)        FlightPlayer: flights handed over without approach
        │ load cases, flights done, the start of loading (queue puts only)
        ▼
    journal writer thread                commit_load_case (one SQLite transaction each, fsync),
        │                                begin_flight, finish_flight with what the flight
        │                                learnt, events, the turning-point log; polls the stop file
    planner thread                       the next flight's piece (LoadProgramme) prepared ahead;
                                         each flight's tracking report, its type's compensation
                                         learning from it

The loop never waits on the disk: a load case is handed to the writer as it is judged. What a
``kill -9`` loses is the load case in progress and one whose commit was under way (queued or in
its transaction; in practice at most one: a commit takes a few ms, load cases are 0.1 s and more
apart); the count is never wrong (the journal counts a flight in the same transaction as its
last load case).

**Compensation per flight type.** After each flight run whole, its tracking report
(:func:`loading.report.tracking_report` on that flight's stretch) teaches its type's
compensation (:class:`loading.compensation.Compensation`), stored with the flight
(``Journal.finish_flight``); a flight's piece is prepared while the flight before it flies, so
what a flight learnt is used from the next flight of its type prepared after it (normally one
flight later). A resumed session takes every type's compensation from the journal.

**Time scaling per flight type** (``[time_scaling]``, a type's ``schedule``): each piece is
made with its type's current segment durations (:class:`endurance.timing.FlightTiming`), and
after each flight run whole the type's search takes its step from the same tracking report;
the schedule is stored with the flight like the compensation, so a resumed session goes on
with each type's own.

**The monitors** (:mod:`endurance.monitors`): the gain monitor runs in the loop within every
flight's pass; after each flight the planner thread feeds the end-point trend, and the
monitors' step is stored with the flight. An alarm notes, or stops the test at once
(``monitor_alarm``; the gain monitor's own: ``gain_alarm``), holding or unloading, its event
naming the channels.

**Stop.** ``stand test stop TESTDIR`` writes ``TESTDIR/stop.json``, which the writer thread
polls (:data:`STOP_POLL_S`): by default the test stops at the end of the flight in progress and
the valves hold at the ground level; ``--at-once`` unloads every channel keeping the load ratios
(the loop's unload, :mod:`gateway.unload`). An inspection (``[[inspection]] at_flight``) is the
same stop once its flight is done. The journal's state is then ``stopped`` with the reason.

**Resume.** The journal's position (flight, attempt, next load case) says where: the test file
is read again and refused if its fingerprint changed (naming what); the valves' latched faults
(a killed gateway leaves them to their own RPDO watchdog: FAULT_HOLD) are reset; the forces are
brought from where they are found along the ratio-keeping line (one channel: the one-way
set-point approach) to the levels of the load case before the interrupted one, and the flight
goes on from there (that segment is run again: the structure sees the interrupted load case's
whole swing), with the compensation its type has; the interrupted flight is completed, counted
once. The time from the resume to loading again is an event (``loading``) and in the
session's record (``TESTDIR/sessions/NNNN.json``: begun with ``state`` running when the session
loads, completed at its end; a session killed after loading leaves it so, with where it found
the stand, and none before).

**The live view.** A session takes a ``publisher`` (:class:`endurance.live.feed.LiveFeed`:
the command line always gives one): the control loop hands it every cycle's forces, references
and commands (it keeps a decimated copy in a ring buffer, never waiting), and a trip is an
``interlock`` event in the journal at its moment (the loop's ``trip`` hook, a queue put).
Events from outside the session (the live page's operator actions and refusals) come through
``TESTDIR/inbox/`` (:mod:`endurance.inbox`), taken in by the writer thread as it polls the stop
file.

**Storage.** Full-rate signals go to the rolling window (:class:`endurance.storage.SignalWindow`,
with ±``event_window_s`` kept around each stop, resume and trip as a run directory); the
turning-point log is exported from the journal every :data:`EXPORT_EVERY` flights and at the end
of each session. No run directory per flight, no bus capture.
"""
from __future__ import annotations

import collections
import copy
import hashlib
import json
import math
import queue
import threading
import time
import tomllib
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from core.durable import write_json
from core.errors import ParameterError, StandError
from gateway.limits import programme_error_limit_kgf
from gateway.load_experiment import LoadProgramme
from loading.compensation import ChannelCompensation, Compensation
from loading.report import tracking_report

from .flights import (OPERATOR_STOP, FlightPiece, FlightPlayer, FlightRecord, StopRequest, filled_forces,
                      first_ways, glide_in, lead_in_of)
from .inbox import take_in
from .journal import EndPoint, Journal, JournalError, MonitorStep, lock_holder
from .monitors import MONITOR_ALARM, FlightEnd, GainWatch, MonitorAlarm, TrendWatch, after_inspection
from .storage import EXPORT_EVERY, SignalWindow, TurningPointLog
from .spectrum import FlightSequence
from .testfile import EnduranceTest, Fingerprint, load_test_file
from .timing import FlightTiming

STOP_FILE = "stop.json"
TEST_RECORD = "test.json"
SESSIONS_DIR = "sessions"
#: how often the writer thread looks for a stop file, s
STOP_POLL_S = 0.2
#: prepared flights kept for a flight type that comes again with the same programme
PIECE_CACHE = 8


# -- what the session reports --------------------------------------------------------------------
@dataclass
class SessionResult:
    """How a session ended (also ``TESTDIR/sessions/NNNN.json``)."""

    testdir: Path
    kind: str                            #: start | resume
    state: str                           #: the journal's after it
    reason: str | None
    flights_done: int
    flights_target: int
    first_flight: int
    status: str | None = None            #: the gateway run's: complete | stopped | aborted
    end_reason: str | None = None
    end_message: str | None = None
    loading: dict | None = None          #: the start of loading (times, approach deviation)
    unload: dict | None = None           #: an unload's record (largest deviation from the ratios)
    flights_flown: int = 0
    waited_for_pieces_s: float = 0.0
    path: Path | None = None
    inspection: str | None = None        #: what the operator said the inspection found

    def to_dict(self) -> dict:
        d = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(self).items()}
        return d

    def text(self) -> str:
        lines = [f"{self.kind}: {self.flights_flown} flight(s) flown; {self.flights_done} of "
                 f"{self.flights_target} done; the test is {self.state}"
                 + (f" ({self.reason})" if self.reason else "")]
        if self.inspection:
            lines.insert(0, f"the trend: {self.inspection}")
        if self.loading:
            lines.append(loading_text(self.loading))
        if self.unload and self.unload.get("largest_deviation"):
            lines.append(unload_text(self.unload))
        return "\n".join(lines)


def loading_text(info: dict) -> str:
    """The ``loading`` event's message: how long from the start or resume to loading again."""
    text = (f"loading again {info['to_loading_s']:.2f} s after the {info['kind']} (reading and checking "
            f"{info['check_s']:.2f} s, gateway {info['gateway_s']:.2f} s, settling and preparing the first "
            f"flight {info['prepare_s']:.2f} s, glide-in {info['glide_s']:.2f} s) into flight {info['flight']}'s "
            f"load case {info['load_case']}")
    dev = info.get("approach_deviation")
    if dev:
        text += (f"; the glide's largest deviation from its ratio line {dev['pct_of_range']:.2f} % of "
                 f"a range ({dev['channel']}, {dev['kgf']:.0f} kgf)")
    return text


def unload_text(unload: dict) -> str:
    big = unload["largest_deviation"]
    return (f"unloaded keeping the ratios ({unload.get('outcome')}), largest deviation "
            f"{big['kgf']:.1f} kgf ({big['pct_of_range']:.2f} % of its range) on {big['channel']}")


# -- compensation per flight type -----------------------------------------------------------------
def load_compensations(journal: Journal, test: EnduranceTest) -> dict[str, Compensation]:
    """Every flight type's compensation as the journal holds it (empty for a type not flown)."""
    names = test.station.names
    out = {}
    for t in test.flight_types:
        comp = Compensation(list(names))
        for channel, text in journal.compensation(t).items():
            where = f"{journal.path}: flight type {t}, channel {channel}"
            try:
                data = tomllib.loads(text)
            except tomllib.TOMLDecodeError as exc:
                raise JournalError(f"{where}: not a compensation table ({exc})") from None
            comp.channels[channel] = ChannelCompensation.from_mapping(data, where)
        out[t] = comp
    return out


def compensation_tables(comp: Compensation) -> dict[str, str]:
    return {n: comp.channels[n].to_toml() for n in comp.names}


# -- the planner: pieces ahead, learning after ---------------------------------------------------------
class Planner:
    """Prepares each flight's piece while the flight before it flies, and learns from each flight
    done: its type's compensation and timing from the flights run whole, the end-point trend
    (one thread, in the order asked). ``gain``: the gain monitor every piece shares."""

    def __init__(self, test: EnduranceTest, compensations: dict[str, Compensation], flights: int,
                 timing: FlightTiming, trend: TrendWatch | None = None, gain=None) -> None:
        self.test = test
        self.controller = test.controller
        self.sequence = FlightSequence(test.block, flights)
        self.compensations = compensations
        self.timing = timing
        self.trend = trend
        self.gain = gain
        self.T = test.station.period_s
        self.writer: "JournalWriter | None" = None
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="flight-planner")
        self.futures: dict[int, Future] = {}
        self.prepared: dict[int, FlightPiece] = {}
        self.cache: collections.OrderedDict[str, LoadProgramme] = collections.OrderedDict()
        self.built = self.reused = 0

    def commanded(self, flight_type: str):
        """A flight type's programme with its timing (the nominal: what its end points are
        judged against) and with its corrections (what is run)."""
        nominal = self.timing.programme(flight_type)
        return nominal, self.compensations[flight_type].commanded(nominal)

    def _ran_with(self, flight_type: str) -> Compensation:
        """A copy of the flight type's compensation as a piece is prepared: what the flight runs
        with, which its learning starts from (the flight ahead may teach its type meanwhile)."""
        return copy.deepcopy(self.compensations[flight_type])

    def start(self, number: int, load_case: int, begun: bool, y0: np.ndarray) -> None:
        self.futures[number] = self.pool.submit(self._first, number, load_case, begun, np.array(y0, float))

    def _first(self, number: int, load_case: int, begun: bool, y0: np.ndarray) -> FlightPiece:
        """The session's first piece: flight ``number`` from load case ``load_case`` (0-based)
        on, gliding in from the forces ``y0`` to the load case before it (module docstring)."""
        slot = self.sequence.slot(number)
        start = max(load_case - 1, 0)
        final = self.timing.final(slot.flight_type)
        nominal, commanded = self.commanded(slot.flight_type)
        if start:
            commanded = commanded.from_case(start)
        delay = max(int(round(m.tau / self.T)) for m in self.controller.model.channels)
        lead_in = glide_in(y0, commanded.r_kgf[:, 0], self.T, delay)
        experiment = LoadProgramme(commanded, self.controller, lead_in=lead_in, unload=False, monitor=self.gain)
        piece = FlightPiece(slot, nominal, start, experiment, begun=begun, commit_from=load_case,
                            start_ways=first_ways(experiment), timing_final=final,
                            compensation=self._ran_with(slot.flight_type))
        self.prepared[number] = piece
        return piece

    # -- Pieces: the player's side ----------------------------------------------------------------
    def request(self, number: int) -> None:
        if number in self.futures or number in self.prepared or number > self.sequence.flights:
            return
        self.futures[number] = self.pool.submit(self._prepare, number)

    def ready(self, number: int) -> bool:
        f = self.futures.get(number)
        return f is not None and f.done()

    def get(self, number: int) -> FlightPiece:
        self.request(number)
        piece = self.futures.pop(number).result()
        for n in [n for n in self.prepared if n < number - 1]:
            del self.prepared[n]
        return piece

    def _prepare(self, number: int) -> FlightPiece:
        previous = self.prepared[number - 1].experiment
        lead = lead_in_of(previous)
        lead_in = previous.reference[:, -lead:]
        slot = self.sequence.slot(number)
        final = self.timing.final(slot.flight_type)
        nominal, commanded = self.commanded(slot.flight_type)
        key = hashlib.sha1(np.ascontiguousarray(lead_in).tobytes() + commanded.r_kgf.tobytes()
                           + slot.flight_type.encode()).hexdigest()
        cached = self.cache.get(key)
        if cached is not None:
            self.cache.move_to_end(key)
            experiment = cached.fresh()
            self.reused += 1
        else:
            experiment = LoadProgramme(commanded, self.controller, lead_in=lead_in, unload=False,
                                       monitor=self.gain)
            self.cache[key] = experiment
            while len(self.cache) > PIECE_CACHE:
                self.cache.popitem(last=False)
            experiment = experiment.fresh()
            self.built += 1
        piece = FlightPiece(slot, nominal, 0, experiment, timing_final=final,
                            compensation=self._ran_with(slot.flight_type))
        self.prepared[number] = piece
        return piece

    # -- learning ----------------------------------------------------------------------------------
    def learn(self, record: FlightRecord, step: MonitorStep | None = None) -> None:
        """Learn from the flight done ``record`` (its type's compensation and timing when it was
        run whole; the trend), then hand it to the writer with what was learnt and ``step``
        (the gain monitor's, taken at its end)."""
        self.pool.submit(self._learn, record, step or MonitorStep())

    def _learn(self, record: FlightRecord, step: MonitorStep) -> None:
        tables = schedule = report = None
        notes, alarms = [], []
        piece = record.piece
        if record.whole:
            try:
                nominal = piece.nominal
                t = (np.arange(record.Y.shape[1]) - piece.experiment.lead) * self.T
                Y = filled_forces(record.Y)
                report = tracking_report(nominal, t, Y)
                comp = self.compensations[piece.slot.flight_type]
                comp.learn(report.channels, nominal.ranges_kgf, ran=piece.compensation)
                tables = compensation_tables(comp)
                schedule = self.timing.learn(piece.slot.flight_type, nominal, report, t, Y,
                                             landing_error_pct(record))
            except Exception as exc:            # the flight is counted all the same
                notes.append(f"flight {record.number}: it taught its type nothing ({type(exc).__name__}: {exc})")
        if self.trend is not None:
            try:
                trend_step, alarm = self.trend.flight(record, piece.timing_final)
                step.extend(trend_step)
                alarms += [alarm] if alarm else []
            except Exception as exc:
                notes.append(f"flight {record.number}: the trend did not take it ({type(exc).__name__}: {exc})")
        self.writer.finish(record, tables, schedule, report, step, alarms, notes)

    def close(self) -> None:
        """Stop preparing; finish every learning asked."""
        for f in self.futures.values():
            f.cancel()
        self.pool.shutdown(wait=True)


# -- the journal writer: the player's sink ------------------------------------------------------------
class JournalWriter:
    """Everything the journal records, on its own thread, in the order it was handed over
    (module docstring); also polls the stop file."""

    def __init__(self, journal: Journal, testdir: Path, stop: StopRequest, planner: Planner,
                 window: SignalWindow, log: TurningPointLog, kind: str, started_at: float,
                 checked_at: float, on_flight: Callable[[FlightEnd, str], None] | None = None,
                 hook: Callable[[FlightEnd], MonitorAlarm | None] | None = None,
                 gain: GainWatch | None = None) -> None:
        self.journal = journal
        self.testdir = testdir
        self.stop = stop
        self.planner = planner
        self.window = window
        self.log = log
        self.kind, self.started_at, self.checked_at = kind, started_at, checked_at
        self.on_flight, self.hook = on_flight, hook
        self.gain = gain
        self.ranges = None
        self.error: BaseException | None = None
        self.loading_info: dict | None = None
        self.record_path: Path | None = None           #: the session's record, once it loads
        self.flights_flown = 0
        self._since_export = 0
        self._stop_seen = False
        self._next_poll = 0.0
        self.q: queue.SimpleQueue = queue.SimpleQueue()
        self.thread = threading.Thread(target=self._work, name="journal-writer", daemon=True)
        self.thread.start()

    # -- the player's calls (the control loop's thread: queue puts only) ---------------------------------
    def begin_flight(self, record: FlightRecord) -> None:
        self.q.put((self._begin, (record.piece.slot, record.cases)))

    def load_case(self, record: FlightRecord, index: int, end_points: list[EndPoint]) -> None:
        self.q.put((self.journal.commit_load_case, (record.number, index, end_points)))

    def flight_done(self, record: FlightRecord) -> None:
        step = self.gain.step(record.number)[0] if self.gain is not None else None
        self.planner.learn(record, step)

    def loading(self, info: dict) -> None:
        self.q.put((self._loading, (info,)))

    # -- the planner's ---------------------------------------------------------------------------------
    def finish(self, record: FlightRecord, tables: dict | None, schedule: str | None, report,
               step: MonitorStep, alarms: list[MonitorAlarm], notes: list[str]) -> None:
        self.q.put((self._finish, (record, tables, schedule, report, step, alarms, notes)))

    # -- the session's ---------------------------------------------------------------------------------
    def event(self, kind: str, message: str, **where) -> None:
        self.q.put((self.journal.add_event, (kind, message), where))

    def close(self) -> None:
        """Record everything handed over, then stop the thread."""
        self.q.put(None)
        self.thread.join()

    # -- the thread ------------------------------------------------------------------------------------
    def _work(self) -> None:
        while True:
            try:
                item = self.q.get(timeout=STOP_POLL_S)
            except queue.Empty:
                self._poll_stop()
                continue
            if item is None:
                return
            fn, args, *kw = item
            if self.error is None:
                try:
                    fn(*args, **(kw[0] if kw else {}))
                except Exception as exc:
                    self._fail(exc)
            self._poll_stop()

    def _fail(self, exc: BaseException) -> None:
        """The journal cannot record: stop at once, every valve holding (nothing more can be
        counted)."""
        self.error = exc
        self.stop.stop_at_once("journal_error", f"the journal cannot record the test ({exc}); every "
                               "valve holds", "hold")

    def _begin(self, slot, cases: int) -> None:
        self.journal.begin_flight(slot.number, slot.flight_type, slot.block, slot.position, cases)

    def _finish(self, record: FlightRecord, tables, schedule, report, step: MonitorStep,
                alarms: list[MonitorAlarm], notes: list[str]) -> None:
        step.events += [("learning", None, note) for note in notes]
        self.journal.finish_flight(record.number, compensation=tables, schedule=schedule, monitors=step)
        self.flights_flown += 1
        end = FlightEnd(record.number, record.piece.slot.flight_type, dict(record.end_points), report)
        if self.on_flight is not None:
            self.on_flight(end, flight_line(end, record.piece.nominal))
        if self.hook is not None:
            alarm = self.hook(end)
            if alarm is not None:
                self.journal.add_event(alarm.kind, alarm.message, alarm.channel, record.number)
                alarms = alarms + [alarm]
        for alarm in alarms:
            self.act(alarm)

    def act(self, alarm: MonitorAlarm) -> None:
        """An alarm's action: a hold or an unload stops the test at once (a note is its event)."""
        if alarm.action in ("hold", "unload"):
            self.stop.stop_at_once(MONITOR_ALARM, alarm.message, alarm.action)
        self._since_export += 1
        if self._since_export >= EXPORT_EVERY:
            self.log.export(self.journal)
            self._since_export = 0

    def _loading(self, info: dict) -> None:
        info = dict(info, kind=self.kind, check_s=self.checked_at - self.started_at,
                    gateway_s=info["began_at"] - self.checked_at,
                    prepare_s=info["main_at"] - info["began_at"],
                    glide_s=info["loading_at"] - info["main_at"],
                    to_loading_s=info["loading_at"] - self.started_at)
        self.loading_info = info
        message = loading_text(info)
        self.journal.add_event("loading", message, flight=info["flight"], load_case=info["load_case"])
        # the session's record, begun now and completed at its end: a session killed later
        # still says where it found the stand (what the stop before it left)
        self.record_path = session_record_path(self.testdir)
        write_json(self.record_path, {"kind": self.kind, "state": "running", "first_flight": info["flight"],
                                      "started_at": self.started_at, "loading": info})
        if self.window.last_time_s is not None:        # its event window: the approach before it
            self.window.mark_event(self.kind, message, flight=info["flight"])

    def _poll_stop(self) -> None:
        now = time.monotonic()
        if now < self._next_poll:
            return
        self._next_poll = now + STOP_POLL_S
        try:                                            # events from outside (endurance.inbox)
            take_in(self.testdir, self.journal)
        except (JournalError, OSError):                 # they wait there; the load cases' own
            pass                                        # commits stop the test if it cannot write
        if self._stop_seen:
            return
        request = read_stop_file(self.testdir)
        if request is None:
            return
        self._stop_seen = True
        if request.get("at_once"):
            self.stop.stop_at_once(OPERATOR_STOP, "stopped at once by the operator (stand test stop --at-once)")
            what = "at once: every channel unloads keeping the load ratios"
        else:
            self.stop.after_flight = True
            what = "at the end of the flight in progress, then the valves hold"
        self.journal.add_event("stop_requested", f"the operator asked the test to stop {what}")


def landing_error_pct(record: FlightRecord) -> float:
    """The worst channel's error at the flight's last load case (its ground level), % of the
    channel's range in the flight."""
    nominal = record.piece.nominal
    ranges = np.maximum(nominal.ranges_kgf, 1e-9)
    points = record.end_points.get(record.cases - 1, [])
    return max((100 * abs(p.reached_kgf - p.level_kgf) / ranges[i] for i, p in enumerate(points)), default=np.nan)


def flight_line(end: FlightEnd, nominal) -> str:
    """One line per flight: its number, type and its worst peak or valley (% of its range)."""
    worst, where = 0.0, ""
    kinds = nominal.kinds()
    ranges = np.maximum(nominal.ranges_kgf, 1e-9)
    names = list(nominal.names)
    for j, points in end.end_points.items():
        for p in points:
            i = names.index(p.channel)
            if kinds[i][j] in ("peak", "valley"):
                e = 100 * abs(p.reached_kgf - p.level_kgf) / ranges[i]
                if e > worst:
                    worst, where = e, f" ({p.channel}, load case {j + 1})"
    return f"flight {end.number} ({end.flight_type}): worst peak/valley {worst:.2f} % of its range{where}"


# -- the rolling window as the gateway's recorder -------------------------------------------------------
class SessionRecorder:
    """The gateway run's recorder (``Gateway.run(recorder=...)``): every cycle to the rolling
    window (and to the ``publisher``'s ``cycle(sync_time, forces, references, commands)``, which
    must not block); a trip's (or a stop's) moment marked for an event window, and a trip the
    session did not ask for handed to ``on_trip`` as it happens."""

    def __init__(self, window: SignalWindow, testdir: Path, flight: Callable[[], int],
                 publisher=None, on_trip: Callable[[Any], None] | None = None) -> None:
        self.window = window
        self.dir = testdir
        self.append_cycle = window.append_cycle if publisher is None else \
            _published(window.append_cycle, publisher.cycle)
        self.flight = flight
        self.on_trip = on_trip
        self.meta: dict[str, Any] = {}

    def trip(self, trip) -> None:
        """The loop's hook: a supervisor tripped (:class:`gateway.supervisor.Trip`), in the
        loop's thread."""
        if self.on_trip is not None:
            self.on_trip(trip)

    def poll(self) -> None:
        self.window.poll()

    def close(self, **meta: Any) -> Path:
        self.meta = meta
        safety = meta.get("safety")
        if safety and self.window.last_time_s is not None:
            onset = safety.get("onset")
            acted = safety.get("safe_state") or safety.get("detected")
            self.window.mark_event(str(meta.get("end_reason") or "stop"), str(meta.get("end_message") or ""),
                                   onset if onset and math.isfinite(onset) else None,
                                   safety.get("channel"), self.flight(),
                                   acted if acted and math.isfinite(acted) else None)
        return self.dir


def _published(append: Callable, publish: Callable) -> Callable:
    def append_cycle(t, cycle, sync_time, u, y, r, *rest) -> None:
        append(t, cycle, sync_time, u, y, r, *rest)
        publish(sync_time, y, r, u)
    return append_cycle


# -- the files of the test directory ---------------------------------------------------------------------
def read_stop_file(testdir: Path) -> dict | None:
    try:
        return json.loads((Path(testdir) / STOP_FILE).read_text())
    except (OSError, ValueError):
        return None


def session_record_path(testdir: Path) -> Path:
    """The next session's record, ``TESTDIR/sessions/NNNN.json`` (numbered on)."""
    sessions = testdir / SESSIONS_DIR
    sessions.mkdir(exist_ok=True)
    return sessions / f"{len(list(sessions.glob('*.json'))) + 1:04d}.json"


def request_stop(testdir: str | Path, at_once: bool = False) -> dict:
    """Ask the session running ``testdir`` to stop (module docstring); returns its holder
    ({pid, host, since}). Refused when no session runs it."""
    testdir = Path(testdir)
    with Journal.open(testdir) as journal:
        state = journal.state()
    holder = lock_holder(testdir)
    if holder is None or state != "running":
        raise StandError(f"{testdir}: no session runs the test (it is {state}); nothing to stop")
    write_json(testdir / STOP_FILE, {"at_once": bool(at_once), "requested": time.time()})
    return holder


def test_file_of(testdir: Path) -> Path:
    """The test file a test was started from (``TESTDIR/test.json``)."""
    try:
        return Path(json.loads((testdir / TEST_RECORD).read_text())["test_file"])
    except (OSError, ValueError, KeyError):
        raise StandError(f"{testdir}: no record of its test file ({TEST_RECORD}); give the test "
                         "file with --test FILE") from None


# -- sessions -------------------------------------------------------------------------------------------
def start(test_file: "str | Path | EnduranceTest", testdir: str | Path, config, flights: int | None = None,
          progress: bool | None = False, on_flight=None, hook=None,
          started_at: float | None = None, publisher=None, gateway_args: list[str] | None = None) -> SessionResult:
    """A new test in ``testdir`` (refused if it holds one) from ``test_file``, then its first
    session on the gateway of ``config`` (:class:`gateway.config.GatewayConfig` for the test's
    station: :func:`station_config`). ``flights``: the target instead of the file's.
    ``publisher``: the live view's (module docstring). ``gateway_args``: the command line's
    gateway options, kept in ``TESTDIR/test.json`` for a resume from the live page."""
    started_at = time.time() if started_at is None else started_at
    test = _read(test_file)
    config = station_config(test, config)
    check_test(test, config)
    testdir = Path(testdir)
    target = test.flights if flights is None else flights
    fp = test.fingerprint()
    journal = Journal.create(testdir, test.name, target, test.station.names, fp.digest, fp.to_json(),
                             test.path.read_text())
    write_json(testdir / TEST_RECORD, {"test_file": str(test.path.resolve()),
                                       "gateway_args": list(gateway_args or [])})
    return run_session(test, testdir, journal, "start", started_at, gateway_drive(test, config, progress),
                       on_flight, hook, config.lockstep, config.limits.command_limit_pct, publisher)


def resume(testdir: str | Path, config, test_file: "str | Path | EnduranceTest | None" = None,
           flights: int | None = None,
           progress: bool | None = False, on_flight=None, hook=None,
           started_at: float | None = None, publisher=None, found: str | None = None) -> SessionResult:
    """The session that takes the test in ``testdir`` up again (module docstring). ``found``:
    what the inspection after the trend's alarm found (:func:`run_session`)."""
    started_at = time.time() if started_at is None else started_at
    testdir = Path(testdir)
    with Journal.open(testdir) as peek:
        before = Fingerprint.from_json(peek.fingerprint_json)
    test = _read(test_file if test_file is not None else test_file_of(testdir))
    changes = test.fingerprint().changes(before)
    if changes:
        raise ParameterError(f"{testdir}: the test changed since it was started, so resuming it would be "
                             f"another test: {'; '.join(changes)}. Undo the change, or start a new test "
                             "in another directory")
    config = station_config(test, config)
    check_test(test, config)
    journal = Journal.open(testdir, write=True)
    try:
        if flights is not None:
            journal.set_target(flights)
        if journal.state() == "finished":
            raise JournalError(f"{testdir}: the test is finished ({journal.flights_done} flights); "
                               "resume --flights N raises its target")
    except BaseException:
        journal.close()
        raise
    return run_session(test, testdir, journal, "resume", started_at, gateway_drive(test, config, progress),
                       on_flight, hook, config.lockstep, config.limits.command_limit_pct, publisher, found)


def _read(test_file: "str | Path | EnduranceTest") -> EnduranceTest:
    return test_file if isinstance(test_file, EnduranceTest) else load_test_file(test_file)


def station_config(test: EnduranceTest, config):
    """``config`` for the test's station: a rig's file (its buses, channels and period), or a
    stand's force limit and period from the test file."""
    st = test.station
    if st.kind == "rig":
        config = replace(config, rig=st.rig)
    else:
        config = replace(config, rig=None, limits=replace(config.limits, force_limit_kgf=st.force_limits_kgf[0]))
    if abs(config.period_s - st.period_s) > 1e-9:
        config = replace(config, period_s=st.period_s)
    config.validate()
    return config


def check_test(test: EnduranceTest, config) -> None:
    """Everything refused before anything moves: every flight type's programme against the
    station's force limits and its feedforward against the command limit (naming the type)."""
    limits = test.station.force_limits_kgf
    for name, ft in test.flight_types.items():
        try:
            LoadProgramme(ft.programme, test.controller, unload=False).check(
                config.period_s, limits, config.limits.command_limit_pct)
        except ParameterError as exc:
            raise ParameterError(f"{test.path}: [flight.{name}]: {exc}") from None


def _last_flight(test: EnduranceTest, journal: Journal, first: int) -> tuple[int, Any]:
    """The flight after which this session ends: the target, or an inspection before it."""
    target = journal.flights_target
    due = [i for i in test.inspections if first <= i.at_flight < target]
    return (due[0].at_flight, due[0]) if due else (target, None)


#: how a session's player is run: ``drive(player, recorder, window)`` runs it to its end and
#: returns the loop's outcome (the gateway's: :func:`gateway_drive`; offline in the tests)
Drive = Callable[[FlightPlayer, "SessionRecorder", SignalWindow], Any]


def gateway_drive(test: EnduranceTest, config, progress: bool | None = False) -> Drive:
    """Run the player through the gateway of ``config``: one run, the rolling window its
    recorder, the valves' latched faults reset first, every channel's tracking-error limit
    set for the flights (:func:`_error_limits`)."""
    def drive(player: FlightPlayer, recorder: SessionRecorder, window: SignalWindow):
        from gateway import Gateway
        rig = test.station.kind == "rig"
        with Gateway(config) as gw:
            window.meta = gw.metadata(player, test.station.names if rig else [])
            restore = _error_limits(gw, test)
            try:
                return gw.run(player, None, progress=progress, recorder=recorder, reset_faults=True).outcome
            finally:
                restore()
    return drive


def run_session(test: EnduranceTest, testdir: Path, journal: Journal, kind: str, started_at: float,
                drive: Drive, on_flight=None, hook=None, lockstep: bool = True,
                command_limit_pct: float = 100.0, publisher=None, found: str | None = None) -> SessionResult:
    """One session: the flights from the journal's position on, back to back, until a stop,
    the target, an inspection or a fault (module docstring). ``journal`` is open for writing
    (the test's lock held) and is closed here. ``lockstep``: the stand waits for the loop (the
    first cycle may wait for the first flight's piece; in real time the valves hold meanwhile).
    ``command_limit_pct``: the valves' (time scaling's minimum counts on it). ``publisher``: the
    live view's, opened with ``open(testdir, channels, period_s)`` before the run and closed after
    it. ``found``: a resume's answer after the trend's alarm (:func:`endurance.monitors.after_inspection`:
    ``inspected`` or ``repaired``; a test the alarm stopped is not resumed without it)."""
    try:
        answer = after_inspection(test, journal, found) if kind == "resume" else None
        (testdir / STOP_FILE).unlink(missing_ok=True)
        names = test.station.names
        rig = test.station.kind == "rig"
        pos = journal.position()
        compensations = load_compensations(journal, test)
        timing = FlightTiming(test, {t: journal.schedule(t) for t in test.flight_types}, command_limit_pct)
        trend = TrendWatch.for_session(test, journal)
        gain = GainWatch.for_session(test, journal)
        planner = Planner(test, compensations, journal.flights_target, timing, trend,
                          gain.monitor if gain is not None else None)
        last, inspection = _last_flight(test, journal, pos.flight)
        stop = StopRequest()
        window = SignalWindow(testdir, names if rig else None, test.station.period_s,
                              test.storage.rolling_window_s, test.storage.event_window_s, test.storage.chunk_s)
        log = TurningPointLog(testdir, test.block.size)
    except BaseException:
        journal.close()
        raise
    writer = JournalWriter(journal, testdir, stop, planner, window, log, kind, started_at, time.time(),
                           on_flight, hook, gain)
    planner.writer = writer
    player = FlightPlayer(names, pos.flight, pos.load_case, pos.attempt is not None, planner, writer, last,
                          stop, test.station.period_s, test.controller.command_limit_pct, wait_first=lockstep)
    recorder = SessionRecorder(window, testdir, lambda: player.number, publisher,
                               _interlock_event(writer, stop, lambda: player.number))
    result = SessionResult(testdir, kind, "running", None, journal.flights_done, journal.flights_target, pos.flight,
                           inspection=answer)
    outcome = None
    failure: BaseException | None = None
    try:
        journal.start()
        if publisher is not None:
            publisher.open(testdir, list(names), test.station.period_s)
        outcome = drive(player, recorder, window)
    except BaseException as exc:
        failure = exc
        raise
    finally:
        if publisher is not None:
            publisher.close()
        planner.close()
        writer.close()
        try:
            window.close()
        except StandError:
            pass
        _end_session(result, journal, log, player, stop, writer, recorder, outcome, failure, inspection, last)
        journal.close()
        (testdir / STOP_FILE).unlink(missing_ok=True)
    return result


def _interlock_event(writer: JournalWriter, stop: StopRequest, flight: Callable[[], int]) -> Callable:
    """The recorder's ``on_trip``: a trip the session did not ask for (not a stop, a monitor's
    alarm or a journal error: those have their events) is an ``interlock`` event at its onset.
    The gain monitor's alarm trips the loop itself; its event is the monitor's (``gain_alarm``,
    :class:`endurance.monitors.GainWatch`)."""
    from loading.gain_monitor import GAIN_ALARM

    def on_trip(trip) -> None:
        if (stop.at_once and trip.reason == stop.reason) or trip.reason == GAIN_ALARM:
            return
        writer.event("interlock", f"{trip.reason}: {trip.message} -> {trip.action}", channel=trip.channel,
                     flight=flight(), time_s=trip.onset_wall)
    return on_trip


def _error_limits(gw, test: EnduranceTest) -> Callable[[], None]:
    """Every channel's tracking-error limit for the session, unless the gateway's options set
    one: :func:`gateway.limits.programme_error_limit_kgf` of the channel's largest range over the
    flight types. Returns what puts them back."""
    sups = [ch.supervisor for ch in gw.loop.channels]
    own = [s.limits for s in sups]
    ranges = np.max([ft.programme.ranges_kgf for ft in test.flight_types.values()], axis=0)
    for s, lim, rng in zip(sups, own, ranges):
        if lim.error_limit_kgf is None:
            s.limits = replace(lim, error_limit_kgf=programme_error_limit_kgf(rng))

    def restore() -> None:
        for s, lim in zip(sups, own):
            s.limits = lim
    return restore


def _end_session(result: SessionResult, journal: Journal, log: TurningPointLog, player: FlightPlayer,
                 stop: StopRequest, writer: JournalWriter, recorder: SessionRecorder, outcome, failure,
                 inspection, last: int) -> None:
    """The journal's state and events after the run, the log brought up to date, the session's
    record written."""
    meta = recorder.meta
    result.status = meta.get("status") or (outcome.status if outcome else None)
    result.end_reason = meta.get("end_reason")
    result.end_message = meta.get("end_message")
    result.loading = writer.loading_info
    result.flights_flown = writer.flights_flown
    result.waited_for_pieces_s = player.waited_s
    unload = (meta.get("safety") or {}).get("unload")
    result.unload = unload
    try:
        if writer.gain is not None and writer.error is None:   # the gain monitor's pass ends here
            writer.gain.monitor.end_pass()
            journal.record_monitors(writer.gain.step(player.number)[0], player.number)
        if unload and unload.get("largest_deviation"):
            journal.add_event("unload", unload_text(unload), flight=player.number)
        state = journal.state()
        if state != "finished":
            if failure is not None:
                reason = f"interrupted ({type(failure).__name__}: {failure or 'signal'})"
            elif writer.error is not None:
                reason = f"journal_error: {writer.error}"
            elif outcome is not None and outcome.status == "stopped":
                reason = f"{outcome.reason}: {outcome.message}"
            elif player.done and stop.after_flight and player.last_flight < last:
                reason = f"operator: stopped at the end of flight {player.last_flight}"
            elif player.done and inspection is not None and player.last_flight == inspection.at_flight:
                reason = f"inspection after flight {inspection.at_flight}" + (
                    f": {inspection.note}" if inspection.note else "")
                journal.add_event("inspection", reason, flight=inspection.at_flight)
            elif player.done and stop.after_flight:
                reason = f"operator: stopped at the end of flight {player.last_flight}"
            else:
                reason = f"{result.status}: {result.end_reason or 'the run ended'}"
            journal.stop(reason)
        log.export(journal)
        journal.checkpoint()
    except StandError:
        pass
    status = journal.status()
    result.state, result.reason = status["state"], status["reason"]
    result.flights_done, result.flights_target = status["flights_done"], status["flights_target"]
    result.path = writer.record_path or session_record_path(result.testdir)
    write_json(result.path, {**result.to_dict(), "started_at": writer.started_at, "ended_at": time.time(),
                             "stats": meta.get("stats"), "safety": meta.get("safety"),
                             "pieces": {"built": player.pieces.built, "reused": player.pieces.reused}})
