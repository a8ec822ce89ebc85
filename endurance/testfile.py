r"""The test file of an endurance test (``test.toml``): what is loaded, on which station, in
which order, how far, and what watches it.

::

    name = "wing box, 100,000 flights"
    station = "rig.toml"          # a rig file, relative to this file; or "stand" (one channel)
    controller = "controller.toml"  # `stand design` output for that station
    rate_kgf_s = 2500             # the flight types' default (or frequency_hz = 0.5)
    flights = 100000              # the target (or blocks = 25)

    [flight.A]                    # a flight type: a load-case CSV, `case` and a column per
    load_cases = "flights/A.csv"  # channel (as `stand load --rig` reads it)
    rate_kgf_s = 2000             # its own rate (or frequency_hz), else the file's
    schedule = "A.schedule.toml"  # optional: its segment durations (stand load --fastest made it)

    [time_scaling]                # optional: each flight type's segments timed to the valves
    accuracy_pct = 0.5            # as stand load --accuracy, flight after flight of the type
    search_flights = 20           # at most this many of a type's flights search its durations

    [block]                       # the flights of one block, flown in a seeded random order
    seed = 20261201
    flights = { A = 1, B = 2, C = 6 }

    [[inspection]]                # the test stops (paused) once this flight is done
    at_flight = 25000
    note = "NDT of the lower skin"

    [monitor.trend]               # the end points' trend (endurance.trends: a crack needs more
    action = "hold"               # flow); note | hold | unload
    learn_flights = 30            # a type's flights that learn its baseline
    shift_pct = 1.0               # the flow change the test is tuned to
    false_alarm_flights = 1e5     # intact flights between false alarms, on average
                                  # (and floor_pct, confidence, sides, common_mode: TrendOptions)

    [monitor.gain]                # as stand load's --gain options
    mode = "watch"                # off | watch | adapt
    block_s = 10.0
    fall_pct = 2.0
    rise_pct = 5.0
    action = "note"

    [storage]
    rolling_window_s = 600        # full-rate signals kept for the last 10 minutes
    event_window_s = 30           # and ±30 s around each event, as run directories
    chunk_s = 60                  # the rolling window's files

**A stand** is a station of one channel: ``station = "stand"`` with an optional ``[stand]``
table (``period_ms`` 2, ``range_kgf`` 10,000, ``force_limit_kgf`` 9,500: the stand's defaults);
its one channel is named ``stand`` (:data:`STAND_CHANNEL`, as the emulator names it), and a
flight type's CSV names its column ``level`` (or ``case,level``) as for ``stand load``.

Everything is checked on reading: the station's file, the controller (for the station's
channels and period), every flight type's load cases (within each channel's force limit), the
block (every flight type in it, none other). A mistake is one
:class:`~core.errors.ParameterError` (or :class:`~core.errors.DataError` for a data file) naming
the test file and the key; an unknown key is refused naming it.

**The fingerprint** (:class:`Fingerprint`) is a sha256 per part of what makes the test the
same test: the station's channels, their ranges and limits, its period, the controller file's
content, every flight type's load cases and rate, the block's counts and seed. A resume
compares the parts and says what changed (:meth:`Fingerprint.changes`). The target, the
inspections, the monitors and the storage policy are not part of it: they may change between a
stop and a resume.
"""
from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from core.errors import DataError, ParameterError

from .spectrum import Block, FlightSequence
from .trends import ACTIONS as MONITOR_ACTIONS, SIDES, TrendOptions

#: a one-channel stand's channel: the column of its turning-point CSVs
STAND = "stand"
#: a stand's one channel: the station's (loading.programme.STAND); its load-case CSVs name it
#: ``level``, as a one-channel turning-point CSV does
STAND_CHANNEL = STAND
#: the one-channel stand's defaults (gateway.config.GatewayConfig, gateway.supervisor.SafetyLimits)
STAND_PERIOD_MS = 2.0
STAND_RANGE_KGF = 10_000.0
STAND_FORCE_LIMIT_KGF = 9_500.0
GAIN_MODES = ("off", "watch", "adapt")
NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_-]*$")

_TOP = {"name", "station", "controller", "rate_kgf_s", "frequency_hz", "flights", "blocks",
        "stand", "flight", "block", "inspection", "monitor", "storage", "time_scaling"}
#: a flight type's flights that search its durations at most (then the fastest that met the
#: accuracy is kept, or the last tried)
SEARCH_FLIGHTS = 20


class TestFileError(ParameterError):
    """A test file that cannot be used; the message names the file and the key."""

    __test__ = False             # not a pytest test class


@dataclass(frozen=True)
class Station:
    """What is loaded: a rig's channels, or a stand as a station of one channel.

    Attributes
    ----------
    kind : "rig" or "stand"
    names : the channels, in the rig's order (a stand: ``["stand"]``)
    ranges_kgf, force_limits_kgf : per channel
    period_s : the control period
    path : the rig file (None for a stand)
    rig : the rig file as read (:class:`rig.config.RigConfig`; None for a stand)
    """

    kind: str
    names: list[str]
    ranges_kgf: list[float]
    force_limits_kgf: list[float]
    period_s: float
    path: Path | None = None
    rig: Any = field(default=None, repr=False, compare=False)

    @property
    def n(self) -> int:
        return len(self.names)


@dataclass(frozen=True)
class FlightType:
    """One flight type: its load cases for every channel and how fast they are joined.

    Attributes
    ----------
    name : e.g. "A"
    path : the load-case CSV
    levels_kgf : (N channels, M load cases)
    labels : the load cases' labels (the CSV's ``case`` column, or 1, 2, ...)
    rate_kgf_s, frequency_hz : one of them (the other None)
    programme : the load cases as :class:`loading.programme.Programme` at the station's
        period, at its rate
    schedule : its segment durations to replay (:class:`loading.time_scaling.Schedule`,
        checked against its load cases), or None
    """

    name: str
    path: Path
    levels_kgf: np.ndarray = field(repr=False)
    labels: list[str] = field(repr=False)
    rate_kgf_s: float | None
    frequency_hz: float | None
    programme: Any = field(repr=False, compare=False)
    schedule: Any = field(default=None, repr=False, compare=False)

    @property
    def load_cases(self) -> int:
        return int(self.levels_kgf.shape[1])

    @property
    def duration_s(self) -> float:
        """The flight's programme time at its rate (s), approach and unload not counted."""
        return float(self.programme.duration_s)


@dataclass(frozen=True)
class Inspection:
    """The test stops once flight ``at_flight`` is done (state stopped, reason inspection)."""

    at_flight: int
    note: str = ""


@dataclass(frozen=True)
class TimeScaling:
    """Every flight type without its own schedule timed to the valves, as ``stand load
    --accuracy`` does, over at most ``search_flights`` of its flights (:mod:`endurance.timing`)."""

    accuracy_pct: float = 0.5
    search_flights: int = SEARCH_FLIGHTS

    def options(self):
        """:class:`loading.time_scaling.ScalingOptions` at this accuracy."""
        from loading.time_scaling import ScalingOptions
        return ScalingOptions(accuracy_pct=self.accuracy_pct)


@dataclass(frozen=True)
class GainMonitor:
    """``stand load --gain``'s options for every flight (:class:`loading.gain_monitor.MonitorOptions`)."""

    mode: str = "off"
    block_s: float = 10.0
    fall_pct: float = 2.0
    rise_pct: float = 5.0
    action: str = "note"

    def options(self):
        """:class:`loading.gain_monitor.MonitorOptions` (None when off)."""
        if self.mode == "off":
            return None
        from loading.gain_monitor import MonitorOptions
        return MonitorOptions(block_s=self.block_s, fall_pct=self.fall_pct, rise_pct=self.rise_pct,
                              action=self.action, follow=self.mode == "adapt")


@dataclass(frozen=True)
class StoragePolicy:
    """What full-rate data is kept: the last ``rolling_window_s`` in files of ``chunk_s``, and
    ``±event_window_s`` around each event."""

    rolling_window_s: float = 600.0
    event_window_s: float = 30.0
    chunk_s: float = 60.0


@dataclass(frozen=True)
class EnduranceTest:
    """A test file, read and checked (module docstring)."""

    name: str
    path: Path
    station: Station
    controller_path: Path
    flight_types: dict[str, FlightType]
    block: Block
    flights: int
    inspections: list[Inspection] = field(default_factory=list)
    #: the end points' trend (None: off)
    trend: TrendOptions | None = None
    gain: GainMonitor = field(default_factory=GainMonitor)
    #: time scaling of the flight types without a schedule (None: off)
    time_scaling: TimeScaling | None = None
    storage: StoragePolicy = field(default_factory=StoragePolicy)
    controller: Any = field(default=None, repr=False, compare=False)

    @property
    def sequence(self) -> FlightSequence:
        """Flight number → block, position, type."""
        return FlightSequence(self.block, self.flights)

    @property
    def blocks(self) -> int:
        return -(-self.flights // self.block.size)

    def fingerprint(self) -> "Fingerprint":
        return fingerprint(self)


# -- the fingerprint -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Fingerprint:
    """A sha256 per part of the test (module docstring); ``digest`` the sha256 of them all.

    Parts: ``station.channels``, ``station.limits``, ``station.period``, ``controller``,
    ``flight.T.load_cases`` and ``flight.T.rate`` per flight type ``T``, ``block.counts``,
    ``block.seed``. ``station`` is "rig" or "stand", for the messages."""

    parts: dict[str, str]
    station: str = "rig"

    @property
    def digest(self) -> str:
        return _sha(_canonical(self.parts))

    def to_json(self) -> str:
        return json.dumps({"station": self.station, "parts": self.parts}, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "Fingerprint":
        """The fingerprint :meth:`to_json` wrote (DataError: not one, the journal damaged)."""
        try:
            data = json.loads(text)
            return cls(dict(data["parts"]), str(data.get("station", "rig")))
        except (ValueError, TypeError, KeyError, AttributeError) as exc:
            raise DataError(f"the test's fingerprint in the journal cannot be read ({type(exc).__name__}: "
                            f"{exc}); the journal is damaged") from None

    def changes(self, before: "Fingerprint") -> list[str]:
        """What changed from ``before`` (the test as it was started) to this one, one sentence
        per change; empty when the test is the same."""
        what = "the rig file's" if self.station == "rig" else "the stand's"
        out = []
        if self.station != before.station:
            out.append(f"the station was {_station_name(before.station)} and is "
                       f"{_station_name(self.station)} now")
        fixed = {"station.channels": f"{what} channels changed (their names or order)",
                 "station.limits": f"{what} ranges or force limits changed",
                 "station.period": f"{what} control period changed",
                 "controller": "the controller file's content changed",
                 "block.counts": "the block's flights per type changed",
                 "block.seed": "the block's seed changed (the order of the flights)"}
        for key, sentence in fixed.items():
            if self.parts.get(key) != before.parts.get(key):
                out.append(sentence)
        now, then = _types(self.parts), _types(before.parts)
        for t in then:
            if t not in now:
                out.append(f"flight type {t} was removed")
        for t in now:
            if t not in then:
                out.append(f"flight type {t} is new")
                continue
            for part, sentence in (("load_cases", "load cases"), ("rate", "rate or frequency")):
                key = f"flight.{t}.{part}"
                if self.parts.get(key) != before.parts.get(key):
                    out.append(f"flight type {t}'s {sentence} changed")
        return out


def _station_name(kind: str) -> str:
    return "a rig" if kind == "rig" else "a one-channel stand"


def _types(parts: Mapping[str, str]) -> list[str]:
    seen = []
    for key in parts:
        if key.startswith("flight."):
            t = key.split(".")[1]
            if t not in seen:
                seen.append(t)
    return seen


def _canonical(data: Any) -> str:
    return json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False)


def _sha(text: str | bytes) -> str:
    return hashlib.sha256(text.encode() if isinstance(text, str) else text).hexdigest()


def _level(v: float) -> float:
    """A level as the fingerprint holds it: to 1 g (0.001 kgf), so 1000 and 1000.0 agree."""
    return round(float(v), 3) + 0.0


def fingerprint(test: EnduranceTest) -> Fingerprint:
    """The fingerprint of a test file as read (:class:`Fingerprint`)."""
    st = test.station
    parts = {
        "station.channels": _sha(_canonical(st.names)),
        "station.limits": _sha(_canonical([[_level(r), _level(f)] for r, f in
                                           zip(st.ranges_kgf, st.force_limits_kgf)])),
        "station.period": _sha(_canonical(round(st.period_s * 1e6))),
        "controller": _sha(test.controller_path.read_bytes()),
    }
    for t in test.flight_types.values():
        parts[f"flight.{t.name}.load_cases"] = _sha(_canonical(
            [[_level(v) for v in row] for row in t.levels_kgf]))
        parts[f"flight.{t.name}.rate"] = _sha(_canonical(
            {"rate_kgf_s": t.rate_kgf_s} if t.rate_kgf_s is not None else
            {"frequency_hz": t.frequency_hz}))
    parts["block.counts"] = _sha(_canonical(list(test.block.counts.items())))
    parts["block.seed"] = _sha(_canonical(int(test.block.seed)))
    return Fingerprint(parts, st.kind)


# -- reading ---------------------------------------------------------------------------------------
def load_test_file(path: str | Path, check_controller: bool = True) -> EnduranceTest:
    """Read and check a test file (module docstring). ``check_controller``: read the controller
    file for the station's channels and period (False: only its content is fingerprinted)."""
    from plant.config import read_toml
    from plant.params import ModelError
    path = Path(path)
    where = str(path)
    try:
        data = read_toml(path)
    except ModelError as exc:
        raise TestFileError(f"{where}: {exc}") from None
    r = _Reader(where, path.parent)
    r.keys(data, _TOP, "")
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name.strip():
        raise TestFileError(f"{where}: name = {name!r}: give the test's name as a string")
    station = r.station(data)
    controller_path = r.file(data, "controller", "", "a controller file (stand design output)")
    controller = r.controller(controller_path, station) if check_controller else None
    rate, freq = r.rate(data, "")
    types = r.flight_types(data, station, rate, freq)
    block = r.block(data, types)
    flights = r.target(data, block)
    inspections = r.inspections(data, flights)
    trend, gain = r.monitors(data, station)
    storage = r.storage(data)
    return EnduranceTest(name=name, path=path, station=station, controller_path=controller_path,
                         flight_types=types, block=block, flights=flights,
                         inspections=inspections, trend=trend, gain=gain, storage=storage,
                         time_scaling=r.time_scaling(data), controller=controller)


class _Reader:
    """The checks, each naming the file and the key."""

    def __init__(self, where: str, base: Path) -> None:
        self.where = where
        self.base = base

    def fail(self, table: str, message: str, data: bool = False) -> None:
        cls = DataError if data else TestFileError
        raise cls(f"{self.where}: {table + ' ' if table else ''}{message}")

    def keys(self, table: Mapping[str, Any], known: set[str], name: str) -> None:
        unknown = sorted(set(table) - known)
        if unknown:
            self.fail(name, f"unknown key(s) {', '.join(unknown)}; "
                            f"{'this table' if name else 'a test file'} takes "
                            f"{', '.join(sorted(known))}")

    def table(self, data: Mapping[str, Any], key: str, name: str) -> Mapping[str, Any]:
        value = data.get(key, {})
        if not isinstance(value, Mapping):
            self.fail("", f"{key} must be a table ([{name}])")
        return value

    def number(self, table: Mapping[str, Any], key: str, name: str, default: float | None,
               positive: bool = True, lo: float | None = None, hi: float | None = None) -> float | None:
        if key not in table:
            return default
        v = table[key]
        ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
        if ok and positive and v <= 0:
            ok = False
        if not ok:
            self.fail(name, f"{key} = {_show(v)}: it must be a positive number")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            bound = f"from {lo:g} to {hi:g}" if lo is not None and hi is not None else \
                f"at least {lo:g}" if lo is not None else f"at most {hi:g}"
            self.fail(name, f"{key} = {_show(v)}: it must be {bound}")
        return float(v)

    def whole(self, table: Mapping[str, Any], key: str, name: str, low: int = 1) -> int:
        v = table[key]
        if isinstance(v, bool) or not isinstance(v, int) or v < low:
            self.fail(name, f"{key} = {_show(v)}: it must be a whole number >= {low}")
        return int(v)

    def choice(self, table: Mapping[str, Any], key: str, name: str, choices: tuple[str, ...],
               default: str) -> str:
        v = table.get(key, default)
        if v not in choices:
            self.fail(name, f"{key} = {_show(v)}: choose one of {', '.join(choices)}")
        return str(v)

    def file(self, data: Mapping[str, Any], key: str, name: str, what: str) -> Path:
        if key not in data:
            self.fail(name, f"{key} is missing: give {what}, relative to the test file")
        v = data[key]
        if not isinstance(v, str) or not v:
            self.fail(name, f"{key} = {_show(v)}: give {what} as a path")
        p = Path(v)
        p = p if p.is_absolute() else self.base / p
        if not p.is_file():
            self.fail(name, f"{key} = {_show(v)}: no such file ({p})")
        return p

    # -- the parts ---------------------------------------------------------------------------
    def station(self, data: Mapping[str, Any]) -> Station:
        if "station" not in data:
            self.fail("", 'station is missing: give a rig file (station = "rig.toml") or '
                          'station = "stand" for a one-channel stand')
        value = data["station"]
        stand = self.table(data, "stand", "stand")
        if value == STAND:
            self.keys(stand, {"period_ms", "range_kgf", "force_limit_kgf"}, "[stand]")
            period_ms = self.number(stand, "period_ms", "[stand]", STAND_PERIOD_MS, lo=0.5, hi=100.0)
            rng = self.number(stand, "range_kgf", "[stand]", STAND_RANGE_KGF)
            limit = self.number(stand, "force_limit_kgf", "[stand]", min(STAND_FORCE_LIMIT_KGF, rng),
                                hi=rng)
            return Station(STAND, [STAND_CHANNEL], [rng], [limit], period_ms / 1e3)
        if "stand" in data:
            self.fail("[stand]", 'is for station = "stand"; a rig\'s channels, limits and period '
                                 "are its rig file's")
        path = self.file(data, "station", "", 'a rig file (or "stand")')
        from rig.config import load_rig_file
        try:
            rig = load_rig_file(path)
        except ParameterError as exc:
            self.fail("", f"station = {_show(value)}: {exc}")
        return Station("rig", list(rig.names), [c.range_kgf for c in rig.channels],
                       [c.limit_kgf for c in rig.channels], rig.period_s, path, rig)

    def controller(self, path: Path, station: Station) -> Any:
        try:
            from loading.controller_files import load_controller
            return load_controller(path, station.period_s, station.names)
        except ParameterError as exc:
            self.fail("", f"controller = {_show(path.name)}: {exc}")

    def rate(self, table: Mapping[str, Any], name: str) -> tuple[float | None, float | None]:
        rate = self.number(table, "rate_kgf_s", name, None)
        freq = self.number(table, "frequency_hz", name, None)
        if rate is not None and freq is not None:
            self.fail(name, "give rate_kgf_s or frequency_hz, not both")
        return rate, freq

    def flight_types(self, data: Mapping[str, Any], station: Station, rate: float | None,
                     freq: float | None) -> dict[str, FlightType]:
        from loading.programme_files import load_programme
        tables = self.table(data, "flight", "flight.NAME")
        if not tables:
            self.fail("", "no flight type: give a [flight.NAME] table per flight type with "
                          'load_cases = "NAME.csv"')
        out = {}
        for t, table in tables.items():
            name = f"[flight.{t}]"
            if not NAME_RE.match(t):
                self.fail(name, "a flight type's name is letters, digits, '_' or '-', starting "
                                "with a letter")
            if not isinstance(table, Mapping):
                self.fail(name, "must be a table")
            self.keys(table, {"load_cases", "rate_kgf_s", "frequency_hz", "schedule"}, name)
            path = self.file(table, "load_cases", name, "a load-case CSV (case and a column per "
                                                        "channel)")
            if path.suffix.lower() == ".toml":
                self.fail(name, f"load_cases = {_show(table['load_cases'])}: a flight type is a "
                                "load-case CSV (per-channel sequences have no load cases)")
            own_rate, own_freq = self.rate(table, name)
            if own_rate is None and own_freq is None:
                own_rate, own_freq = rate, freq
            if own_rate is None and own_freq is None:
                self.fail(name, "needs rate_kgf_s or frequency_hz (or give one at the top of the "
                                "file for every flight type)")
            try:
                prog = load_programme(str(path), station.names, station.period_s, own_rate, own_freq)
                prog.check(station.force_limits_kgf)
            except (DataError, ParameterError) as exc:
                self.fail(name, f"load_cases = {_show(table['load_cases'])}: {exc}",
                          data=isinstance(exc, DataError))
            out[t] = FlightType(t, path, prog.levels_kgf, list(prog.case_labels or []), own_rate,
                                own_freq, prog, self.schedule(table, name, prog))
        return out

    def schedule(self, table: Mapping[str, Any], name: str, programme) -> Any:
        """A flight type's ``schedule``: a schedule file made for its load cases, or None."""
        if "schedule" not in table:
            return None
        from loading.time_scaling import Schedule
        path = self.file(table, "schedule", name, "a schedule file (stand load --rig --fastest made it)")
        try:
            schedule = Schedule.load(path)
            schedule.apply(programme)
        except ParameterError as exc:
            self.fail(name, f"schedule = {_show(table['schedule'])}: {exc}")
        return schedule

    def block(self, data: Mapping[str, Any], types: Mapping[str, FlightType]) -> Block:
        table = self.table(data, "block", "block")
        if not table:
            self.fail("", "no [block]: give flights = { A = 1, B = 4, ... } (flights of each type "
                          "per block) and seed")
        self.keys(table, {"flights", "seed"}, "[block]")
        counts = table.get("flights")
        if not isinstance(counts, Mapping) or not counts:
            self.fail("[block]", "flights must be a table of flights per type, e.g. "
                                 "flights = { A = 1, B = 4 }")
        for t in counts:
            if t not in types:
                self.fail("[block]", f"flights: {t} is not a flight type (there is no "
                                     f"[flight.{t}]; the types are {', '.join(types)})")
            self.whole(counts, t, "[block] flights:")
        missing = [t for t in types if t not in counts]
        if missing:
            self.fail("[block]", f"flights: no count for flight type(s) {', '.join(missing)}; "
                                 "every flight type is flown in the block (remove the ones not)")
        seed = self.whole(table, "seed", "[block]", low=0) if "seed" in table else 0
        # in the flight types' order: the shuffle starts from it
        return Block({t: int(counts[t]) for t in types}, seed)

    def target(self, data: Mapping[str, Any], block: Block) -> int:
        if ("flights" in data) == ("blocks" in data):
            self.fail("", "give the target as flights = N or blocks = N (one of them)")
        if "flights" in data:
            return self.whole(data, "flights", "")
        return self.whole(data, "blocks", "") * block.size

    def inspections(self, data: Mapping[str, Any], flights: int) -> list[Inspection]:
        items = data.get("inspection", [])
        if not isinstance(items, list) or not all(isinstance(i, Mapping) for i in items):
            self.fail("", "inspection must be an array of tables ([[inspection]] at_flight = N)")
        out = []
        for k, item in enumerate(items, start=1):
            name = f"[[inspection]] #{k}"
            self.keys(item, {"at_flight", "note"}, name)
            if "at_flight" not in item:
                self.fail(name, "at_flight is missing: the flight after which the test stops")
            n = self.whole(item, "at_flight", name)
            if n > flights:
                self.fail(name, f"at_flight = {n}: the test has {flights} flights")
            note = item.get("note", "")
            if not isinstance(note, str):
                self.fail(name, f"note = {_show(note)}: give a string")
            out.append(Inspection(n, note))
        seen = [i.at_flight for i in out]
        twice = sorted({n for n in seen if seen.count(n) > 1})
        if twice:
            self.fail("[[inspection]]", f"at_flight = {twice[0]} is given twice")
        return sorted(out, key=lambda i: i.at_flight)

    def flag(self, table: Mapping[str, Any], key: str, name: str, default: bool) -> bool:
        v = table.get(key, default)
        if not isinstance(v, bool):
            self.fail(name, f"{key} = {_show(v)}: give true or false")
        return v

    def monitors(self, data: Mapping[str, Any], station: Station) -> tuple[TrendOptions | None, GainMonitor]:
        table = self.table(data, "monitor", "monitor.NAME")
        self.keys(table, {"trend", "gain"}, "[monitor]")
        tm = None
        if "trend" in table:
            trend = self.table(table, "trend", "monitor.trend")
            name = "[monitor.trend]"
            d = TrendOptions()
            known = {"action", "learn_flights", "shift_pct", "false_alarm_flights", "floor_pct",
                     "confidence", "sides", "common_mode"}
            self.keys(trend, known, name)
            tm = TrendOptions(
                learn_flights=self.whole(trend, "learn_flights", name) if "learn_flights" in trend
                else d.learn_flights,
                shift_pct=self.number(trend, "shift_pct", name, d.shift_pct, lo=0.01, hi=100.0),
                false_alarm_flights=self.number(trend, "false_alarm_flights", name, d.false_alarm_flights,
                                                lo=10.0, hi=1e12),
                floor_pct=self.number(trend, "floor_pct", name, d.floor_pct, positive=False, lo=0.0, hi=10.0),
                confidence=self.number(trend, "confidence", name, d.confidence, lo=0.5, hi=0.999),
                sides=self.choice(trend, "sides", name, SIDES, d.sides),
                common_mode=self.flag(trend, "common_mode", name, d.common_mode),
                action=self.choice(trend, "action", name, MONITOR_ACTIONS, d.action))
            try:
                tm.check(station.n)
            except ParameterError as exc:
                self.fail(name, str(exc).removeprefix("trends: "))
        gain = self.table(table, "gain", "monitor.gain")
        name = "[monitor.gain]"
        self.keys(gain, {"mode", "block_s", "fall_pct", "rise_pct", "action"}, name)
        g = GainMonitor()
        gm = GainMonitor(
            mode=self.choice(gain, "mode", name, GAIN_MODES, "watch" if gain else g.mode),
            block_s=self.number(gain, "block_s", name, g.block_s, lo=0.1, hi=3600.0),
            fall_pct=self.number(gain, "fall_pct", name, g.fall_pct, lo=0.01, hi=90.0),
            rise_pct=self.number(gain, "rise_pct", name, g.rise_pct, lo=0.01, hi=900.0),
            action=self.choice(gain, "action", name, MONITOR_ACTIONS, g.action))
        return tm, gm

    def time_scaling(self, data: Mapping[str, Any]) -> TimeScaling | None:
        if "time_scaling" not in data:
            return None
        table = self.table(data, "time_scaling", "time_scaling")
        name = "[time_scaling]"
        self.keys(table, {"accuracy_pct", "search_flights"}, name)
        d = TimeScaling()
        return TimeScaling(self.number(table, "accuracy_pct", name, d.accuracy_pct, lo=0.01, hi=10.0),
                           self.whole(table, "search_flights", name, low=2) if "search_flights" in table
                           else d.search_flights)

    def storage(self, data: Mapping[str, Any]) -> StoragePolicy:
        table = self.table(data, "storage", "storage")
        name = "[storage]"
        self.keys(table, {"rolling_window_s", "event_window_s", "chunk_s"}, name)
        d = StoragePolicy()
        rolling = self.number(table, "rolling_window_s", name, d.rolling_window_s, hi=86400.0 * 7)
        event = self.number(table, "event_window_s", name, d.event_window_s, hi=3600.0)
        chunk = self.number(table, "chunk_s", name, min(d.chunk_s, rolling), hi=3600.0)
        if chunk > rolling:
            self.fail(name, f"chunk_s = {chunk:g} is longer than rolling_window_s = {rolling:g}")
        if event > rolling:
            self.fail(name, f"event_window_s = {event:g} is longer than rolling_window_s = "
                            f"{rolling:g}: the window before an event comes from the rolling window")
        return StoragePolicy(rolling, event, chunk)


def _show(v: Any) -> str:
    """A value as the file wrote it."""
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and v.is_integer():
        return str(int(v)) if abs(v) < 1e15 else repr(v)
    return repr(v) if not isinstance(v, (dict, list)) else json.dumps(v, default=str)
