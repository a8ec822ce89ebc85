r"""Each flight type's timing in a running test: its rate's, a schedule it replays, or segment
durations searched by time scaling flight after flight of the type.

A test file's ``[time_scaling] accuracy_pct`` times every flight type without a ``schedule`` of
its own to the valves, as ``stand load --accuracy`` times a programme pass after pass
(:mod:`loading.time_scaling`): each flight of the type run whole is a pass. After it, its
tracking report (the one its compensation learns from) gives each segment's verdict (land,
hold, miss: the worst channel's at the load case it arrives at), and the type's
:class:`~loading.time_scaling.TimeScaler` sets the durations of its next flight, floored at the
segments' valve-limited minimum (:mod:`loading.minimum_time`); a segment whose feedforward then
needs more than the valves give is stretched first (:func:`gateway.load.stretched_pass`). The
search ends (**found**) at the first flight that met the accuracy with (nearly) every segment
settled, or after ``search_flights`` flights of the type: then the fastest durations whose flight
met the accuracy are kept for the rest of the test (none met it: the last tried, noted).

**The landing** is judged too: flights are flown back to back, so a flight's last load case (the
ground level) is where the next one takes off, a valley of the sequence though its own flight
ends there. Its segment's verdict is the worse of the scaler's (a last segment arriving at no
peak or valley lands) and its ground level's error against the accuracy's bands, and a flight
whose landing misses does not meet the accuracy. (Without it the landings went to their floor
on the example rig, where the ground was missed by 100 kgf, 2 % of outer's range, and every
flight after it began off its ground level: its peaks 15-30 kgf high.)

A flight prepared before the flight of its type that changed the durations ran the old ones:
its report is not a verdict on the new durations and is not used (pieces are prepared one flight
ahead, :mod:`endurance.run`).

**Journalled** per type (``schedules``, :meth:`endurance.journal.Journal.finish_flight`, in the
transaction that stores the flight's compensation): a schedule file's text (what ``stand load
--schedule`` replays: the durations the type's next flight uses) followed by a ``[search]``
table with the search's state (the scaler's per segment, the fastest durations that met the
accuracy, the flights searched). A resumed session goes on from there, so each type keeps its
own schedule through every stop, as it keeps its compensation.

The end-point trends (:mod:`endurance.trends`) learn a type's flows only from flights whose
timing is final (:meth:`FlightTiming.final`): a searched segment's flows move with its speed
(the reversal boosts meet it differently), which the trend's baseline would take for a change
of the structure.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass

import numpy as np

from core.errors import ParameterError
from loading.programme import Programme
from loading.time_scaling import HOLD, LAND, MISS, Schedule, ScalingOptions, TimeScaler, meets

from .testfile import EnduranceTest

RATE, SCHEDULE, SEARCH, FOUND = "rate", "schedule", "search", "found"


@dataclass
class TypeTiming:
    """One flight type's timing: ``mode`` (rate, schedule, search or found) and the segment
    durations its next flight uses (None: its rate's)."""

    mode: str
    durations: np.ndarray | None = None
    scaler: TimeScaler | None = None
    #: the fastest durations whose flight met the accuracy
    best: np.ndarray | None = None
    #: flights of the search so far
    flights: int = 0
    note: str = ""


class FlightTiming:
    """Every flight type's timing for a session (module docstring); ``schedules`` the journal's
    texts per type (:meth:`endurance.journal.Journal.schedule`), ``command_limit_pct`` the
    valves' (with the controller's) for the minimum."""

    def __init__(self, test: EnduranceTest, schedules: dict[str, str | None] | None = None,
                 command_limit_pct: float = 100.0) -> None:
        self.test = test
        self.controller = test.controller
        self.limit = min(self.controller.command_limit_pct, command_limit_pct)
        scaling = test.time_scaling
        self.options: ScalingOptions | None = scaling.options() if scaling is not None else None
        self.search_flights = scaling.search_flights if scaling is not None else 0
        self.types: dict[str, TypeTiming] = {}
        for name, ft in test.flight_types.items():
            if ft.schedule is not None:
                self.types[name] = TypeTiming(SCHEDULE, np.asarray(ft.schedule.durations_s, float))
            elif scaling is None:
                self.types[name] = TypeTiming(RATE)
            else:
                text = (schedules or {}).get(name)
                # a search not begun starts at the type's rate: its scaler is made at its first flight
                self.types[name] = self._restored(name, text) if text else TypeTiming(SEARCH)
        self._minimum: dict[str, np.ndarray] = {}

    # -- what the planner asks ---------------------------------------------------------------------
    def programme(self, flight_type: str) -> Programme:
        """The type's programme (its levels as the test file gives them) with the durations its
        next flight uses."""
        base = self.test.flight_types[flight_type].programme
        tt = self.types[flight_type]
        if tt.durations is None:
            return base
        return base.with_durations(tt.durations, f"{base.source}, {tt.mode} ({float(np.sum(tt.durations)):.2f} s)")

    def final(self, flight_type: str) -> bool:
        """The type's timing no longer changes (its rate, a schedule, or its search ended)."""
        return self.types[flight_type].mode != SEARCH

    # -- after a flight run whole ----------------------------------------------------------------------
    def learn(self, flight_type: str, ran: Programme, report, t_s: np.ndarray, y_kgf: np.ndarray,
              landing_error_pct: float) -> str | None:
        """A flight of ``flight_type`` ran ``ran`` (its programme as flown, before compensation)
        and was reported as ``report`` (:func:`loading.report.tracking_report` on its forces
        ``y_kgf`` at the programme's times ``t_s``), its ground level at the end reached within
        ``landing_error_pct`` (% of the range, the worst channel): the search's step (module
        docstring). Returns the type's journal text when it changed, else None."""
        tt = self.types[flight_type]
        if tt.mode != SEARCH:
            return None
        if tt.scaler is None:
            base = self.test.flight_types[flight_type].programme
            tt.scaler = TimeScaler(base, self.minimum(flight_type), base.segment_durations_s, self.options)
        scaler = tt.scaler
        T = ran.period_s
        if not np.allclose(ran.segment_durations_s, scaler.durations, atol=T / 2):
            return None                       # prepared before the durations last changed
        settled = scaler.all_settled
        verdicts = scaler.station_verdicts(ran, report, t_s, y_kgf)
        landing = self._landing(landing_error_pct)
        verdicts[-1] = max(verdicts[-1], landing, key=(LAND, HOLD, MISS).index)
        ok = meets(report, self.options.accuracy_pct) and landing != MISS
        tt.flights += 1
        if ok and (tt.best is None or ran.duration_s < float(np.sum(tt.best)) - T / 2):
            tt.best = scaler.durations.copy()
        if ok and settled:
            self._found(tt, f"met {self.options.accuracy_pct:g} % with its segments settled after "
                            f"{tt.flights} flight(s)")
        elif tt.flights >= self.search_flights:
            self._found(tt, f"searched {tt.flights} flights")
        else:
            scaler.update(verdicts)
            self._fit_to_valves(flight_type, tt)
            tt.durations = scaler.durations.copy()
        return self.text(flight_type)

    def _landing(self, error_pct: float) -> str:
        """The ground level's verdict: its error against the accuracy's bands (as a turning
        point's, :mod:`loading.time_scaling`)."""
        o = self.options
        if not np.isfinite(error_pct) or error_pct > o.miss_share * o.accuracy_pct:
            return MISS
        return HOLD if error_pct > o.land_share * o.accuracy_pct else LAND

    def _found(self, tt: TypeTiming, why: str) -> None:
        tt.mode = FOUND
        if tt.best is not None:
            tt.durations, tt.note = tt.best.copy(), why
        else:
            tt.durations = tt.scaler.durations.copy()
            tt.note = f"{why}; no flight met the accuracy: the last durations tried are kept"

    def _fit_to_valves(self, flight_type: str, tt: TypeTiming) -> None:
        """The scaler's new durations with every segment the valves cannot follow lengthened
        (:func:`gateway.load.stretched_pass`); if that is not enough, the search ends on the
        fastest durations that met the accuracy (never a flight the valves cannot follow)."""
        from gateway.load import stretched_pass, segment_peaks
        from gateway.load_experiment import LoadProgramme
        from loading.minimum_time import FEEDFORWARD_SHARE
        base = self.test.flight_types[flight_type].programme
        period = self.test.station.period_s
        try:
            _, experiment = stretched_pass(base, tt.scaler, tt.flights,
                                           lambda p: LoadProgramme(p, self.controller, unload=False),
                                           segment_peaks, FEEDFORWARD_SHARE * self.limit)
            experiment.check(period, self.test.station.force_limits_kgf, self.limit)
        except ParameterError as exc:
            if tt.best is None:
                tt.best = base.segment_durations_s.copy()      # its rate's: checked before the test
            self._found(tt, f"the valves cannot follow the next durations ({exc})")
            tt.scaler.durations = tt.durations.copy()

    # -- the journal ---------------------------------------------------------------------------------
    def text(self, flight_type: str) -> str:
        """A searched type's journal text (module docstring): a schedule file, then ``[search]``."""
        tt = self.types[flight_type]
        base = self.test.flight_types[flight_type].programme
        schedule = Schedule.of(base, tt.durations, self.options.accuracy_pct, float(np.sum(self.minimum(flight_type))),
                               tt.mode == FOUND and tt.best is not None and np.allclose(tt.durations, tt.best),
                               [tt.note] if tt.note else [])
        search = {"mode": tt.mode, "flights": tt.flights,
                  "best": [] if tt.best is None else tt.best.tolist(), **tt.scaler.state()}
        return schedule.to_toml() + "\n[search]\n" + "".join(
            f"{k} = {_toml_value(v)}\n" for k, v in search.items())

    def minimum(self, flight_type: str) -> np.ndarray:
        """Each segment's valve-limited minimum (s) by the controller's model (computed once,
        when first needed: half a second a type)."""
        if flight_type not in self._minimum:
            from loading.minimum_time import minimum_durations_s, programme_flow_limit
            base = self.test.flight_types[flight_type].programme
            model = self.controller.model
            self._minimum[flight_type] = np.asarray(
                minimum_durations_s(base, model, programme_flow_limit(base, model, self.limit))[0], float)
        return self._minimum[flight_type]

    def _restored(self, flight_type: str, text: str) -> TypeTiming:
        """A searched type from its journal text."""
        base = self.test.flight_types[flight_type].programme
        try:
            d = tomllib.loads(text)
            s = d["search"]
            scaler = TimeScaler.from_state(base, self.options, s)
            durations = np.asarray(d["durations_s"], float)
            best = np.asarray(s["best"], float) if s["best"] else None
            notes = d.get("notes") or [""]
            return TypeTiming(str(s["mode"]), durations, scaler, best, int(s["flights"]), notes[0])
        except (tomllib.TOMLDecodeError, KeyError, TypeError, ValueError, ParameterError) as exc:
            raise ParameterError(f"the journal's schedule of flight type {flight_type} cannot be read "
                                 f"({exc}); it was written by this test, so the journal is damaged") from None


def _toml_value(v) -> str:
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(float(v)) if isinstance(v, float) else str(v)
