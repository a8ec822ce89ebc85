r"""The journal of an endurance test: ``TESTDIR/journal.sqlite``, the record that makes the flight
count exact across kills, power losses and months.

**Guarantees.** SQLite in WAL mode with ``synchronous=FULL``: a transaction that returned is on
disk (a process kill keeps it; a power loss too, where the disk honours fsync). One transaction
per load case: :meth:`Journal.commit_load_case` records the load case and advances the position
together, and the last load case of a flight also marks the flight done and counts it, in the
**same** transaction. So after a kill at any moment the count equals the flights whose every
load case is committed, no load case is recorded twice (the key is flight, attempt, index and
the position only moves forward), and the journal says which load case comes next
(:meth:`Journal.position`): at most the load case in progress is lost. A failed transaction
(the disk full, an I/O error) rolls back whole and raises :class:`JournalError` naming what
was not recorded; the journal on disk stays as it was before it.

**The lock.** A test runs in one process: the writer holds an exclusive ``fcntl.flock`` on
``TESTDIR/lock`` (it dies with the process, so a ``kill -9`` leaves no stale lock) and writes
its pid, host and start into that file for the message a second writer gets
(:class:`TestLocked`). ``interrupted`` is what a journal says whose state is ``running`` but
whose lock is free: the process died. A writer that opens such a journal records the
interruption as an event.

**Threads.** A :class:`Journal` may be used from any thread, also one other than the thread
that opened it (the connection is opened with ``check_same_thread=False``); every call holds the
journal's own lock, so calls from several threads are serialized, never interleaved inside a
transaction. Readers (``status``) may be any number of processes at once, beside the writer.
Do not fork a process that holds an open journal.

Schema (``PRAGMA user_version`` = :data:`SCHEMA_VERSION`; times are seconds since the epoch)::

    test         id = 1, name, created, flights_target, fingerprint (sha256),
                 fingerprint_json (the parts: endurance.testfile.Fingerprint), channels (JSON),
                 test_file (its text as started)
    state        id = 1, state (running | stopped | interrupted | finished), reason,
                 flights_done, flight (in progress, or NULL), attempt, load_cases_done (of the
                 flight in progress), updated, pid, host
    flights      number (key), flight_type, block, position, load_cases, attempt (1 + re-runs
                 from its first load case), interruptions, rerun (0/1), started, finished,
                 status (running | done)
    load_cases   (flight, attempt, idx) key, time                                 WITHOUT ROWID
    end_points   (flight, attempt, load_case, channel) key, level_kgf, reached_kgf, flow_pct,
                 time: every channel's end point and the valve's command that reached it
                 (the monitors' history; exported to the turning-point log, then pruned) WITHOUT ROWID
    compensation (flight_type, channel) key, tables (TOML text), flight, updated
    schedules    flight_type key, schedule (TOML text), flight, updated
    monitor_state    key (a monitor's part: ``trend``, ``trend.type.C``, ``gain``), state (JSON),
                 flight, updated: what a monitor needs to go on after a stop or a kill
    monitor_history  (monitor, flight, seq) key, row (JSON): a monitor's row per flight (the
                 trend's statistics, the gain's blocks), for plots           WITHOUT ROWID
    events       id, time, kind, channel, flight, load_case, message

What a flight leaves besides its count (its type's compensation and schedule, the monitors'
states, their rows and alarms) is stored by :meth:`Journal.finish_flight` in **one**
transaction after the one that counted it: a kill between the two loses what the flight taught
and its monitors' step, never the count, and never records a monitor's step twice (a flight is
finished once; the monitors' states say which flight they saw last).

A journal of schema 1 (no monitor tables) is brought to :data:`SCHEMA_VERSION` when it is opened
for writing; read only, its monitors read as none.
"""
from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import sqlite3
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

from core.durable import fsync_dir
from core.errors import StandError

SCHEMA_VERSION = 2
JOURNAL_FILE = "journal.sqlite"
LOCK_FILE = "lock"
STATES = ("running", "stopped", "interrupted", "finished")
#: how long a writer retries the lock before it calls the test live: a reader probes it for
#: microseconds (:func:`lock_holder`)
LOCK_RETRY_S = 1.0
#: the pace is measured over the flights finished in this window (at least the last two)
PACE_WINDOW_S = 3600.0

_SCHEMA = """
CREATE TABLE test (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    name TEXT NOT NULL,
    created REAL NOT NULL,
    flights_target INTEGER NOT NULL CHECK (flights_target >= 1),
    fingerprint TEXT NOT NULL,
    fingerprint_json TEXT NOT NULL,
    channels TEXT NOT NULL,
    test_file TEXT
);
CREATE TABLE state (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    state TEXT NOT NULL CHECK (state IN ('running', 'stopped', 'interrupted', 'finished')),
    reason TEXT,
    flights_done INTEGER NOT NULL CHECK (flights_done >= 0),
    flight INTEGER,
    attempt INTEGER,
    load_cases_done INTEGER,
    updated REAL NOT NULL,
    pid INTEGER,
    host TEXT
);
CREATE TABLE flights (
    number INTEGER PRIMARY KEY CHECK (number >= 1),
    flight_type TEXT NOT NULL,
    block INTEGER NOT NULL,
    position INTEGER NOT NULL,
    load_cases INTEGER NOT NULL CHECK (load_cases >= 1),
    attempt INTEGER NOT NULL DEFAULT 1,
    interruptions INTEGER NOT NULL DEFAULT 0,
    rerun INTEGER NOT NULL DEFAULT 0,
    started REAL NOT NULL,
    finished REAL,
    status TEXT NOT NULL CHECK (status IN ('running', 'done'))
);
CREATE INDEX flights_finished ON flights (finished);
CREATE TABLE load_cases (
    flight INTEGER NOT NULL,
    attempt INTEGER NOT NULL,
    idx INTEGER NOT NULL,
    time REAL NOT NULL,
    PRIMARY KEY (flight, attempt, idx)
) WITHOUT ROWID;
CREATE TABLE end_points (
    flight INTEGER NOT NULL,
    attempt INTEGER NOT NULL,
    load_case INTEGER NOT NULL,
    channel INTEGER NOT NULL,
    level_kgf REAL NOT NULL,
    reached_kgf REAL NOT NULL,
    flow_pct REAL,
    time REAL NOT NULL,
    PRIMARY KEY (flight, attempt, load_case, channel)
) WITHOUT ROWID;
CREATE TABLE compensation (
    flight_type TEXT NOT NULL,
    channel TEXT NOT NULL,
    tables TEXT NOT NULL,
    flight INTEGER,
    updated REAL NOT NULL,
    PRIMARY KEY (flight_type, channel)
);
CREATE TABLE schedules (
    flight_type TEXT PRIMARY KEY,
    schedule TEXT NOT NULL,
    flight INTEGER,
    updated REAL NOT NULL
);
CREATE TABLE monitor_state (
    key TEXT PRIMARY KEY,
    state TEXT NOT NULL,
    flight INTEGER,
    updated REAL NOT NULL
);
CREATE TABLE monitor_history (
    monitor TEXT NOT NULL,
    flight INTEGER NOT NULL,
    seq INTEGER NOT NULL,
    row TEXT NOT NULL,
    PRIMARY KEY (monitor, flight, seq)
) WITHOUT ROWID;
CREATE TABLE events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    time REAL NOT NULL,
    kind TEXT NOT NULL,
    channel TEXT,
    flight INTEGER,
    load_case INTEGER,
    message TEXT NOT NULL
);
"""
#: what schema 2 added to schema 1 (:meth:`Journal.open` for writing adds it)
_SCHEMA_2 = _SCHEMA[_SCHEMA.index("CREATE TABLE monitor_state"):_SCHEMA.index("CREATE TABLE events")]


class JournalError(StandError):
    """The journal cannot do what was asked: the message says what and what to do."""


class TestLocked(JournalError):
    """Another live process runs the test in this directory."""

    __test__ = False             # not a pytest test class


@dataclass(frozen=True)
class EndPoint:
    """One channel's end point of a load case: the level commanded, the force reached, and the
    valve's command (%, the flow) that reached it."""

    channel: str
    level_kgf: float
    reached_kgf: float
    flow_pct: float | None = None
    time_s: float | None = None      #: epoch s; None: the load case's commit time


@dataclass(frozen=True)
class Position:
    """What comes next: ``flight`` (1-based), its ``attempt`` (None: not begun) and the index of
    its next ``load_case`` (0-based)."""

    flight: int
    attempt: int | None
    load_case: int


@dataclass
class MonitorStep:
    """What the monitors made of a flight, stored with it (:meth:`Journal.finish_flight`):
    ``states`` {key: JSON text} replacing those keys' states, ``rows`` (monitor, flight, seq,
    JSON text) added to their history, ``events`` (kind, channel or None, message): the alarms."""

    states: dict[str, str] = field(default_factory=dict)
    rows: list[tuple[str, int, int, str]] = field(default_factory=list)
    events: list[tuple[str, str | None, str]] = field(default_factory=list)

    def __bool__(self) -> bool:
        return bool(self.states or self.rows or self.events)

    def extend(self, other: "MonitorStep | None") -> "MonitorStep":
        if other:
            self.states.update(other.states)
            self.rows += other.rows
            self.events += other.events
        return self


@dataclass(frozen=True)
class FlightRecord:
    number: int
    flight_type: str
    block: int
    position: int
    load_cases: int
    attempt: int
    interruptions: int
    rerun: bool
    started: float
    finished: float | None
    status: str


def lock_holder(testdir: str | Path) -> dict[str, Any] | None:
    """The live writer of ``testdir`` ({pid, host, since}) or None when nobody holds the lock
    (a lock file left by a dead process is no lock)."""
    path = Path(testdir) / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _read_holder(fd)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def _read_holder(fd: int) -> dict[str, Any]:
    try:
        text = os.pread(fd, 4096, 0).decode(errors="replace")
        data = json.loads(text)
        return data if isinstance(data, dict) else {"pid": None, "host": None}
    except (OSError, ValueError):
        return {"pid": None, "host": None}


class Journal:
    """The journal of the test in ``testdir`` (module docstring). Make one with
    :meth:`create`, open one with :meth:`open`; ``write=True`` takes the test's lock."""

    def __init__(self, testdir: Path, db: sqlite3.Connection, lock_fd: int | None,
                 clock: Callable[[], float]) -> None:
        self.testdir = testdir
        self.path = testdir / JOURNAL_FILE
        self._db = db
        self._lock_fd = lock_fd
        self._mutex = threading.RLock()
        self._clock = clock
        row = db.execute("SELECT channels, name, flights_target, fingerprint, fingerprint_json, "
                         "created FROM test").fetchone()
        self.channels: list[str] = json.loads(row[0])
        self._channel_index = {c: i for i, c in enumerate(self.channels)}
        self.name: str = row[1]
        self.fingerprint: str = row[3]
        self.fingerprint_json: str = row[4]
        self.created: float = row[5]

    # -- opening ---------------------------------------------------------------------------------
    @classmethod
    def create(cls, testdir: str | Path, name: str, flights_target: int, channels: Sequence[str],
               fingerprint: str, fingerprint_json: str = "{}", test_file: str | None = None,
               clock: Callable[[], float] = time.time) -> "Journal":
        """A new journal in ``testdir`` (made if need be), opened for writing (locked), state
        ``stopped`` (reason "created"); refuses a directory that holds a journal."""
        testdir = Path(testdir)
        if isinstance(flights_target, bool) or not isinstance(flights_target, int) or flights_target < 1:
            raise JournalError(f"flights_target = {flights_target!r}: give a whole number >= 1")
        if not channels or len(set(channels)) != len(channels):
            raise JournalError(f"channels {list(channels)!r}: give each channel once")
        try:
            testdir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise JournalError(f"cannot create the test directory {testdir}: {exc}") from None
        lock_fd = _acquire(testdir)
        try:
            path = testdir / JOURNAL_FILE
            if path.exists():
                raise JournalError(f"{testdir} already holds a test ({JOURNAL_FILE}); resume it, or "
                                   "choose another directory (a journal is never overwritten)")
            db = _connect(path)
            try:
                now = clock()
                with _transaction(db, f"creating the journal {path}"):
                    for statement in _SCHEMA.split(";"):
                        if statement.strip():
                            db.execute(statement)
                    db.execute("INSERT INTO test VALUES (1, ?, ?, ?, ?, ?, ?, ?)",
                               (name, now, flights_target, fingerprint, fingerprint_json,
                                json.dumps(list(channels)), test_file))
                    db.execute("INSERT INTO state (id, state, reason, flights_done, updated, pid, "
                               "host) VALUES (1, 'stopped', 'created', 0, ?, ?, ?)",
                               (now, os.getpid(), socket.gethostname()))
                    db.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            except BaseException:
                db.close()
                raise
            fsync_dir(testdir)
            return cls(testdir, db, lock_fd, clock)
        except BaseException:
            _release(lock_fd)
            raise

    @classmethod
    def open(cls, testdir: str | Path, write: bool = False,
             clock: Callable[[], float] = time.time) -> "Journal":
        """The journal of ``testdir``; ``write``: take the test's lock (:class:`TestLocked` when
        a live process holds it) and record an interruption the previous writer left."""
        testdir = Path(testdir)
        path = testdir / JOURNAL_FILE
        if not path.is_file():
            raise JournalError(f"{testdir} holds no test (no {JOURNAL_FILE}): start one first")
        lock_fd = _acquire(testdir) if write else None
        try:
            db = _connect(path)
            try:
                version = db.execute("PRAGMA user_version").fetchone()[0]
                if version == 0:
                    raise JournalError(f"{path} is not a complete journal (its creation did not "
                                       "finish: the process died first); remove it and create the "
                                       "test again")
                if version > SCHEMA_VERSION:
                    raise JournalError(f"{path} has schema {version}, written by a newer hydrostand "
                                       f"(this one reads {SCHEMA_VERSION}): update hydrostand")
                journal = cls(testdir, db, lock_fd, clock)
                if write and version < SCHEMA_VERSION:
                    journal._upgrade(version)
                if write and db.execute("PRAGMA auto_vacuum").fetchone()[0] == 0:
                    # a journal made before it gave pruned pages back: rewritten once (it holds
                    # a block's end points at most, so seconds) with incremental auto-vacuum
                    db.execute("VACUUM")
            except sqlite3.DatabaseError as exc:
                db.close()
                raise JournalError(f"{path} is not a readable journal: {exc}") from None
            except BaseException:
                db.close()
                raise
            if write:
                journal._note_interruption()
            return journal
        except BaseException:
            if lock_fd is not None:
                _release(lock_fd)
            raise

    def _upgrade(self, version: int) -> None:
        """Bring a journal of an older schema to :data:`SCHEMA_VERSION` (its writer's lock held)."""
        with self._tx(f"upgrading the journal from schema {version} to {SCHEMA_VERSION}"):
            for statement in _SCHEMA_2.split(";"):
                if statement.strip():
                    self._db.execute(statement)
            self._db.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")

    def close(self) -> None:
        with self._mutex:
            if self._db is not None:
                self._db.close()
                self._db = None
            if self._lock_fd is not None:
                _release(self._lock_fd)
                self._lock_fd = None

    def __enter__(self) -> "Journal":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def writer(self) -> bool:
        return self._lock_fd is not None

    # -- the state -------------------------------------------------------------------------------
    def _state(self) -> dict[str, Any]:
        row = self._db.execute("SELECT state, reason, flights_done, flight, attempt, "
                               "load_cases_done, updated, pid, host FROM state").fetchone()
        keys = ("state", "reason", "flights_done", "flight", "attempt", "load_cases_done",
                "updated", "pid", "host")
        return dict(zip(keys, row))

    @property
    def flights_done(self) -> int:
        with self._mutex:
            return int(self._db.execute("SELECT flights_done FROM state").fetchone()[0])

    @property
    def test_file(self) -> str | None:
        """The test file's text as the test was created with it."""
        with self._mutex:
            return self._db.execute("SELECT test_file FROM test").fetchone()[0]

    @property
    def flights_target(self) -> int:
        with self._mutex:
            return int(self._db.execute("SELECT flights_target FROM test").fetchone()[0])

    def state(self) -> str:
        """running, stopped, interrupted (running, but its process died) or finished."""
        with self._mutex:
            s = self._state()["state"]
        if s == "running" and not self.writer and lock_holder(self.testdir) is None:
            return "interrupted"
        return s

    @property
    def reason(self) -> str | None:
        """Why the test stopped (or was interrupted), as the state's last change said it."""
        with self._mutex:
            return self._state()["reason"]

    def position(self) -> Position:
        """The next flight and load case (a flight in progress continues where it stopped)."""
        with self._mutex:
            s = self._state()
        if s["flight"] is not None:
            return Position(s["flight"], s["attempt"], s["load_cases_done"])
        return Position(s["flights_done"] + 1, None, 0)

    def _note_interruption(self) -> None:
        with self._mutex:
            s = self._state()
            if s["state"] != "running":
                return
            where = (f"during flight {s['flight']} after {s['load_cases_done']} load case(s)"
                     if s["flight"] is not None else f"after flight {s['flights_done']}")
            with self._tx("recording the interruption"):
                if s["flight"] is not None:
                    self._db.execute("UPDATE flights SET interruptions = interruptions + 1 "
                                     "WHERE number = ?", (s["flight"],))
                self._set_state("interrupted", f"the process {s['pid']} on {s['host']} died {where}")
                self._event("interrupted", f"the process {s['pid']} on {s['host']} died {where}",
                            None, s["flight"], s["load_cases_done"])

    def start(self) -> None:
        """The test runs (from stopped, interrupted or created); the writer's pid and host are
        recorded."""
        with self._mutex:
            self._need_writer("start the test")
            s = self._state()
            if s["state"] == "finished":
                raise JournalError(f"{self.testdir}: the test is finished ({s['flights_done']} "
                                   "flights); raise its target to go on")
            with self._tx("starting the test"):
                self._set_state("running", None)
                self._event("started", f"{'resumed' if s['flights_done'] or s['flight'] else 'started'}"
                            f" at flight {self.position().flight} load case "
                            f"{self.position().load_case + 1}", None, None, None)

    def stop(self, reason: str) -> None:
        """The test stops (an operator, an inspection, a monitor's hold): state ``stopped``."""
        with self._mutex:
            self._need_writer("stop the test")
            if self._state()["state"] == "finished":
                return
            with self._tx("stopping the test"):
                self._set_state("stopped", reason)
                self._event("stopped", reason, None, None, None)

    def set_target(self, flights: int) -> None:
        """A new target (a test extended, or shortened to no fewer than the flights done)."""
        with self._mutex:
            self._need_writer("change the target")
            done = self._state()["flights_done"]
            if isinstance(flights, bool) or not isinstance(flights, int) or flights < max(done, 1):
                raise JournalError(f"target {flights!r}: give a whole number >= the {done} flights done")
            with self._tx("changing the target"):
                self._db.execute("UPDATE test SET flights_target = ?", (flights,))
                if self._state()["state"] == "finished" and flights > done:
                    self._set_state("stopped", f"target raised to {flights}")
                elif flights == done:
                    self._set_state("finished", None)

    # -- flights and load cases --------------------------------------------------------------------
    def begin_flight(self, number: int, flight_type: str, block: int, position: int,
                     load_cases: int) -> int:
        """Flight ``number`` begins (it must be the next: flights_done + 1). A flight that was
        in progress begins again from its first load case as a new attempt (``rerun``: its
        earlier attempts' load cases stay recorded under their attempt). Returns the attempt."""
        with self._mutex:
            self._need_writer("begin a flight")
            s = self._state()
            if s["state"] != "running":
                raise JournalError(f"flight {number}: the test is {s['state']}; start it first")
            if number != s["flights_done"] + 1:
                raise JournalError(f"flight {number}: the next flight is {s['flights_done'] + 1} "
                                   f"({s['flights_done']} done); a flight is never skipped or "
                                   "counted twice")
            if load_cases < 1:
                raise JournalError(f"flight {number}: {load_cases} load cases")
            now = self._clock()
            with self._tx(f"beginning flight {number}"):
                row = self._db.execute("SELECT flight_type, attempt FROM flights WHERE number = ?",
                                       (number,)).fetchone()
                if row is None:
                    attempt = 1
                    self._db.execute("INSERT INTO flights (number, flight_type, block, position, "
                                     "load_cases, started, status) VALUES (?, ?, ?, ?, ?, ?, "
                                     "'running')", (number, flight_type, block, position,
                                                    load_cases, now))
                else:
                    if row[0] != flight_type:
                        raise JournalError(f"flight {number} was begun as type {row[0]}, not "
                                           f"{flight_type}: the sequence changed")
                    attempt = row[1] + 1
                    self._db.execute("UPDATE flights SET attempt = ?, rerun = 1, started = ?, "
                                     "load_cases = ? WHERE number = ?",
                                     (attempt, now, load_cases, number))
                    self._event("rerun", f"flight {number} runs again from its first load case "
                                f"(attempt {attempt})", None, number, 0)
                self._db.execute("UPDATE state SET flight = ?, attempt = ?, load_cases_done = 0, "
                                 "updated = ?", (number, attempt, now))
            return attempt

    def commit_load_case(self, flight: int, index: int, end_points: Iterable[EndPoint] = (),
                         time_s: float | None = None) -> bool:
        """Load case ``index`` (0-based) of ``flight`` is done: recorded with every channel's
        end point, and the position advanced, in one transaction; the flight's last load case
        also marks the flight done and counts it (and the test finished at its target).
        Returns True when that finished the flight. Refuses a load case out of order (never
        one twice)."""
        with self._mutex:
            self._need_writer("commit a load case")
            s = self._state()
            if s["state"] != "running":
                raise JournalError(f"load case {index + 1} of flight {flight}: the test is "
                                   f"{s['state']}; start it first")
            if s["flight"] != flight:
                raise JournalError(f"load case {index + 1} of flight {flight}: the flight in progress "
                                   f"is {s['flight'] or 'none'} ({s['flights_done']} done)")
            if index != s["load_cases_done"]:
                raise JournalError(f"load case {index + 1} of flight {flight}: the next is load case "
                                   f"{s['load_cases_done'] + 1} (a load case is committed once, in order)")
            attempt = s["attempt"]
            now = self._clock() if time_s is None else float(time_s)
            n = self._db.execute("SELECT load_cases FROM flights WHERE number = ?", (flight,)).fetchone()[0]
            rows = []
            for p in end_points:
                ch = self._channel_index.get(p.channel)
                if ch is None:
                    raise JournalError(f"end point of channel {p.channel!r}: the test's channels "
                                       f"are {', '.join(self.channels)}")
                rows.append((flight, attempt, index, ch, float(p.level_kgf), float(p.reached_kgf),
                             None if p.flow_pct is None else float(p.flow_pct),
                             now if p.time_s is None else float(p.time_s)))
            last = index + 1 == n
            with self._tx(f"committing load case {index + 1} of flight {flight}"):
                self._db.execute("INSERT INTO load_cases VALUES (?, ?, ?, ?)",
                                 (flight, attempt, index, now))
                self._db.executemany("INSERT INTO end_points VALUES (?, ?, ?, ?, ?, ?, ?, ?)", rows)
                if not last:
                    self._db.execute("UPDATE state SET load_cases_done = ?, updated = ?",
                                     (index + 1, now))
                else:
                    self._db.execute("UPDATE flights SET status = 'done', finished = ? "
                                     "WHERE number = ?", (now, flight))
                    done = s["flights_done"] + 1
                    self._db.execute("UPDATE state SET flights_done = ?, flight = NULL, attempt = "
                                     "NULL, load_cases_done = NULL, updated = ?", (done, now))
                    if done >= self._db.execute("SELECT flights_target FROM test").fetchone()[0]:
                        self._set_state("finished", None)
                        self._event("finished", f"the target of {done} flights is reached", None,
                                    flight, None)
            return last

    def finish_flight(self, number: int, compensation: Mapping[str, str] | None = None,
                      schedule: str | None = None, monitors: "MonitorStep | None" = None) -> FlightRecord:
        """After flight ``number``'s last load case (which counted it): store what was learnt
        from it for its type and what its monitors made of it, in one transaction: every
        channel's compensation tables (``{channel: TOML text}``), the time-scaling schedule
        (TOML text) and the monitors' step (:class:`MonitorStep`: their states, rows and
        alarms, the alarms as events of this flight). Returns the flight's record; refuses a
        flight not done."""
        with self._mutex:
            rec = self.flight(number)
            if rec is None or rec.status != "done":
                raise JournalError(f"flight {number} is not done: its last load case is not "
                                   "committed")
            if compensation or schedule is not None or monitors:
                self._need_writer("store what a flight taught")
                with self._tx(f"storing what flight {number} taught"):
                    self._put_compensation(rec.flight_type, compensation or {}, number)
                    if schedule is not None:
                        self._put_schedule(rec.flight_type, schedule, number)
                    if monitors:
                        self._put_monitors(monitors, number)
            return rec

    def flight(self, number: int) -> FlightRecord | None:
        with self._mutex:
            row = self._db.execute("SELECT number, flight_type, block, position, load_cases, "
                                   "attempt, interruptions, rerun, started, finished, status "
                                   "FROM flights WHERE number = ?", (number,)).fetchone()
        if row is None:
            return None
        row = list(row)
        row[7] = bool(row[7])
        return FlightRecord(*row)

    # -- what is learnt per flight type --------------------------------------------------------------
    def set_compensation(self, flight_type: str, tables: Mapping[str, str],
                         flight: int | None = None) -> None:
        """Every channel's compensation tables for a flight type (``{channel: TOML text}``:
        :meth:`loading.compensation.Compensation.to_toml`)."""
        with self._mutex:
            self._need_writer("store the compensation")
            with self._tx(f"storing flight type {flight_type}'s compensation"):
                self._put_compensation(flight_type, tables, flight)

    def compensation(self, flight_type: str) -> dict[str, str]:
        with self._mutex:
            rows = self._db.execute("SELECT channel, tables FROM compensation WHERE flight_type = ?",
                                    (flight_type,)).fetchall()
        return dict(rows)

    def set_schedule(self, flight_type: str, schedule: str, flight: int | None = None) -> None:
        """A flight type's time-scaling schedule (TOML text: ``loading.time_scaling``)."""
        with self._mutex:
            self._need_writer("store a schedule")
            with self._tx(f"storing flight type {flight_type}'s schedule"):
                self._put_schedule(flight_type, schedule, flight)

    def schedule(self, flight_type: str) -> str | None:
        with self._mutex:
            row = self._db.execute("SELECT schedule FROM schedules WHERE flight_type = ?",
                                   (flight_type,)).fetchone()
        return None if row is None else row[0]

    def _put_compensation(self, flight_type: str, tables: Mapping[str, str], flight: int | None) -> None:
        for channel, text in tables.items():
            if channel not in self._channel_index:
                raise JournalError(f"compensation of channel {channel!r}: the test's channels are "
                                   f"{', '.join(self.channels)}")
            self._db.execute("INSERT OR REPLACE INTO compensation VALUES (?, ?, ?, ?, ?)",
                             (flight_type, channel, str(text), flight, self._clock()))

    def _put_schedule(self, flight_type: str, schedule: str, flight: int | None) -> None:
        self._db.execute("INSERT OR REPLACE INTO schedules VALUES (?, ?, ?, ?)",
                         (flight_type, str(schedule), flight, self._clock()))

    # -- the monitors ----------------------------------------------------------------------------------
    def record_monitors(self, step: "MonitorStep", flight: int | None = None) -> None:
        """A monitors' step outside a finished flight (at the end of a session: what a monitor
        saw of the flight a stop cut), in one transaction."""
        with self._mutex:
            self._need_writer("store the monitors' state")
            with self._tx("storing the monitors' state"):
                self._put_monitors(step, flight)

    def monitor_states(self, prefix: str = "") -> dict[str, str]:
        """The monitors' states whose key starts with ``prefix`` ({key: JSON text})."""
        with self._mutex:
            try:
                rows = self._db.execute("SELECT key, state FROM monitor_state WHERE substr(key, 1, ?) = ? "
                                        "ORDER BY key", (len(prefix), prefix)).fetchall()
            except sqlite3.OperationalError:          # a journal of schema 1, read only
                return {}
        return dict(rows)

    def monitor_history(self, monitor: str, first_flight: int = 1,
                        last_flight: int | None = None) -> list[tuple[int, int, str]]:
        """A monitor's rows of flights ``first_flight``..``last_flight``: (flight, seq, JSON text)."""
        with self._mutex:
            try:
                return [tuple(r) for r in self._db.execute(
                    "SELECT flight, seq, row FROM monitor_history WHERE monitor = ? AND flight BETWEEN ? AND ? "
                    "ORDER BY flight, seq", (monitor, first_flight,
                                            last_flight if last_flight is not None else 2 ** 62))]
            except sqlite3.OperationalError:
                return []

    def _put_monitors(self, step: "MonitorStep", flight: int | None) -> None:
        now = self._clock()
        for key, text in step.states.items():
            self._db.execute("INSERT OR REPLACE INTO monitor_state VALUES (?, ?, ?, ?)",
                             (key, str(text), flight, now))
        for monitor, row_flight, seq, text in step.rows:
            self._db.execute("INSERT OR REPLACE INTO monitor_history VALUES (?, ?, ?, ?)",
                             (monitor, row_flight, seq, str(text)))
        for kind, channel, message in step.events:
            self._event(kind, message, channel, flight, None)

    # -- events ------------------------------------------------------------------------------------
    def add_event(self, kind: str, message: str, channel: str | None = None,
                  flight: int | None = None, load_case: int | None = None,
                  time_s: float | None = None) -> int:
        """An event (a limit, an interlock, a monitor's alarm, an operator's note); returns
        its id."""
        with self._mutex:
            self._need_writer("record an event")
            with self._tx(f"recording the event {kind!r}"):
                return self._event(kind, message, channel, flight, load_case, time_s)

    def events(self, since_id: int = 0, limit: int | None = None) -> list[dict[str, Any]]:
        """Events after ``since_id``, oldest first (``limit``: the latest that many)."""
        with self._mutex:
            sql = ("SELECT id, time, kind, channel, flight, load_case, message FROM events "
                   "WHERE id > ? ORDER BY id")
            rows = self._db.execute(sql, (since_id,)).fetchall()
        keys = ("id", "time", "kind", "channel", "flight", "load_case", "message")
        out = [dict(zip(keys, r)) for r in rows]
        return out[-limit:] if limit else out

    # -- the end points ----------------------------------------------------------------------------
    def end_points(self, first_flight: int, last_flight: int) -> list[tuple]:
        """Every end point of flights ``first_flight``..``last_flight`` (every attempt), in
        order: tuples (flight, block, flight_type, attempt, load_case, channel name, level_kgf,
        reached_kgf, flow_pct, time)."""
        with self._mutex:
            rows = self._db.execute(
                "SELECT e.flight, f.block, f.flight_type, e.attempt, e.load_case, e.channel, "
                "e.level_kgf, e.reached_kgf, e.flow_pct, e.time FROM end_points e JOIN flights f "
                "ON f.number = e.flight WHERE e.flight BETWEEN ? AND ? "
                "ORDER BY e.flight, e.attempt, e.load_case, e.channel",
                (first_flight, last_flight)).fetchall()
        names = self.channels
        return [(f, b, t, a, k, names[c], *rest) for f, b, t, a, k, c, *rest in rows]

    def prune_end_points(self, through_flight: int) -> int:
        """Delete the end points of flights up to ``through_flight`` (done flights only: after
        they are in the turning-point log); returns the rows deleted."""
        with self._mutex:
            self._need_writer("prune end points")
            done = self._state()["flights_done"]
            if through_flight > done:
                raise JournalError(f"prune through flight {through_flight}: only {done} are done")
            with self._tx("pruning end points"):
                deleted = self._db.execute("DELETE FROM end_points WHERE flight <= ?",
                                           (through_flight,)).rowcount
            try:            # the free pages back to the file system (a journal made with
                # auto_vacuum; else nothing); executescript steps it to the end, execute frees one page
                self._db.executescript("PRAGMA incremental_vacuum;")
            except sqlite3.Error as exc:
                raise _journal_error(exc, "giving back the pruned pages") from None
            return deleted

    def checkpoint(self, vacuum: bool = False) -> None:
        """Move the write-ahead log into the database and truncate it (SQLite does this by
        itself every 1,000 pages); ``vacuum``: also give the pages of pruned rows back to the
        file system (rewrites the database: minutes for a large one, the test stopped)."""
        with self._mutex:
            self._need_writer("checkpoint the journal")
            try:
                if vacuum:
                    self._db.execute("VACUUM")
                self._db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            except sqlite3.Error as exc:
                raise _journal_error(exc, f"checkpointing {self.path}") from None

    # -- status and checks -----------------------------------------------------------------------------
    def status(self, now: float | None = None, events: int = 10) -> dict[str, Any]:
        """The test at a glance: ``state`` (interrupted when running without a live process),
        ``reason``, ``flights_done``, ``flights_target``, ``flight`` {number, type, block,
        position, attempt, load_cases} in progress (or next), ``load_case`` (the next, 1-based),
        ``pace_flights_per_h`` over the last hour (at least the last two flights; None before),
        ``eta_s``, ``events`` (the latest), ``holder`` (the live writer) and the test's name,
        fingerprint and channels."""
        now = self._clock() if now is None else now
        with self._mutex:
            s = self._state()
            target = self.flights_target
            pos = self.position()
            row = self._db.execute("SELECT flight_type, block, position, load_cases, attempt FROM "
                                   "flights WHERE number = ?", (pos.flight,)).fetchone()
            finished = [r[0] for r in self._db.execute(
                "SELECT finished FROM flights WHERE status = 'done' AND finished >= ? "
                "ORDER BY finished", (now - PACE_WINDOW_S,))]
            if len(finished) < 2:
                finished = sorted(r[0] for r in self._db.execute(
                    "SELECT finished FROM flights WHERE status = 'done' ORDER BY finished DESC "
                    "LIMIT 2"))
            latest = self.events(limit=events)
        state = s["state"]
        holder = lock_holder(self.testdir) if not self.writer else \
            {"pid": os.getpid(), "host": socket.gethostname()}
        if state == "running" and holder is None:
            state = "interrupted"
        pace = None
        if len(finished) >= 2 and finished[-1] > finished[0]:
            pace = (len(finished) - 1) / (finished[-1] - finished[0]) * 3600.0
        remaining = max(target - s["flights_done"], 0)
        flight = None
        if pos.flight <= target:
            flight = {"number": pos.flight, "type": row[0] if row else None,
                      "block": row[1] if row else None, "position": row[2] if row else None,
                      "load_cases": row[3] if row else None,
                      "attempt": row[4] if row and s["flight"] is not None else None}
        return {
            "name": self.name, "testdir": str(self.testdir), "state": state,
            "reason": s["reason"], "flights_done": s["flights_done"], "flights_target": target,
            "flight": flight, "load_case": pos.load_case + 1 if flight else None,
            "pace_flights_per_h": pace,
            "eta_s": remaining / pace * 3600.0 if pace and remaining else (0.0 if not remaining else None),
            "events": latest, "holder": holder, "updated": s["updated"],
            "fingerprint": self.fingerprint, "channels": list(self.channels),
        }

    def integrity_check(self) -> list[str]:
        """Problems found, none when the journal is sound: SQLite's ``PRAGMA integrity_check``,
        then the count's invariants (the done flights are 1..flights_done, each with every load
        case of its last attempt; the flight in progress has exactly its load cases before the
        position; no load case beyond a flight's count)."""
        with self._mutex:
            db = self._db
            problems = [r[0] for r in db.execute("PRAGMA integrity_check") if r[0] != "ok"]
            s = self._state()
            done = [r[0] for r in db.execute("SELECT number FROM flights WHERE status = 'done' "
                                             "ORDER BY number")]
            if done != list(range(1, s["flights_done"] + 1)):
                problems.append(f"flights_done = {s['flights_done']} but the done flights are "
                                f"{_ranges(done)}")
            bad = db.execute(
                "SELECT f.number, f.load_cases, COUNT(l.idx), MIN(l.idx), MAX(l.idx) FROM flights f "
                "LEFT JOIN load_cases l ON l.flight = f.number AND l.attempt = f.attempt "
                "WHERE f.status = 'done' GROUP BY f.number "
                "HAVING COUNT(l.idx) != f.load_cases OR MIN(l.idx) != 0 "
                "OR MAX(l.idx) != f.load_cases - 1").fetchall()
            for number, n, count, lo, hi in bad[:10]:
                problems.append(f"flight {number} is done with {count} of its {n} load cases")
            beyond = db.execute("SELECT COUNT(*) FROM load_cases l JOIN flights f ON "
                                "l.flight = f.number WHERE l.idx >= f.load_cases").fetchone()[0]
            if beyond:
                problems.append(f"{beyond} load case(s) beyond their flight's count")
            if s["flight"] is not None:
                idx = [r[0] for r in db.execute("SELECT idx FROM load_cases WHERE flight = ? AND "
                                                "attempt = ? ORDER BY idx", (s["flight"], s["attempt"]))]
                if idx != list(range(s["load_cases_done"])):
                    problems.append(f"flight {s['flight']} in progress at load case "
                                    f"{s['load_cases_done'] + 1} has load cases {_ranges(idx)}")
                if s["flight"] != s["flights_done"] + 1:
                    problems.append(f"flight {s['flight']} in progress after {s['flights_done']} done")
            orphans = db.execute("SELECT COUNT(*) FROM load_cases WHERE flight NOT IN "
                                 "(SELECT number FROM flights)").fetchone()[0]
            if orphans:
                problems.append(f"{orphans} load case(s) of flights never begun")
            return problems

    # -- internals -------------------------------------------------------------------------------------
    def _need_writer(self, what: str) -> None:
        if self._db is None:
            raise JournalError(f"{self.path}: the journal is closed")
        if not self.writer:
            raise JournalError(f"cannot {what}: the journal of {self.testdir} was opened for reading "
                               "(Journal.open(testdir, write=True) takes the test's lock)")

    def _tx(self, what: str) -> "_transaction":
        if self._db is None:
            raise JournalError(f"{self.path}: the journal is closed")
        return _transaction(self._db, f"{what} in {self.path}")

    def _set_state(self, state: str, reason: str | None) -> None:
        self._db.execute("UPDATE state SET state = ?, reason = ?, updated = ?, pid = ?, host = ?",
                         (state, reason, self._clock(), os.getpid(), socket.gethostname()))

    def _event(self, kind: str, message: str, channel: str | None, flight: int | None,
               load_case: int | None, time_s: float | None = None) -> int:
        cur = self._db.execute("INSERT INTO events (time, kind, channel, flight, load_case, message) "
                               "VALUES (?, ?, ?, ?, ?, ?)",
                               (self._clock() if time_s is None else time_s, kind, channel, flight,
                                load_case, message))
        return int(cur.lastrowid)


class _transaction:
    """``BEGIN IMMEDIATE`` … ``COMMIT``; on any error ``ROLLBACK`` and a :class:`JournalError`
    naming what was not recorded (the disk full, an I/O error)."""

    def __init__(self, db: sqlite3.Connection, what: str) -> None:
        self.db = db
        self.what = what

    def __enter__(self) -> None:
        try:
            self.db.execute("BEGIN IMMEDIATE")
        except sqlite3.Error as exc:
            raise _journal_error(exc, self.what) from None

    def __exit__(self, kind, exc, tb) -> bool:
        if kind is None:
            try:
                self.db.execute("COMMIT")
                return False
            except sqlite3.Error as err:
                exc = err
        try:
            self.db.execute("ROLLBACK")
        except sqlite3.Error:
            pass                      # SQLite rolled back already (SQLITE_FULL, ...)
        if isinstance(exc, sqlite3.Error):
            raise _journal_error(exc, self.what) from None
        return False


def _journal_error(exc: sqlite3.Error, what: str) -> JournalError:
    text = str(exc)
    if "full" in text.lower():
        return JournalError(f"{what}: the disk is full ({text}); nothing of it was recorded and the "
                            "journal is as it was before: free space, then resume")
    if "locked" in text.lower() or "busy" in text.lower():
        return JournalError(f"{what}: the journal is busy ({text})")
    return JournalError(f"{what}: {text}; nothing of it was recorded")


def _connect(path: Path) -> sqlite3.Connection:
    try:
        db = sqlite3.connect(str(path), timeout=10.0, isolation_level=None,
                             check_same_thread=False)
        # pages freed by pruning go back to the file system (Journal.prune_end_points), so the
        # file stays the size of what it holds: takes effect on a new file (before WAL and the
        # first table), on an older journal at its next VACUUM
        db.execute("PRAGMA auto_vacuum = INCREMENTAL")
        db.execute("PRAGMA journal_mode = WAL")
        db.execute("PRAGMA synchronous = FULL")
    except sqlite3.Error as exc:
        raise JournalError(f"{path}: cannot open the journal: {exc}") from None
    return db


def _acquire(testdir: Path) -> int:
    """Take ``testdir``'s lock (exclusive flock) and write the holder into the lock file."""
    path = testdir / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise JournalError(f"cannot open the test's lock {path}: {exc}") from None
    deadline = time.monotonic() + LOCK_RETRY_S
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            if time.monotonic() < deadline:
                time.sleep(0.02)
                continue
            holder = _read_holder(fd)
            os.close(fd)
            since = holder.get("since")
            raise TestLocked(
                f"{testdir} is a live test: process {holder.get('pid')} on "
                f"{holder.get('host')} runs it{f' since {since}' if since else ''}; a test runs in "
                "one process (stop that one first)") from None
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.ENOLCK, errno.EOPNOTSUPP):
                raise JournalError(f"{path}: this file system cannot lock files ({exc}); put the "
                                   "test directory on a local disk") from None
            raise
    try:
        text = json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                           "since": time.strftime("%Y-%m-%dT%H:%M:%S%z")})
        os.ftruncate(fd, 0)
        os.pwrite(fd, text.encode(), 0)
        os.fsync(fd)
    except OSError:
        pass                          # the lock holds; only the message would lack the holder
    return fd


def _release(fd: int) -> None:
    try:
        fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def _ranges(numbers: Sequence[int]) -> str:
    """1-5, 7 for [1, 2, 3, 4, 5, 7]."""
    if not numbers:
        return "none"
    out, start, prev = [], numbers[0], numbers[0]
    for n in list(numbers[1:]) + [None]:
        if n is not None and n == prev + 1:
            prev = n
            continue
        out.append(f"{start}-{prev}" if prev != start else str(start))
        if n is not None:
            start = prev = n
    return ", ".join(out)
