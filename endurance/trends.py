r"""End-point trends: a change of the structure found, flight by flight, from the flow each
valve needs to reach its end points (issue 39: "End-point trends (cracks)").

A flight-by-flight test applies the same flight types over and over. In force control the end
points are held (compensation, feedback), so a crack does not show as a missed end point: it
shows as the **flow a valve needs to reach it**. With the rig's model ``dy/dt = G·w + Δ`` the
flows that move the forces by ``Δy`` over a segment are ``G⁻¹(Δy − Δ·T)``; a crack at
attachment i (a compliance in series there, :mod:`plant.rig`) makes them
``G⁻¹(Δy − Δ·T) + (1/f − 1)·Δy_i/G_ii·e_i``: channel i's valve needs ``1/f − 1`` more of its
own share of each step, its neighbours' valves need what they needed (3.1 % for a 3 % drop).

**What is tracked**, per channel, per flight type, per load case j of the flight: the achieved
end point ``E_ij`` (kgf: the force at the load case's moment, a short mean,
:func:`load_case_statistics`) and the flow it took, ``F_ij`` (%·s: the integral of the channel's
command over the segment into the load case, shifted by its delay so that it is the flow that
moved the force over the segment; the planned flow ``P_ij`` is the feedforward's integral over
the same cycles). Flights repeat by type, so each type has its own **baseline**: the mean end
points ``Ē`` and flows ``F̄`` over its first ``learn_flights`` flights (its flights are not
tested before), then over every quiet one too.

**The per-flight statistic**, channel i's flow excess over its baseline, in its own share of the
steps, with what the achieved end points needed taken off:

.. math::  r = F - \bar F - C\,\delta s,\qquad
           \delta s_j = (E_j - \bar E_j) - (E_{j-1} - \bar E_{j-1}),\qquad
           x_i = \frac{\sum_j r_{ij}\,u_{ij}}{\sum_j u_{ij}^2}

(``C = G⁻¹`` of the rig's model: a flight that stopped 10 kgf short of a peak needed less flow
into it and more out of it; ``u_ij = (Ē_ij − Ē_{i,j−1})/G_ii`` the baseline's own share of
each step, %·s). ``x_i`` is a fraction: 0.01, 1 % more flow than the flight type needs. Without
G the planned flows are the unit and ``C`` is each channel's own flow per kgf fitted on its
baseline (diagonal: weaker, docs/endurance.md). A crack at i moves ``x_i`` by about ``1/f − 1``
(less in the closed loop: measured 0.5-1 of it, by flight type), and a valve that loses gain
moves it too: the statistic names where more flow is needed, not why.

**The noise, and what all channels share.** Over the type's learning flights the covariance
``Σ`` of ``x`` (plus ``floor_pct²`` on the diagonal) is learned, and afterwards on every quiet
flight (no statistic on a run before it, every ``|z| < 4``; the whitening and the thresholds
are computed again after a quarter more of them): what moves every valve alike wanders further
over a test than over its first flights. That common part (supply pressure, oil temperature:
every valve's flow gain ``1 + ε``) moves ``x`` along ``b``, ``b_i = −Σ_j F̄_ij·u_ij / Σ_j
u_ij²`` (every flow of the baseline over ``1 + ε``), which is taken out of the statistic
whatever its size (``common_mode``; ``Σ⁻¹`` projected: ``Π = Σ⁻¹ − Σ⁻¹b·bᵀΣ⁻¹/(bᵀΣ⁻¹b)``).
Channel i's standardized statistic is its part that neither the others nor the common part
predict:

.. math::  z_i = \frac{(\Pi\,x)_i}{\sqrt{\Pi_{ii}\,\kappa}},
           \qquad z_i \sim N(0, 1)\ \text{intact},\qquad
           E[z_i] = \theta\,a_i,\ a_i = \sqrt{\Pi_{ii}/\kappa}

after a change of ``θ`` at channel i (the likelihood ratio's direction for a change at one
channel). ``κ = ν/χ²_{1−c}(ν)`` (``ν`` the flights in ``Σ`` less N, ``c`` the ``confidence``): the
noise taken at its ``c`` upper confidence bound, so a baseline that happened to look quiet does
not make alarms. The means ``Ē``, ``F̄`` go on averaging the quiet flights too; a mean of ``n``
flights is off by ``N(0, 1/n)`` in ``z``, a bias for the whole test, so the thresholds are set
for the mean off by its bound ``Φ⁻¹(c)/√n`` (0.23 after 30 flights; less as they add up).

**The test: a CUSUM of the log-likelihood ratio per channel and way.** For the design change
``δ`` (``shift_pct``) the flight's log-likelihood ratio is ``λ = d·z − d²/2`` with ``d = δ·a_i``
(flights of a quiet type weigh more; at least 2: a channel whose noise is over half the design
change is tuned to twice its noise, as its baseline's own error would make false alarms), and

.. math::  S_t = \max(0,\ S_{t-1} + λ_t) > h  \;\Rightarrow\;\text{alarm}

one statistic for more flow (``soften``: a crack) and, with ``sides = "both"``, one for less
(``stiffen``: a jammed part), per channel. ``h`` is set so that the **average run of intact
flights between false alarms** of all ``2N`` statistics together is at least
``false_alarm_flights`` (10⁵): each statistic's is ``2N`` times that, computed exactly for the
flight types' mixture of ``d`` (a Markov chain on ``S``, Brook & Evans 1972: :func:`cusum_arl`).
The delay for a change is the same chain with the increments' mean moved
(:meth:`TrendDetector.expected_delay`).

**The alarm** names the channels whose statistic crossed (the strongest first), when their run
began (the change's flight, estimated), their own flow excess since then and the action
(``note``, ``hold``, ``unload``: the running test acts on it). Taking the common part out shows
one channel's change a little, the other way, on the others (a crack at inner, 13σ, moved
root's statistic 4σ less-flow): a statistic that crossed is named only if its channel's own
excess over the run, ``x_i − b_i·median_k(x_k/b_k)`` (a median: one channel's change does not
move it; 3 channels or more), moved its way by at least half the design change; else it starts
again from 0. A channel's alarm stays latched until :meth:`TrendDetector.acknowledge` (after the
inspection; ``relearn=True`` after a repair, the structure is then a new baseline), and while
it is on, the other channels are tested without it (its excess given no weight).

**Journal.** :meth:`TrendDetector.state` is the whole state as JSON-ready numbers (floats
round-trip exactly), :meth:`TrendDetector.from_state` continues the same statistic;
:attr:`TrendDetector.history` has a :class:`FlightTrend` per flight (for plots), its
``to_dict`` the journal's row.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.special import ndtr, ndtri
from scipy.stats import chi2
from threadpoolctl import threadpool_limits

from core.errors import ParameterError

ACTIONS = ("note", "hold", "unload")
SIDES = ("both", "soften")
#: the state's format (:meth:`TrendDetector.state`)
STATE_VERSION = 1
#: the Markov chain's states over [0, h] (ARL to about 0.1 %)
CHAIN_STATES = 120
#: a tested flight adds to its type's noise when no statistic was on a run before it and none
#: of its standardized statistics is beyond this
QUIET_Z = 4.0
#: the design change is tuned to at least this many times a channel's noise: nearer the noise,
#: the baseline's own error (its mean from n flights, 1/√n of the noise, fixed for the test)
#: would make false alarms (at a change of one noise, a bias of 0.3 of it cut the run length
#: between false alarms from 8·10⁵ to hundreds)
MIN_D = 2.0
#: the variance (a share², 1000 %) a channel's excess is given while its alarm is on: no
#: information, so the others' statistics do not read its change
LATCHED_VARIANCE = 100.0


# ------------------------------------------------------------------------------------------
# the CUSUM's run length
# ------------------------------------------------------------------------------------------
def cusum_arl(h: float, means: Sequence[float], stds: Sequence[float],
              weights: Sequence[float] | None = None, states: int = CHAIN_STATES) -> float:
    """Average run length (flights) of ``S_t = max(0, S_{t−1} + λ_t)`` from 0 until ``S > h``,
    the increments ``λ`` i.i.d., a mixture of normals ``N(means_c, stds_c²)`` with ``weights``
    (the flight types): a Markov chain on ``S`` over ``states`` cells of [0, h] (Brook & Evans,
    Biometrika 59, 1972)."""
    m = np.asarray(means, float)
    s = np.asarray(stds, float)
    w = np.ones(len(m)) if weights is None else np.asarray(weights, float)
    w = w / w.sum()
    live = s > 0
    if not live.any():
        return math.inf

    def cdf(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, float)
        out = (w[live] * ndtr((x[..., None] - m[live]) / s[live])).sum(-1)
        return out + w[~live].sum() * (x >= m[~live][:1] if (~live).any() else 0.0)

    if h <= 0:
        over = 1.0 - float(cdf(0.0))
        return math.inf if over <= 0 else 1.0 / over
    cell = h / (states - 0.5)
    # P(S' ≤ upper edge of cell j | S at cell i) = cdf((j − i + 0.5)·cell): one value per j − i
    lag = np.arange(-states, states)
    upper = cdf((lag + 0.5) * cell)
    j_minus_i = np.arange(states)[None, :] - np.arange(states)[:, None] + states
    F = upper[j_minus_i]
    Q = np.diff(np.concatenate([np.zeros((states, 1)), F], axis=1), axis=1)
    try:
        L = np.linalg.solve(np.eye(states) - Q, np.ones(states))
    except np.linalg.LinAlgError:
        return math.inf
    return float(L[0]) if L[0] > 0 else math.inf


def cusum_threshold(target: float, means: Sequence[float], stds: Sequence[float],
                    weights: Sequence[float] | None = None, guess: float = 1.0) -> float:
    """The smallest ``h`` (to 0.2 % of itself) whose :func:`cusum_arl` is at least ``target``
    flights; ``guess``: where to start looking (the last threshold)."""
    def enough(h: float) -> bool:
        return cusum_arl(h, means, stds, weights) >= target

    if enough(0.0):
        return 0.0
    guess = guess if math.isfinite(guess) and guess > 0 else 1.0
    lo, hi = guess / 1.25, guess * 1.25
    while not enough(hi):
        lo, hi = hi, 2 * hi
        if hi > 1e6:
            raise ParameterError("no CUSUM threshold reaches that false alarm rate")
    while lo > 1e-6 and enough(lo):
        lo, hi = lo / 2, lo
    if lo <= 1e-6:
        lo = 0.0
    while hi - lo > 2e-3 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if enough(mid) else (mid, hi)
    return hi


# ------------------------------------------------------------------------------------------
# what a flight gives
# ------------------------------------------------------------------------------------------
def load_case_statistics(forces_kgf: np.ndarray, commands_pct: np.ndarray,
                         planned_pct: np.ndarray, case_cycles: Sequence[int],
                         delay_cycles: Sequence[int], period_s: float, window: int = 5,
                         start_cycle: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flight's end points, flows and planned flows per load case, each (N, M).

    ``forces_kgf``, ``commands_pct``, ``planned_pct``: (N, K) per control cycle, the force read
    at cycle k, the command sent then, the feedforward planned for it; ``case_cycles``: the cycle
    of each load case (the reference's turning point); ``delay_cycles``: each channel's delay in
    cycles. The end point is the mean force over ``case ± window`` cycles (the noise of one
    reading would be the largest term of the flow's correction); the flow into load case j is
    ``T·Σ u`` over the cycles ``[case_{j−1}, case_j)`` shifted back by the channel's delay (the
    commands whose flow moved the force over the segment), the first from ``start_cycle``."""
    y = np.asarray(forces_kgf, float)
    u = np.asarray(commands_pct, float)
    p = np.asarray(planned_pct, float)
    if not (y.ndim == 2 and y.shape == u.shape == p.shape):
        raise ParameterError(f"forces, commands and planned commands must be (N, K) alike, got "
                             f"{y.shape}, {u.shape}, {p.shape}")
    N, K = y.shape
    idx = np.asarray(case_cycles, int)
    m = np.asarray(delay_cycles, int)
    if len(m) != N or np.any(idx < 0) or np.any(idx >= K) or np.any(np.diff(idx) <= 0):
        raise ParameterError("case_cycles must rise within the record; one delay per channel")
    lo = np.clip(idx - window, 0, K)
    hi = np.clip(idx + window + 1, 0, K)
    cy = np.concatenate([np.zeros((N, 1)), np.cumsum(y, axis=1)], axis=1)
    E = (cy[:, hi] - cy[:, lo]) / (hi - lo)[None, :]
    cuts = np.concatenate([[start_cycle], idx])
    F = np.empty((N, len(idx)))
    P = np.empty((N, len(idx)))
    for i in range(N):
        b = np.clip(cuts - m[i], 0, K)
        for src, dst in ((u[i], F[i]), (p[i], P[i])):
            c = np.concatenate([[0.0], np.cumsum(src)])
            dst[:] = period_s * (c[b[1:]] - c[b[:-1]])
    return E, F, P


# ------------------------------------------------------------------------------------------
# the detector
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TrendOptions:
    """How the trends are learned and tested (module docstring)."""

    #: flights of a type that learn its baseline (its mean and noise) before it is tested
    learn_flights: int = 30
    #: the change the test is tuned to: channel i's flow this much (%) above its type's need
    shift_pct: float = 1.0
    #: the average run of intact flights between false alarms, all statistics together
    false_alarm_flights: float = 1e5
    #: noise floor on each channel's statistic (%): no baseline is taken as quieter than this
    floor_pct: float = 0.02
    #: the baseline's noise taken at this upper confidence bound
    confidence: float = 0.9
    #: "both": a statistic for more flow and one for less per channel; "soften": more only
    sides: str = "both"
    #: take out what moves every valve's flow alike (supply pressure, oil temperature), of any
    #: size (2 channels or more; naming the channel that changed needs 3)
    common_mode: bool = True
    #: what the running test does on an alarm: note, hold, unload
    action: str = "note"

    def check(self, n_channels: int) -> None:
        """:class:`ParameterError` naming the option that cannot be used."""
        if not isinstance(self.learn_flights, int) or self.learn_flights < n_channels + 5:
            raise ParameterError(f"trends: learn_flights = {self.learn_flights!r}: give at least "
                                 f"{n_channels + 5} (the channels + 5: the noise's covariance "
                                 "is learned from them)")
        for name, v, lo, hi in (("shift_pct", self.shift_pct, 0.01, 100.0),
                                ("false_alarm_flights", self.false_alarm_flights, 10.0, 1e12),
                                ("floor_pct", self.floor_pct, 0.0, 10.0),
                                ("confidence", self.confidence, 0.5, 0.999)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or not lo <= v <= hi:
                raise ParameterError(f"trends: {name} = {v!r} must be a number in [{lo:g}, {hi:g}]")
        if not isinstance(self.common_mode, bool):
            raise ParameterError(f"trends: common_mode = {self.common_mode!r} must be true or false")
        if self.sides not in SIDES:
            raise ParameterError(f"trends: sides = {self.sides!r}: choose {' or '.join(SIDES)}")
        if self.action not in ACTIONS:
            raise ParameterError(f"trends: action = {self.action!r}: choose one of {', '.join(ACTIONS)}")


@dataclass
class TrendAlarm:
    """A persistent change found: the channels whose statistic crossed, the strongest first."""

    flight: int
    flight_type: str
    channels: list[str]
    #: per channel: "soften" (more flow: a crack) or "stiffen" (less)
    directions: list[str]
    #: per channel: the first flight of the run that crossed (the change's flight, estimated)
    since_flights: list[int]
    #: per channel: its own mean flow excess since then (the common mode taken out), % of its
    #: own share of the steps
    flow_change_pct: list[float]
    statistics: list[float]
    thresholds: list[float]
    action: str

    def message(self) -> str:
        parts = []
        for name, way, since, pct, s, h in zip(self.channels, self.directions, self.since_flights,
                                               self.flow_change_pct, self.statistics,
                                               self.thresholds):
            why = ("the structure at its attachment softened (a crack?) or its valve lost gain"
                   if way == "soften" else
                   "the structure at its attachment stiffened (a jammed part?) or its valve gained")
            parts.append(f"channel {name} needs {abs(pct):.2f} % {'more' if pct >= 0 else 'less'} "
                         f"flow to reach its end points since flight {since} (statistic {s:.1f} "
                         f"over its threshold {h:.1f}): {why}")
        return (f"flight {self.flight} (type {self.flight_type}): " + "; ".join(parts)
                + f"; action {self.action}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "TrendAlarm":
        return cls(**d)


@dataclass
class FlightTrend:
    """One flight as the detector saw it (its history, for plots and the journal)."""

    flight: int
    flight_type: str
    #: False while its type learns its baseline (then the statistics below are None)
    tested: bool
    #: per channel: x, its flow over its type's need, % of its own share of the steps
    flow_excess_pct: list[float] | None = None
    #: per channel: z, the standardized statistic
    z: list[float] | None = None
    #: per channel: the CUSUMs after this flight (more flow; less flow)
    soften: list[float] | None = None
    stiffen: list[float] | None = None
    #: per channel: the RMS of its end points from its type's baseline, kgf
    end_point_shift_kgf: list[float] | None = None
    #: how far the planned flows moved from the type's baseline, % of their size (a changed
    #: programme, compensation or schedule of the type)
    plan_change_pct: float | None = None
    #: the channels of an alarm raised at this flight
    alarm: list[str] | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "FlightTrend":
        return cls(**d)


@dataclass
class _Baseline:
    """A flight type's learning flights, then its baseline (module docstring)."""

    cases: int
    flights: list[list] = field(default_factory=list)     #: learning: [E, F, P] as lists
    count: int = 0                                         #: flights of this type seen
    #: armed: the means, the unit per load case, the correction, the whitening, a_i
    E: np.ndarray | None = None
    F: np.ndarray | None = None
    P: np.ndarray | None = None
    unit: np.ndarray | None = None
    unit_norm: np.ndarray | None = None
    correction: np.ndarray | None = None
    whiten: np.ndarray | None = None
    gain: np.ndarray | None = None
    common: np.ndarray | None = None
    #: the noise: Σ x·xᵀ over the learning flights and the quiet tested ones, how many, when
    #: the whitening is next computed again, and how many flights the means are of
    scatter: np.ndarray | None = None
    used: int = 0
    refresh_at: int = 0
    averaged: int = 0

    @property
    def armed(self) -> bool:
        return self.whiten is not None

    _ARRAYS = ("E", "F", "P", "unit", "unit_norm", "correction", "whiten", "gain", "common",
               "scatter")
    _COUNTS = ("count", "used", "refresh_at", "averaged")

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"cases": self.cases, "flights": self.flights}
        d.update({k: getattr(self, k) for k in self._COUNTS})
        for k in self._ARRAYS:
            v = getattr(self, k)
            d[k] = None if v is None else v.tolist()
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "_Baseline":
        b = cls(int(d["cases"]), [list(f) for f in d["flights"]])
        for k in cls._COUNTS:
            setattr(b, k, int(d[k]))
        for k in cls._ARRAYS:
            if d.get(k) is not None:
                setattr(b, k, np.array(d[k], float))
        return b


class TrendDetector:
    """End-point trends of a rig's channels, one call per flight (module docstring).

    ``names``: the channels, in the order of the arrays' rows; ``G``: the rig model's G,
    kgf/(%·s) (recommended: the flows the achieved end points needed are taken off through
    ``G⁻¹``; None: the planned flows are the unit)."""

    def __init__(self, names: Sequence[str], G: np.ndarray | None = None,
                 options: TrendOptions | None = None) -> None:
        self.names = list(names)
        n = len(self.names)
        if n == 0:
            raise ParameterError("trends: a rig needs at least one channel")
        self.options = options or TrendOptions()
        self.options.check(n)
        self.G: np.ndarray | None = None
        if G is not None:
            G = np.array(G, float)
            if G.shape != (n, n) or not np.all(np.isfinite(G)) or np.any(np.diag(G) <= 0):
                raise ParameterError(f"trends: G must be {n}x{n} finite numbers with a positive "
                                     "diagonal (the rig model's, kgf/(%·s))")
            self.G = G
        self._types: dict[str, _Baseline] = {}
        self.soften = np.zeros(n)
        self.stiffen = np.zeros(n)
        self._since = np.zeros((2, n), int)             # the flight each run began
        self._sum = np.zeros((2, n))                    # Σ own excess over the run
        self._runs = np.zeros((2, n), int)              # flights in the run
        self.latched = np.zeros((2, n), bool)
        self.thresholds = np.full(n, math.inf)
        self.last_flight: int | None = None
        self.alarms: list[TrendAlarm] = []
        self.history: list[FlightTrend] = []

    @property
    def n(self) -> int:
        return len(self.names)

    # -- one flight ----------------------------------------------------------------------------
    def add_flight(self, flight_number: int, flight_type: str, end_points: np.ndarray,
                   flows: np.ndarray, planned_flows: np.ndarray) -> TrendAlarm | None:
        """The flight ``flight_number`` of type ``flight_type`` ended: each channel's achieved
        end point (kgf), the flow it took and the flow planned for it (%·s), (N, M) for its M
        load cases (:func:`load_case_statistics`). Returns the alarm it raised, if any."""
        E, F, P = self._check_flight(flight_number, flight_type, end_points, flows, planned_flows)
        base = self._types.get(flight_type)
        if base is None:
            base = self._types[flight_type] = _Baseline(E.shape[1])
        elif base.cases != E.shape[1]:
            raise ParameterError(f"trends: flight {flight_number}: type {flight_type!r} has "
                                 f"{base.cases} load cases, this flight {E.shape[1]}")
        self.last_flight = flight_number
        base.count += 1
        if not base.armed:
            base.flights.append([E.tolist(), F.tolist(), P.tolist()])
            if len(base.flights) >= self.options.learn_flights:
                self._arm(base)
            self.history.append(FlightTrend(flight_number, flight_type, False,
                                            soften=self.soften.tolist(),
                                            stiffen=self.stiffen.tolist()))
            return None
        x = self._excess(base, E, F)
        z = base.whiten @ x
        d = self._d(base)
        quiet = not (self.soften.any() or self.stiffen.any())
        alarm = self._test(flight_number, flight_type, self._own(base, x), z, d)
        if quiet and np.all(np.abs(z) < QUIET_Z):
            self._learn_noise(base, x, E, F)
        self.history.append(FlightTrend(
            flight_number, flight_type, True, (100 * x).tolist(), z.tolist(),
            self.soften.tolist(), self.stiffen.tolist(),
            np.sqrt(np.mean((E - base.E) ** 2, axis=1)).tolist(),
            float(100 * np.linalg.norm(P - base.P) / max(np.linalg.norm(base.P), 1e-12)),
            alarm.channels if alarm else None))
        return alarm

    def _check_flight(self, flight_number, flight_type, end_points, flows, planned):
        if isinstance(flight_number, bool) or not isinstance(flight_number, (int, np.integer)):
            raise ParameterError(f"trends: flight_number = {flight_number!r} must be an integer")
        if self.last_flight is not None and flight_number <= self.last_flight:
            raise ParameterError(f"trends: flight {flight_number} after flight {self.last_flight}: "
                                 "each flight is added once, in order")
        if not isinstance(flight_type, str) or not flight_type:
            raise ParameterError(f"trends: flight_type = {flight_type!r} must be a name")
        arrays = []
        for what, a in (("end_points", end_points), ("flows", flows), ("planned_flows", planned)):
            a = np.asarray(a, float)
            if a.ndim != 2 or a.shape[0] != self.n or a.shape[1] < 2:
                raise ParameterError(f"trends: flight {flight_number}: {what} must be (channels, "
                                     f"load cases) = ({self.n}, M >= 2), got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise ParameterError(f"trends: flight {flight_number}: {what} has a value that is "
                                     "not a finite number")
            arrays.append(a)
        if not arrays[0].shape == arrays[1].shape == arrays[2].shape:
            raise ParameterError(f"trends: flight {flight_number}: end_points, flows and "
                                 "planned_flows must have one shape")
        return arrays

    # -- the statistic --------------------------------------------------------------------------
    def _excess(self, base: _Baseline, E: np.ndarray, F: np.ndarray) -> np.ndarray:
        """x: each channel's flow over its type's need, a fraction of its own share."""
        dE = E - base.E
        ds = np.diff(np.concatenate([np.zeros((self.n, 1)), dE], axis=1), axis=1)
        r = F - base.F - base.correction @ ds
        return np.where(base.unit_norm > 0, (r * base.unit).sum(axis=1) /
                        np.where(base.unit_norm > 0, base.unit_norm, 1.0), 0.0)

    def _arm(self, base: _Baseline) -> None:
        """The type's baseline from its learning flights (module docstring)."""
        o = self.options
        flights = [[np.array(a, float) for a in f] for f in base.flights]
        n = len(flights)
        base.E = np.mean([f[0] for f in flights], axis=0)
        base.F = np.mean([f[1] for f in flights], axis=0)
        base.P = np.mean([f[2] for f in flights], axis=0)
        steps = np.diff(base.E, axis=1)
        if self.G is not None:
            base.unit = np.concatenate([np.zeros((self.n, 1)), steps / np.diag(self.G)[:, None]],
                                       axis=1)
            base.correction = np.linalg.inv(self.G)
        else:
            base.unit = base.P.copy()
            own = (base.P[:, 1:] * steps).sum(axis=1) / np.maximum((steps ** 2).sum(axis=1), 1e-300)
            base.correction = np.diag(np.where((steps ** 2).sum(axis=1) > 0, own, 0.0))
        base.unit_norm = (base.unit ** 2).sum(axis=1)
        still = base.unit_norm <= 0                  # a channel this type never moves
        # x's answer to every valve's flow gain 1 higher (a share): its flows scale by 1/(1 + ε)
        base.common = np.where(still, 0.0, -(base.F * base.unit).sum(axis=1) /
                               np.where(still, 1.0, base.unit_norm))
        X = np.array([self._excess(base, f[0], f[1]) for f in flights])
        X -= X.mean(axis=0)                          # 0 but for rounding: x is linear in F, E
        base.scatter = X.T @ X
        base.used = base.averaged = n
        base.refresh_at = n + o.learn_flights
        base.flights = []
        self._whiten(base)
        self._set_thresholds()

    def _whiten(self, base: _Baseline) -> None:
        """The type's whitening and gains from its noise so far (module docstring)."""
        o = self.options
        still = base.unit_norm <= 0                  # a channel this type never moves
        S = base.scatter / (base.used - 1) + (o.floor_pct / 100.0) ** 2 * np.eye(self.n)
        S[still, :] = S[:, still] = 0.0
        S[still, still] = 1.0
        # a channel with an alarm on is known to have changed: the others are tested without it
        # (its excess would show, through the common mode taken out, on every other channel)
        alarmed = self.latched.any(axis=0)
        S[alarmed, alarmed] += LATCHED_VARIANCE
        prec = np.linalg.inv(S)
        b = base.common
        if self._common_mode and np.any(b != 0):
            pb = prec @ b
            prec = prec - np.outer(pb, pb) / float(b @ pb)
        dof = max(base.used - self.n, 1)
        kappa = dof / chi2.ppf(1.0 - o.confidence, dof)
        own = np.where(still, 1.0, np.diag(prec))
        base.whiten = np.where(still[:, None], 0.0, prec / np.sqrt(own * kappa)[:, None])
        base.gain = np.where(still, 0.0, np.sqrt(own / kappa))

    def _learn_noise(self, base: _Baseline, x: np.ndarray, E: np.ndarray, F: np.ndarray) -> None:
        """A quiet flight (no statistic on a run before it, no |z| beyond :data:`QUIET_Z`) adds
        to its type's means and noise; after ``learn_flights`` of them, or a quarter more than
        it had, the whitening and the thresholds are computed again (module docstring)."""
        base.scatter = base.scatter + np.outer(x, x)
        base.used += 1
        base.averaged += 1
        base.E = base.E + (E - base.E) / base.averaged
        base.F = base.F + (F - base.F) / base.averaged
        if base.used >= base.refresh_at:
            base.refresh_at = base.used + max(self.options.learn_flights, base.used // 4)
            self._whiten(base)
            self._set_thresholds()

    @property
    def _common_mode(self) -> bool:
        return self.options.common_mode and self.n >= 2

    def _own(self, base: _Baseline, x: np.ndarray) -> np.ndarray:
        """Each channel's own flow excess: x less its type's common-mode answer times the
        flight's common mode, the median of the channels' (a change at one channel does not
        move it; with fewer than 3 channels: x)."""
        b = base.common
        live = b != 0
        if not self._common_mode or live.sum() < 3:
            return x
        return x - b * float(np.median(x[live] / b[live]))

    def _d(self, base: _Baseline) -> np.ndarray:
        """Each channel's ``d`` under a type: the design change over its noise, at least
        :data:`MIN_D` (0 for a channel the type does not move)."""
        return np.where(base.gain > 0, np.maximum(self.options.shift_pct / 100.0 * base.gain,
                                                  MIN_D), 0.0)

    def _mixture(self, channel: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The armed types' ``d`` of ``channel``, their shares of the flights, and how far
        their baselines' means may be off (in the noise, at the confidence bound)."""
        armed = [b for b in self._types.values() if b.armed]
        d = np.array([self._d(b)[channel] for b in armed])
        w = np.array([b.count for b in armed], float)
        off = ndtri(self.options.confidence) / np.sqrt([b.averaged for b in armed])
        return d, w, off

    def _set_thresholds(self) -> None:
        """Each channel's h: the average run of intact flights of its statistic is
        ``2N × false_alarm_flights`` (``N ×`` with one side), its type's mean off by its bound."""
        sides = 2 if self.options.sides == "both" else 1
        target = self.options.false_alarm_flights * sides * self.n
        # one BLAS thread: the chain's small solves wait for threads more than they compute
        with threadpool_limits(1):
            for i in range(self.n):
                d, w, off = self._mixture(i)
                self.thresholds[i] = (cusum_threshold(target, d * off - d ** 2 / 2, d, w,
                                                      self.thresholds[i])
                                      if np.any(d > 0) else math.inf)

    def _test(self, flight: int, flight_type: str, own: np.ndarray, z: np.ndarray,
              d: np.ndarray) -> TrendAlarm | None:
        """The CUSUMs' step; a new alarm for every statistic that crossed, was not latched and
        whose channel's own flow excess over the run moved the statistic's way by at least half
        the design change (one that crossed without it crossed for the others' change, which the
        common mode's removal shows on every channel: it starts again from 0)."""
        ways = [(0, self.soften, z), (1, self.stiffen, -z)]
        if self.options.sides == "soften":
            ways = ways[:1]
        crossed = []
        for side, S, zz in ways:
            lam = d * zz - d ** 2 / 2
            new = np.maximum(0.0, S + lam)
            began = (S == 0) & (new > 0)
            self._since[side] = np.where(began, flight, self._since[side])
            self._sum[side] = np.where(new > 0, np.where(began, 0.0, self._sum[side]) + own, 0.0)
            self._runs[side] = np.where(new > 0, np.where(began, 0, self._runs[side]) + 1, 0)
            S[:] = new
            half = self.options.shift_pct / 200.0
            for i in np.flatnonzero((S > self.thresholds) & ~self.latched[side]):
                moved = self._sum[side, i] / self._runs[side, i] * (1 if side == 0 else -1)
                if moved < half:
                    S[i] = 0.0
                    self._sum[side, i] = 0.0
                    self._runs[side, i] = 0
                    continue
                crossed.append((S[i] / self.thresholds[i] if self.thresholds[i] > 0 else math.inf,
                                side, int(i)))
        if not crossed:
            return None
        crossed.sort(key=lambda c: -c[0])
        alarm = TrendAlarm(
            flight, flight_type, [self.names[i] for _, _, i in crossed],
            ["soften" if side == 0 else "stiffen" for _, side, _ in crossed],
            [int(self._since[side, i]) for _, side, i in crossed],
            [float(100 * self._sum[side, i] / max(self._runs[side, i], 1)) for _, side, i in crossed],
            [float((self.soften if side == 0 else self.stiffen)[i]) for _, side, i in crossed],
            [float(self.thresholds[i]) for _, _, i in crossed], self.options.action)
        for _, side, i in crossed:
            self.latched[side, i] = True
        self._rewhiten()
        self.alarms.append(alarm)
        return alarm

    # -- after an alarm ----------------------------------------------------------------------------
    def acknowledge(self, relearn: bool = False) -> None:
        """The alarms are dealt with (an inspection): every statistic from 0, the latches off;
        ``relearn``: the baselines too (a repair: the structure is a new one)."""
        self.soften[:] = 0.0
        self.stiffen[:] = 0.0
        self.latched[:] = False
        self._sum[:] = 0.0
        self._runs[:] = 0
        if relearn:
            self._types = {}
            self.thresholds[:] = math.inf
        else:
            self._rewhiten()

    def _rewhiten(self) -> None:
        """Every tested type's whitening, and the thresholds, for the alarms on now."""
        for b in self._types.values():
            if b.armed:
                self._whiten(b)
        self._set_thresholds()

    # -- what it says ------------------------------------------------------------------------------
    def armed_types(self) -> list[str]:
        return [t for t, b in self._types.items() if b.armed]

    def evaluate(self, flight_type: str, end_points: np.ndarray,
                 flows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A flight of a tested type as :meth:`add_flight` sees it, without adding it: each
        channel's flow excess x (%) and its standardized statistic z."""
        b = self._types.get(flight_type)
        if b is None or not b.armed:
            raise ParameterError(f"trends: type {flight_type!r} is not tested yet")
        x = self._excess(b, np.asarray(end_points, float), np.asarray(flows, float))
        return 100.0 * x, b.whiten @ x

    def noise_pct(self, flight_type: str) -> np.ndarray:
        """Each channel's noise under its type's baseline (%, the standard deviation of the part
        the other channels do not predict, at the confidence bound): 1/a_i."""
        b = self._types[flight_type]
        if not b.armed:
            raise ParameterError(f"trends: type {flight_type!r} is still learning")
        return np.where(b.gain > 0, 100.0 / np.where(b.gain > 0, b.gain, 1.0), math.inf)

    def expected_delay(self, channel: str, flow_change_pct: float) -> float:
        """The average flights from a change of ``flow_change_pct`` (% of its own share, + more
        flow) at ``channel`` until its statistic crosses, the armed types mixed as flown (the
        CUSUM from 0: the worst case is a little longer)."""
        i = self.names.index(channel)
        d, w, _ = self._mixture(i)
        if not np.any(d > 0):
            return math.inf
        a = np.array([b.gain[i] for b in self._types.values() if b.armed])
        shift = abs(flow_change_pct) / 100.0 * a            # the change in z
        return cusum_arl(self.thresholds[i], d * shift - d ** 2 / 2, d, w)

    def text(self) -> str:
        lines = [f"end-point trends: {len(self.armed_types())} of {len(self._types)} flight "
                 f"type(s) tested, false alarms at most 1 in {self.options.false_alarm_flights:g} "
                 f"flights, tuned to {self.options.shift_pct:g} % more flow"]
        width = max(len(n) for n in self.names)
        for i, name in enumerate(self.names):
            lines.append(f"  {name:<{width}}  soften {self.soften[i]:8.2f}  stiffen "
                         f"{self.stiffen[i]:8.2f}  threshold {self.thresholds[i]:.2f}"
                         + ("  ALARM" if self.latched[:, i].any() else ""))
        lines += [f"  alarm: {a.message()}" for a in self.alarms]
        return "\n".join(lines)

    # -- the journal ------------------------------------------------------------------------------
    def state(self, with_history: bool = False) -> dict[str, Any]:
        """Everything the statistic needs to go on, as JSON-ready numbers (exact)."""
        d: dict[str, Any] = {
            "version": STATE_VERSION, "names": self.names,
            "G": None if self.G is None else self.G.tolist(),
            "options": asdict(self.options),
            "types": {t: b.to_dict() for t, b in self._types.items()},
            "soften": self.soften.tolist(), "stiffen": self.stiffen.tolist(),
            "since": self._since.tolist(), "sum": self._sum.tolist(), "runs": self._runs.tolist(),
            "latched": self.latched.tolist(),
            "thresholds": [None if not math.isfinite(h) else h for h in self.thresholds],
            "last_flight": self.last_flight,
            "alarms": [a.to_dict() for a in self.alarms],
        }
        if with_history:
            d["history"] = [h.to_dict() for h in self.history]
        return d

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "TrendDetector":
        """The detector :meth:`state` saved; it continues the same statistic."""
        if state.get("version") != STATE_VERSION:
            raise ParameterError(f"trends: a state of version {state.get('version')!r}; this "
                                 f"reads {STATE_VERSION}")
        det = cls(state["names"], state["G"], TrendOptions(**state["options"]))
        det._types = {t: _Baseline.from_dict(b) for t, b in state["types"].items()}
        det.soften = np.array(state["soften"], float)
        det.stiffen = np.array(state["stiffen"], float)
        det._since = np.array(state["since"], int)
        det._sum = np.array(state["sum"], float)
        det._runs = np.array(state["runs"], int)
        det.latched = np.array(state["latched"], bool)
        det.thresholds = np.array([math.inf if h is None else h for h in state["thresholds"]], float)
        det.last_flight = state["last_flight"]
        det.alarms = [TrendAlarm.from_dict(a) for a in state["alarms"]]
        det.history = [FlightTrend.from_dict(h) for h in state.get("history", [])]
        return det
