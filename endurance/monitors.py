r"""The monitors of a running test, and the one thing a session does with what they find: an
alarm (:class:`MonitorAlarm`), which notes, holds or unloads.

* **The end-point trend** (``[monitor.trend]``, :class:`TrendWatch`): each flight run whole,
  taken over from the flight before it (:func:`fed`) and with its type's final timing
  (:meth:`endurance.timing.FlightTiming.final`) gives :class:`endurance.trends.TrendDetector` its
  end points, flows and planned flows per load case (:func:`flight_statistics`, from the forces
  and commands the control loop kept for the flight, computed on the planner's thread after the
  flight: nothing of it runs in the loop). A flight interrupted and completed in a later session
  is **skipped**, not fed: its end points are in the journal but the flows before the
  interruption were the other process's and are gone, and the segment it was taken up at began
  from a glide out of held forces, not from the load case before at speed. A session's first
  flight (it glides in from held forces) is skipped too: on the example rig offline the first
  flight after a resume of an intact structure needed 4.8 % more flow on outer than its type's
  baseline (z = 32) and alarmed. So every flight is fed once or not at all.
* **The gain monitor** (``[monitor.gain]``, :class:`GainWatch`): ``stand load --gain``'s
  :class:`loading.gain_monitor.GainMonitor` in the control loop, given to every flight's pass;
  the flights handed over without approach are one motion, so its pass (and a block of
  ``block_s``) goes on across them (:meth:`gateway.load_experiment.LoadProgramme.begin_handover`)
  and ends with the session. Its alarm acts in the loop (hold and unload stop the pass at once,
  :data:`loading.gain_monitor.GAIN_ALARM`); a note is an event.
* **A session's hook** (``run_session(..., hook=)``): any callable of a :class:`FlightEnd`
  returning a :class:`MonitorAlarm` or None (scripts, tests).

**Journalled.** After each flight its monitors' step (:class:`endurance.journal.MonitorStep`:
their states, a row per flight for plots, their alarms as events naming the channels) is stored
with what the flight taught its type, in one transaction (``Journal.finish_flight``), after the
transaction that counted it. A kill between the two loses that flight's step (the flight is then
not in the trend: skipped, as above) and never records one twice: a resumed session restores the
monitors from the journal and flies only flights after the count. The trend's state is split by
flight type (``trend``, ``trend.type.T``: only the parts that changed are written, a type's
baseline when it flies), its floats as JSON numbers (exact: the detector goes on bit for bit).
The gain monitor's state between passes is its channels' followed gains, alarm runs and
clock (:meth:`loading.gain_monitor.GainMonitor.state`); its blocks are rows.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, fields, replace
from typing import Any, Sequence

import numpy as np

from core.errors import ParameterError

from .flights import FlightRecord, filled_forces
from .journal import EndPoint, Journal, JournalError, MonitorStep
from .testfile import EnduranceTest
from .trends import TrendDetector, load_case_statistics

TREND = "trend"
GAIN = "gain"
#: the trend's state of flight type T is ``trend.type.T``
TREND_TYPE = "trend.type."
#: the stop reason of a session that a monitor's alarm stopped (hold or unload)
MONITOR_ALARM = "monitor_alarm"
#: what an alarm's action does, as its event says it
ACTION_TEXT = {"note": "noted, the test goes on", "hold": "every valve holds",
               "unload": "every channel unloads keeping the load ratios"}


@dataclass
class FlightEnd:
    """A flight done, for a session's hook: its end points per load case and, when it was run
    whole, its tracking report."""

    number: int
    flight_type: str
    end_points: dict[int, list[EndPoint]]
    report: Any = None


@dataclass(frozen=True)
class MonitorAlarm:
    """What a monitor found that the session acts on: ``note`` (an event), ``hold`` or
    ``unload`` (the test stops at once so, every valve holding or every channel unloading
    keeping the load ratios). ``channels`` where it was found, the strongest first."""

    monitor: str
    action: str
    channels: tuple[str, ...]
    message: str

    @property
    def kind(self) -> str:
        """The event's kind: ``trend_alarm``, ``gain_alarm``, ..."""
        return f"{self.monitor}_alarm"

    @property
    def channel(self) -> str | None:
        """The event's channel: the channels, comma-separated."""
        return ",".join(self.channels) or None

    def event(self) -> tuple[str, str | None, str]:
        return self.kind, self.channel, self.message


def fed(record: FlightRecord, timing_final: bool) -> bool:
    """Whether the trend takes the flight (module docstring): run whole, taken over from the
    flight before it (not a session's first, which glides in), its type's timing final."""
    return record.whole and record.piece.start_ways is None and timing_final


def flight_statistics(record: FlightRecord, delay_cycles: Sequence[int],
                      period_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flight run whole as :class:`TrendDetector` takes it: its end points, flows and planned
    flows per load case (:func:`endurance.trends.load_case_statistics` on the forces and
    commands the loop kept, the pass's feedforward the plan), up to its last load case."""
    cases = record.lead + np.asarray(record.idx, int)
    K = int(cases[-1]) + 1
    planned = record.piece.experiment.feedforward_pct
    return load_case_statistics(filled_forces(record.Y[:, :K]), record.U[:, :K], planned[:, :K],
                                cases, delay_cycles, period_s)


class TrendWatch:
    """The end-point trend of a session (module docstring)."""

    def __init__(self, detector: TrendDetector, delay_cycles: Sequence[int], period_s: float,
                 written: dict[str, str] | None = None) -> None:
        self.detector = detector
        self.delays = list(delay_cycles)
        self.T = float(period_s)
        self._written = dict(written or {})

    @classmethod
    def for_session(cls, test: EnduranceTest, journal: Journal) -> "TrendWatch | None":
        """The test's trend monitor (None when off), going on from the journal's state. The
        statistic goes on with the options it began with but the action, which the test file
        may change between sessions (a change of another option is an event)."""
        options = test.trend
        if options is None:
            return None
        T = test.station.period_s
        delays = [int(round(m.tau / T)) for m in test.controller.model.channels]
        states = journal.monitor_states(TREND)
        if not states:
            return cls(TrendDetector(test.station.names, test.controller.G, options), delays, T)
        try:
            detector = detector_from_rows(states)
        except (KeyError, TypeError, ValueError, ParameterError) as exc:
            raise JournalError(f"{journal.path}: the trend's state cannot be read ({exc}); the journal is "
                               "damaged") from None
        if detector.names != list(test.station.names):
            raise JournalError(f"{journal.path}: the trend's state is of the channels {', '.join(detector.names)}")
        changed = [f.name for f in fields(options) if f.name != "action"
                   and getattr(options, f.name) != getattr(detector.options, f.name)]
        if changed:
            journal.add_event("trend_note", "[monitor.trend] " + ", ".join(
                f"{k} = {getattr(options, k)!r}" for k in changed) + " changed since the trend began; it goes "
                "on as it began (" + ", ".join(f"{k} = {getattr(detector.options, k)!r}" for k in changed) + ")")
        detector.options = replace(detector.options, action=options.action)
        return cls(detector, delays, T, states)

    def flight(self, record: FlightRecord, timing_final: bool) -> tuple[MonitorStep, MonitorAlarm | None]:
        """Feed a flight done (module docstring): its step for the journal and its alarm."""
        if not fed(record, timing_final):
            return MonitorStep(), None
        det = self.detector
        try:
            E, F, P = flight_statistics(record, self.delays, self.T)
            found = det.add_flight(record.number, record.piece.slot.flight_type, E, F, P)
        except ParameterError as exc:
            return MonitorStep(events=[("trend_note", None, f"flight {record.number} was not added to the "
                                                            f"trend: {exc}")]), None
        row = det.history.pop()
        det.history.clear()                 # the journal keeps the history, not the session
        step = MonitorStep(self._changed(), [(TREND, record.number, 0, _row_json(row.to_dict()))])
        alarm = None
        if found is not None:
            alarm = MonitorAlarm(TREND, found.action, tuple(found.channels),
                                 f"{found.message()}: {ACTION_TEXT[found.action]}")
            step.events.append(alarm.event())
        return step, alarm

    def _changed(self) -> dict[str, str]:
        rows = detector_rows(self.detector)
        changed = {k: v for k, v in rows.items() if self._written.get(k) != v}
        self._written.update(changed)
        return changed


#: what an inspection found, as ``stand test resume --inspected | --repaired`` says it
INSPECTED, REPAIRED = "inspected", "repaired"


def after_inspection(test: EnduranceTest, journal: Journal, found: str | None) -> str | None:
    """Before a session resumes: what the inspection after the trend's alarm found.

    An alarm stays latched (its channels untested) until the operator says what the inspection
    found: ``inspected`` (nothing to repair: every statistic from 0, the alarmed channels watched
    again against their baselines; a crack still there alarms again) or ``repaired`` (the
    structure is a new one: every flight type's baseline is learnt again, no alarm until a type
    is armed again; also after an inspection stop without an alarm). A test the trend's alarm
    stopped (hold or unload) and still latched is not resumed without either (ParameterError
    naming the channels). The answer is journalled (its state and a ``trend_acknowledged``
    event, one transaction); returns the event's text (None: nothing done)."""
    flag = f"--{found}" if found else ""
    if test.trend is None:
        if found:
            raise ParameterError(f"{flag}: the test watches no end-point trend ([monitor.trend]); leave it out")
        return None
    detector, latched = _latched(journal)
    if found is None:
        waiting = awaiting_inspection(journal)
        if waiting:
            raise ParameterError(
                f"{journal.testdir}: the test stopped for the trend's alarm on {', '.join(waiting)}; say what the "
                f"inspection found: resume --{INSPECTED} (nothing to repair: {', '.join(waiting)} watched "
                f"again against the baseline) or --{REPAIRED} (every flight type's baseline learnt again)")
        return None
    if found == INSPECTED and not latched:
        raise ParameterError(f"{flag}: no trend alarm is on (it acknowledges one); leave it out, or "
                             f"--{REPAIRED} after a repair")
    if detector is None:                       # nothing learnt yet: nothing to learn again
        text = "repaired before the trend learnt anything: nothing to learn again"
    else:
        detector.acknowledge(relearn=found == REPAIRED)
        on = f" after the alarm on {', '.join(latched)}" if latched else ""
        text = (f"inspected{on}: nothing to repair; every channel watched again against its baseline, "
                "the statistics from 0" if found == INSPECTED else
                f"repaired{on}: every flight type's baseline is learnt again (the structure is a new "
                "one); no alarm until a type is armed again")
    step = MonitorStep(detector_rows(detector) if detector is not None else {},
                       events=[("trend_acknowledged", ",".join(latched) or None, text)])
    journal.record_monitors(step, journal.flights_done or None)
    return text


def awaiting_inspection(journal: Journal) -> list[str]:
    """The channels of the trend's alarm that stopped the test (hold or unload), still latched: a
    resume waits for what the inspection found (:func:`after_inspection`). [] if none."""
    return _latched(journal)[1] if (journal.reason or "").startswith(MONITOR_ALARM) else []


def _latched(journal: Journal) -> tuple[TrendDetector | None, list[str]]:
    """The trend's detector as the journal holds it (None: nothing learnt yet) and its latched
    channels."""
    states = journal.monitor_states(TREND)
    if TREND not in states:
        return None, []
    detector = detector_from_rows(states)
    return detector, [n for n, on in zip(detector.names, detector.latched.any(axis=0)) if on]


def detector_rows(detector: TrendDetector) -> dict[str, str]:
    """:meth:`TrendDetector.state` as the journal's rows: ``trend`` and ``trend.type.T`` per
    flight type (JSON, floats exact; the types' order kept: the thresholds mix them in it)."""
    state = detector.state()
    types = state.pop("types")
    state["type_order"] = list(types)
    rows = {TREND: json.dumps(state)}
    rows.update({TREND_TYPE + t: json.dumps(b) for t, b in types.items()})
    return rows


def detector_from_rows(rows: dict[str, str]) -> TrendDetector:
    """The detector :func:`detector_rows` wrote."""
    state = json.loads(rows[TREND])
    order = state.pop("type_order")
    state["types"] = {t: json.loads(rows[TREND_TYPE + t]) for t in order}
    return TrendDetector.from_state(state)


def _row_json(row: dict) -> str:
    """A history row for plots: its floats to 6 significant digits (the state is exact)."""
    def short(v):
        if isinstance(v, float):
            return float(f"{v:.6g}")
        if isinstance(v, list):
            return [short(x) for x in v]
        return v
    return json.dumps({k: short(v) for k, v in row.items()}, separators=(",", ":"))


class GainWatch:
    """The gain monitor of a session (module docstring): the monitor the flights' passes share,
    and its step at each flight's end (in the control loop: a few numbers per channel and the
    blocks closed since)."""

    def __init__(self, monitor, recorded: bool = False) -> None:
        self.monitor = monitor
        #: the monitor's alarm is in the journal already
        self.recorded = recorded

    @classmethod
    def for_session(cls, test: EnduranceTest, journal: Journal) -> "GainWatch | None":
        options = test.gain.options()
        if options is None:
            return None
        from loading.gain_monitor import GainMonitor
        monitor = GainMonitor.for_controller(test.controller, test.station.period_s, options)
        text = journal.monitor_states(GAIN).get(GAIN)
        if text:
            try:
                monitor.restore(json.loads(text))
            except (KeyError, TypeError, ValueError, ParameterError) as exc:
                raise JournalError(f"{journal.path}: the gain monitor's state cannot be read ({exc}); the "
                                   "journal is damaged") from None
        return cls(monitor, monitor.alarm is not None)

    def step(self, flight: int) -> tuple[MonitorStep, MonitorAlarm | None]:
        """Its state now, the blocks closed since the last step as rows of ``flight``, and its
        alarm once."""
        m = self.monitor
        rows = []
        for i, (name, c) in enumerate(zip(m.names, m.channels)):
            rows += [(GAIN, flight, b.index * m.n + i, json.dumps({"channel": name, **b.to_dict()}))
                     for b in c.blocks]
            c.blocks.clear()
        step = MonitorStep({GAIN: json.dumps(m.state())}, rows)
        alarm = None
        if m.alarm is not None and not self.recorded:
            self.recorded = True
            action = m.options.action
            alarm = MonitorAlarm(GAIN, action, (m.names[m.alarm_channel],),
                                 f"gain {m.alarm[0]}: {m.alarm[1]}: {ACTION_TEXT[action]}")
            step.events.append(alarm.event())
        return step, alarm
