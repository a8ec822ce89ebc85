r"""Flights back to back: the station experiment of an endurance test.

One gateway run per session (a start or a resume until a stop, the target or a kill) plays
the flight sequence flight after flight. Each flight is one pass of the load experiment
(:class:`gateway.load_experiment.LoadProgramme`, its feedforward, plans, law and guards), a
**piece** (:class:`FlightPiece`): the flight type's programme with its peak/valley corrections,
prepared ahead on another thread (:mod:`endurance.run`). Flights start and end at the ground
level; a piece ends at its last sample (no unload) and the next one takes over from it without
an approach: its lead-in is the last :func:`lead_in_samples` of the piece before (the landing
into the ground level), which carries the next flight's first commands, due a delay before it
takes off, as a pre-roll does, and the feedback's integral and the way every rod last moved are
carried on (:meth:`LoadProgramme.begin_handover`).

**The session's first piece glides in.** Every valve first holds (a zero command) for
:data:`SETTLE_S`, so what was commanded before the session has acted (in lockstep a stand
stopped between two sessions keeps the last commands of the one before in its delay line: they
act in the next one's first cycles). Its lead-in (:func:`glide_in`) starts at the forces found
then: held there, then along the straight line to the first load
case's levels (every force in the same haversine of time: the ratio-keeping line) at
:data:`GLIDE_RATE_KGF_S`, so the line is planned as the flights are, its feedforward through the
model's inverse and each valve's first way the one its plan starts with (the way of the flow
that holds the forces). It is made on the planner's thread from those forces while every valve
holds (a zero command), then taken over like any piece. On a start it glides into the flight's
first load case; on a resume into the load case before the interrupted one, whose segment is
then run again. (The load experiment's own approach, a P loop settling on a tolerance with each
valve moving one way, stopped ``set_point_not_reached`` when it began at a held ground level
with the rods' last way unknown: a 90 kgf line of 0.14 s, a reversal boost it does not plan
threw a coupled channel 50 kgf off, and its hold could not bring it back.)

**Load cases.** Every channel's force and command are kept per flight (:class:`FlightRecord`,
on the global cycle count). A load case's end point is judged as the tracking report judges a
turning point (:mod:`loading.report`): a channel's peak (valley) is the largest (smallest) force
from half way after the load case before to half way before the one after, any other level the
force at the load case's moment; its flow is the mean valve command over the segment that
arrived at it (%, what moved the force there: a softer structure needs more). A load case is
handed to the ``sink`` once its window has passed; the flight's last (its ground level, at the
moment it is reached) also ends the flight (``flight_done``). The sink (the journal's writer
thread) must not block: this runs in the control loop.

**Stops.** ``stop`` is read every cycle: ``after_flight`` lets the piece running finish (no
hand-over), then the run ends and the valves hold at the ground level; ``at_once`` aborts with
its action: ``hold`` at once, or ``unload`` (every channel unloads keeping the load ratios: the
loop's unload, :mod:`gateway.unload`) after a halt: every valve at the flows that hold the
forces for the largest delay and :data:`HALT_S`, while the commands already sent act. The unload
then starts from forces that stand still instead of a programme that goes on moving for a
delay (a gust at 6000 kgf/s moved outer 130 kgf off the ratios of where the unload began in its
first 60 ms: 2.7 % of its range). The target and an inspection end the run after their flight
the same way (``last_flight``).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Protocol, Sequence

import numpy as np

from gateway.experiments.rig import RigExperiment
from gateway.load_experiment import APPROACH_RATE_KGF_S, PRE_ROLL_S, LoadProgramme, held_direction
from loading.programme import Programme

from .journal import EndPoint
from .spectrum import FlightSlot

#: the reason of a run the operator stopped at once (``stand test stop --at-once``)
OPERATOR_STOP = "operator_stop"
#: extra samples of a lead-in beyond the largest delay
LEAD_MARGIN = 5
#: the glide-in's peak rate for the channel that moves the most (kgf/s; the load experiment's
#: approach line's), its shortest time (s) and how long it holds the forces found first (s)
GLIDE_RATE_KGF_S = APPROACH_RATE_KGF_S
GLIDE_MIN_S = 0.5
GLIDE_HOLD_S = 0.1
#: a hand-over begins at least this long after the landing's turning point (s): the rods'
#: reversal there is over (the example rig's reversal boost decays in 0.15 s)
HANDOVER_AFTER_TURN_S = 0.2
#: a stop at once that unloads halts first this long beyond the largest delay (s)
HALT_S = 0.1
#: every valve holds this long at a session's start before the forces are taken as found (s)
SETTLE_S = 0.2
#: the reason of a run whose first piece could not be made
NOT_PREPARED = "flight_not_prepared"


def glide_in(y0: np.ndarray, level: np.ndarray, period_s: float, delay_steps: int) -> np.ndarray:
    """(N, n): the session's first lead-in (module docstring): the forces ``y0`` held for
    :data:`GLIDE_HOLD_S` (at least the largest delay and :data:`LEAD_MARGIN`: the line's first
    commands go out then), then a haversine of every channel at once to ``level``, the channel
    that moves the most at :data:`GLIDE_RATE_KGF_S`, in at least :data:`GLIDE_MIN_S`."""
    y0, level = np.asarray(y0, float), np.asarray(level, float)
    hold = max(int(round(GLIDE_HOLD_S / period_s)), delay_steps + LEAD_MARGIN)
    span = float(np.max(np.abs(level - y0)))
    n = max(int(round(max(math.pi * span / (2 * GLIDE_RATE_KGF_S), GLIDE_MIN_S) / period_s)), 1)
    s = np.arange(n) / n
    line = y0[:, None] + (level - y0)[:, None] * (1 - np.cos(np.pi * s))[None, :] / 2
    return np.concatenate([np.repeat(y0[:, None], hold, axis=1), line], axis=1)


def first_ways(experiment: LoadProgramme) -> np.ndarray:
    """Each valve's way at a glide-in's start: that of the flow its plan begins with (the one
    that holds the forces), +1 where it plans none."""
    flows = np.asarray(experiment.ff[1.0].flow_pct, float)
    out = np.ones(flows.shape[0])
    for i, w in enumerate(flows):
        moving = np.flatnonzero(np.abs(w) > 1e-9)
        if len(moving):
            out[i] = 1.0 if w[moving[0]] > 0 else -1.0
    return out


def lead_in_samples(reference: np.ndarray, turning_idx: np.ndarray, delay_steps: int, period_s: float) -> int:
    """How many of a piece's last samples the next flight's piece takes as its lead-in: the
    pre-roll's length (:data:`PRE_ROLL_S`) within the last segment (the landing) and beginning
    at least :data:`HANDOVER_AFTER_TURN_S` after the landing began, but at least the largest
    delay plus :data:`LEAD_MARGIN` (the next flight's first commands go out then), and never
    the whole reference. (A hand-over at the landing's turning point, as a short landing of a
    time-scaled flight put it, planned the next piece's first commands from a standing start
    while the rods were reversing: the turning point before it missed by 4-7 % of a range.)"""
    last = int(turning_idx[-1] - turning_idx[-2])
    n = min(int(round(PRE_ROLL_S / period_s)), last - int(round(HANDOVER_AFTER_TURN_S / period_s)))
    n = max(n, delay_steps + LEAD_MARGIN)
    return int(min(n, reference.shape[1] - 1))


def lead_in_of(experiment: LoadProgramme) -> int:
    """:func:`lead_in_samples` of a pass: how much of it the next flight's piece takes over."""
    T = experiment.period_s
    delay = max(int(round(m.tau / T)) for m in experiment.controller.model.channels)
    return lead_in_samples(experiment.reference, experiment.commanded.turning_idx + experiment.lead, delay, T)


@dataclass
class FlightPiece:
    """A flight as it is run: one pass of the load experiment.

    Attributes
    ----------
    slot : the flight's number, block, position and type
    nominal : the flight type's programme (the levels asked, before compensation)
    first_case : the flight's load case (0-based) the piece's programme starts at (0, or on a
        resume the one before the interrupted one)
    experiment : the pass (its ``commanded`` programme is ``nominal`` with the corrections,
        from ``first_case`` on)
    begun : the journal has the flight begun already (a resumed flight)
    commit_from : the first of its load cases to hand to the journal (on a resume the
        interrupted one)
    handover_at : main-phase cycles it runs before the next flight's piece takes over
    start_ways : a session's first piece (a glide-in): each valve's way at its start
    timing_final : its type's timing was final when it was prepared (no longer searched:
        :mod:`endurance.timing`)
    compensation : its type's compensation as it was prepared, the corrections it runs with
        (its type learns from them: the flight ahead may have taught it since); None: the
        type's as it is when the flight is learnt from
    """

    slot: FlightSlot
    nominal: Programme
    first_case: int
    experiment: LoadProgramme
    begun: bool = False
    commit_from: int = 0
    handover_at: int = 0
    start_ways: np.ndarray | None = None
    timing_final: bool = True
    compensation: Any = None
    #: global cycle at which its experiment began (local time 0) and its main phase's first
    #: cycle (the reference's sample 0); None until known
    c0: int | None = None
    origin: int | None = None
    final: bool = False

    @property
    def number(self) -> int:
        return self.slot.number

    @property
    def length(self) -> int:
        """Samples of its reference (lead-in or pre-roll, then the programme)."""
        return int(self.experiment.reference.shape[1])


class Pieces(Protocol):
    """Where the player gets its pieces: prepared ahead on another thread."""

    def start(self, number: int, load_case: int, begun: bool, y0: np.ndarray) -> None:
        """Begin preparing the session's first piece: flight ``number`` from load case
        ``load_case`` (0-based; ``begun``: the journal has the flight begun), gliding in from
        the forces ``y0``."""

    def ready(self, number: int) -> bool:
        """Whether flight ``number``'s piece is ready (without waiting)."""

    def request(self, number: int) -> None:
        """Begin preparing flight ``number``'s piece (again: no effect)."""

    def get(self, number: int) -> FlightPiece:
        """Flight ``number``'s piece (waits until it is ready)."""


class Sink(Protocol):
    """What the player hands over (it must not block: the control loop calls it)."""

    def begin_flight(self, record: "FlightRecord") -> None: ...

    def load_case(self, record: "FlightRecord", index: int, end_points: list[EndPoint]) -> None: ...

    def flight_done(self, record: "FlightRecord") -> None: ...

    def loading(self, info: dict[str, Any]) -> None: ...


@dataclass
class StopRequest:
    """A stop asked of the running test (set from any thread, read every cycle)."""

    after_flight: bool = False
    at_once: bool = False
    action: str = "unload"            #: at once: unload (keeping the ratios) or hold
    reason: str = OPERATOR_STOP
    message: str = "stopped at once by the operator"

    def stop_at_once(self, reason: str, message: str, action: str = "unload") -> None:
        self.reason, self.message, self.action = reason, message, action
        self.at_once = True


@dataclass
class FlightRecord:
    """One flight's forces and commands on the global cycle count, and its end points as they
    are judged (module docstring)."""

    piece: FlightPiece
    origin: int                          #: global cycle of the reference's sample 0
    Y: np.ndarray = field(repr=False)    #: (N, samples) forces, kgf
    U: np.ndarray = field(repr=False)    #: (N, samples) commands asked, %
    next_case: int = 0
    #: per load case committed: every channel's end point
    end_points: dict[int, list[EndPoint]] = field(default_factory=dict)
    closed: bool = False

    def __post_init__(self) -> None:
        p = self.piece
        e = p.experiment
        self.lead = e.lead
        self.idx = e.commanded.turning_idx
        self.kinds = p.nominal.kinds()
        self.levels = p.nominal.levels_kgf
        self.cases = self.levels.shape[1]
        self.next_case = p.commit_from

    @property
    def number(self) -> int:
        return self.piece.number

    @property
    def whole(self) -> bool:
        """The flight was run from its first load case on in one piece (what it learns from)."""
        return self.piece.first_case == 0

    def at(self, j: int) -> int:
        """The reference's sample of the flight's load case ``j``."""
        return int(self.lead + self.idx[j - self.piece.first_case])

    def due(self, j: int) -> int:
        """The reference's sample after which load case ``j``'s end points are judged."""
        p = j - self.piece.first_case
        if j == 0 or j == self.cases - 1:
            return self.at(j)
        return int(self.lead + (self.idx[p] + self.idx[p + 1]) // 2)

    def end_points_of(self, j: int) -> list[EndPoint]:
        """Every channel's end point of load case ``j`` (module docstring)."""
        p = j - self.piece.first_case
        i = self.at(j)
        lo = int(self.lead + (self.idx[p - 1] + self.idx[p]) // 2) if p >= 1 else i
        a = int(self.lead + self.idx[p - 1]) if p >= 1 else 0
        hi = self.due(j)
        names = self.piece.nominal.names
        out = []
        for c, name in enumerate(names):
            kind = self.kinds[c][j]
            y = self.Y[c]
            near = y[lo:hi + 1]
            if kind == "peak" and np.isfinite(near).any():
                reached = float(np.nanmax(near))
            elif kind == "valley" and np.isfinite(near).any():
                reached = float(np.nanmin(near))
            else:
                reached = _last_finite(y, i)
            u = self.U[c, a:i]
            flow = float(np.nanmean(u)) if np.isfinite(u).any() else None
            out.append(EndPoint(name, float(self.levels[c, j]), reached, flow))
        return out


def filled_forces(Y: np.ndarray) -> np.ndarray:
    """Forces with a skipped cycle (NaN: a real-time cycle without a reading) taken from the
    cycle before."""
    Y = np.array(Y, float)
    for row in Y:
        bad = ~np.isfinite(row)
        if bad.any() and (~bad).any():
            idx = np.where(~bad, np.arange(len(row)), 0)
            np.maximum.accumulate(idx, out=idx)
            row[:] = row[idx]
    return Y


def _last_finite(y: np.ndarray, i: int) -> float:
    """``y[i]``, or the last finite value before it (a real-time cycle that was skipped)."""
    finite = np.flatnonzero(np.isfinite(y[:i + 1]))
    return float(y[finite[-1]]) if len(finite) else math.nan


def line_deviation(Y: np.ndarray, start: np.ndarray, end: np.ndarray,
                   ranges_kgf: np.ndarray) -> tuple[float, int, float]:
    """How far forces ``Y`` (K, N) strayed from the straight line from ``start`` to ``end``
    (each row's point of the line by least squares, ``s = (y − y₀)·(L − y₀)/|L − y₀|²`` within
    [0, 1]): the largest deviation as % of its channel's range, the channel and the kgf."""
    Y = np.atleast_2d(np.asarray(Y, float))
    d = np.asarray(end, float) - np.asarray(start, float)
    norm = float(d @ d)
    if not len(Y) or norm <= 0:
        return 0.0, 0, 0.0
    s = np.clip((Y - start) @ d / norm, 0.0, 1.0)
    dev = Y - (start[None, :] + s[:, None] * d[None, :])
    pct = 100 * np.abs(dev) / np.maximum(ranges_kgf, 1e-9)[None, :]
    k, i = np.unravel_index(int(np.nanargmax(pct)), pct.shape)
    return float(pct[k, i]), int(i), float(dev[k, i])


class FlightPlayer(RigExperiment):
    """Flights back to back in one run (module docstring).

    Parameters
    ----------
    names : the station's channels
    flight, load_case, begun : where the session begins (the journal's position: the flight,
        its next load case, 0-based, and whether the journal has the flight begun)
    pieces : the pieces, prepared on another thread
    sink : where begun flights, load cases, done flights and the start of loading go
    last_flight : the run ends once this flight is done (the target, an inspection)
    stop : a stop asked from outside
    period_s : the loop's period
    max_command_pct : the controller's command limit
    wait_first : wait in the first cycle until the first piece is made (lockstep: the stand does
        not move meanwhile); else every valve holds (a zero command) until it is
    """

    name = "endurance"
    #: no one programme's clock: each flight's is its piece's (gateway.offline reads this)
    programme_start_s = None

    def __init__(self, names: Sequence[str], flight: int, load_case: int, begun: bool, pieces: Pieces,
                 sink: Sink, last_flight: int, stop: StopRequest, period_s: float,
                 max_command_pct: float = 100.0, wait_first: bool = False) -> None:
        self.names = list(names)
        self.n = len(self.names)
        self.first = (int(flight), int(load_case), bool(begun))
        self.piece: FlightPiece | None = None
        self.pieces = pieces
        self.sink = sink
        self.last_flight = int(last_flight)
        self.stop = stop
        self.T = float(period_s)
        self.max_command_pct = max_command_pct
        self.wait_first = wait_first
        self.records: list[FlightRecord] = []
        self.done = False
        self.force_limits = [math.inf] * self.n
        self.abort: tuple[str, str] | None = None
        self.abort_channel: int | None = None
        self.abort_action = "hold"
        #: wall-clock times: the run began, the first piece began (its glide), the programme began
        self.began_at = self.main_at = self.loading_at = None
        self.y0: np.ndarray | None = None
        self._halt_until: int | None = None
        #: how long the hand-overs waited for a piece not ready yet (s)
        self.waited_s = 0.0

    @property
    def number(self) -> int:
        """The flight of the piece running (or about to)."""
        return self.piece.number if self.piece is not None else self.first[0]

    # -- what the loop and the gateway read ---------------------------------------------------------
    @property
    def duration_s(self) -> float:
        return self.piece.experiment.main_duration_s if self.piece is not None else 0.0

    @property
    def max_duration_s(self) -> float:
        return self.duration_s + 10.0

    def params(self) -> dict[str, Any]:
        flight, case, _ = self.first
        return {"first_flight": flight, "first_load_case": case + 1, "last_flight": self.last_flight,
                "channels": self.names}

    def configure_rig(self, period_s: float, force_limits_kgf: Sequence[float]) -> None:
        self.T = float(period_s)
        self.force_limits = list(force_limits_kgf)

    def begin_rig(self, y0: Sequence[float]) -> None:
        self.abort = None
        self.abort_channel = None
        self.began_at = time.time()
        self.y0 = None

    def _found(self, c: int, ys: Sequence[float]) -> bool:
        """Whether the forces are found (the settling hold is over): then the first piece is
        asked for, gliding in from them."""
        if self.y0 is not None:
            return True
        if c * self.T < SETTLE_S:
            return False
        self.y0 = np.asarray(ys, float)
        self.pieces.start(*self.first, self.y0)
        return True

    def finished_rig(self, t: float, ys: Sequence[float]) -> bool:
        return self.done

    # -- every cycle --------------------------------------------------------------------------------
    def step_rig(self, t: float, ys: Sequence[float]) -> tuple[list[float], list[float]]:
        c = int(round(t / self.T))
        stop = self.stop
        if stop.at_once:
            return self._halt(c, stop)
        piece = self.piece
        if piece is None:
            if not self._found(c, ys) or not self.wait_first and not self.pieces.ready(self.first[0]):
                return [0.0] * self.n, [math.nan] * self.n         # every valve holds meanwhile
            piece = self._take(self.first[0], c, None)
            if piece is None:
                return [0.0] * self.n, [math.nan] * self.n
        if stop.after_flight and self.last_flight > piece.number:
            self.last_flight = piece.number
        if c - piece.origin >= piece.handover_at and not piece.final:
            piece = self._hand_over(piece, c)
            if piece is None:
                return [0.0] * self.n, [math.nan] * self.n
        e = piece.experiment
        u, r = e.step_rig((c - piece.c0) * self.T, ys)
        if e.abort is not None:
            self.abort, self.abort_channel, self.abort_action = e.abort, e.abort_channel, e.abort_action
            return u, r
        for rec in self.records:
            i = c - rec.origin
            if 0 <= i < rec.Y.shape[1]:
                rec.Y[:, i] = ys
                rec.U[:, i] = u
        if self.loading_at is None and c - piece.origin >= piece.experiment.lead:
            self._loading_began()
        self._judge(c)
        return u, r

    def _halt(self, c: int, stop: StopRequest) -> tuple[list[float], list[float]]:
        """A stop at once (module docstring): hold now, or halt, then unload."""
        piece = self.piece
        if stop.action != "unload" or piece is None:
            return self._stop(stop.reason, stop.message, stop.action)
        e = piece.experiment
        if self._halt_until is None:
            delay = max(m.tau for m in e.controller.model.channels)
            self._halt_until = c + int(round((delay + HALT_S) / self.T))
        if c < self._halt_until:
            return e.hold_flows.tolist(), [math.nan] * self.n
        return self._stop(stop.reason, stop.message, stop.action)

    def _stop(self, reason: str, message: str, action: str = "hold") -> tuple[list[float], list[float]]:
        self.abort_action = action
        self.abort = (reason, message)
        return [0.0] * self.n, [math.nan] * self.n

    def _take(self, number: int, c: int, before: FlightPiece | None) -> FlightPiece | None:
        """Flight ``number``'s piece begins at cycle ``c``: taking over from ``before``, or
        (None) the session's first, gliding in. None if it could not be made (the run stops)."""
        began = time.monotonic()
        try:
            new = self.pieces.get(number)
        except Exception as exc:
            self._stop(NOT_PREPARED, f"flight {number} could not be prepared ({type(exc).__name__}: {exc}); "
                                     "every valve holds")
            return None
        self.waited_s += time.monotonic() - began if before is not None else 0.0
        e = new.experiment
        e.configure_rig(self.T, self.force_limits)
        if before is None:
            e.begin_handover(new.start_ways, np.zeros(self.n))
            self.main_at = time.time()
        else:
            rec = self.records[-1]
            k = c - rec.origin
            sent = np.nan_to_num(rec.U[:, :k])
            ways = np.array([held_direction(sent[i], w)[-1] if k else w
                             for i, w in enumerate(before.experiment.way)])
            e.begin_handover(ways, before.experiment.law.integral.copy())
        new.c0 = new.origin = c
        new.handover_at = new.length - lead_in_of(e)
        self.piece = new
        shape = (self.n, new.length)
        self.records.append(FlightRecord(new, c, np.full(shape, np.nan), np.full(shape, np.nan)))
        if before is None and new.number < self.last_flight:
            self.pieces.request(new.number + 1)
        return new

    def _hand_over(self, piece: FlightPiece, c: int) -> FlightPiece | None:
        """The next flight's piece takes over at cycle ``c`` (its lead-in is this piece's rest),
        or this one runs to its end when it flies the last flight of the run."""
        if piece.number + 1 > self.last_flight:
            piece.final = True
            return piece
        return self._take(piece.number + 1, c, piece)

    def _loading_began(self) -> None:
        """The programme of the session's first piece begins (its glide-in is done)."""
        self.loading_at = time.time()
        rec = self.records[0]
        piece = rec.piece
        glide = rec.Y[:, :piece.experiment.lead].T
        info: dict[str, Any] = {"began_at": self.began_at, "main_at": self.main_at,
                                "loading_at": self.loading_at, "flight": piece.number,
                                "load_case": piece.first_case + 1, "forces_found_kgf": self.y0.tolist(),
                                "glide_cycles": piece.experiment.lead, "settle_s": SETTLE_S}
        if self.n > 1:
            ranges = np.array([max(float(np.ptp(p.r_kgf)), 1.0) for p in piece.nominal.channels])
            target = piece.experiment.reference[:, piece.experiment.lead]
            pct, i, kgf = line_deviation(glide, self.y0, target, ranges)
            info["approach_deviation"] = {"pct_of_range": pct, "channel": self.names[i], "kgf": kgf}
        self.sink.loading(info)

    def _judge(self, c: int) -> None:
        """Hand over every load case whose window has passed; close the flights done."""
        for rec in list(self.records):
            while rec.next_case < rec.cases and c - rec.origin >= rec.due(rec.next_case):
                j = rec.next_case
                if j == 0 and not rec.piece.begun:
                    self.sink.begin_flight(rec)
                rec.end_points[j] = rec.end_points_of(j)
                self.sink.load_case(rec, j, rec.end_points[j])
                rec.next_case = j + 1
            if rec.next_case >= rec.cases and not rec.closed:
                rec.closed = True
                self.records.remove(rec)
                self.sink.flight_done(rec)
                if rec.number >= self.last_flight:
                    self.done = True
                elif self.piece.number + 1 <= self.last_flight:
                    self.pieces.request(self.piece.number + 1)
