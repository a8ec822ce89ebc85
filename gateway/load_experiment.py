r"""The load experiment: one pass of a station's programme under its controller.

Every channel at once, each cycle (stepped with every channel's force, it returns every
channel's command: :meth:`LoadProgramme.step_rig`; a one-channel stand is the station of one
channel)::

    approach   to the pre-roll's start: one channel by a short P loop that moves the rod one
               way only (holding rather than reversing it); several along one straight line
               (a haversine in time, the ratio-keeping line), the feedforward of the base model
               through G⁻¹ and the designed P gains through the mixing matrix, each valve moving
               one way only, then held until every force is within the tolerance, each valve
               then on the way of the flow that holds its force against the trends (−G⁻¹Δ:
               one planned reversal where the line ends)
    pre-roll   a haversine into the first load case (:data:`PRE_ROLL_S`) along the trend, so
               that every valve keeps the sign of the command that holds the forces
    programme  u = feedforward through the model's inverse + PI through M (loading.controller)
    unload     a haversine from the last load case to the unload level (every channel in the
               same time: the ratios kept), tracked the same way

**No reversal the model does not plan.** With a reversal effect the stand's gain right after
the rod reverses at a small command is many times the steady one (17× at b = 2, p = 0.7, where
the design's margins hold up to ``ρ`` = 3); on the emulated stands a reversal brings 100-200 kgf
of force the steady gain does not predict. The feedforward plans it at every turning point of
the programme; a reversal it does not plan throws the force off by as much, and a feedback that
reverses the valve near a turning point, where the planned command is small, rings (the extra
cycles of the tracking report). So, per valve: wherever its channel's model predicts a gain
above its ``ρ`` (the feedback is scaled down there, :func:`loading.feedforward.feedback_scale`)
and during the pre-roll, the command keeps the feedforward's sign or holds (0): the feedback
slows the rod, it does not reverse it. A feedforward through G⁻¹ (a rig's, ``feedforward =
"rig"``) holds each valve's sign everywhere its channel's model has a reversal boost: its
neighbours' flows would otherwise make its feedback reverse it at small flows.

**The approach and the pre-roll** give the programme a start the model plans. A plain P loop
ends holding the force with small commands of either sign (its noise, and with a reversal
effect a limit cycle), so the way the rod last moved would be unknown. Here every valve moves
one way only, so that way is known, and the feedforward is planned both ways for every channel
before the run; at the approach's end each channel takes the plan of its own way. A held
station needs the flows ``w = −G^{-1}Δ`` (Δ the trends); a pre-roll that moves the forces by
``d`` needs ``G^{-1}(d·ḣ − Δ)``: with ``d = −c·Δ`` (``c > 0``) both have the same sign at every
valve, so every command keeps one sign from the pre-roll into the hold at the first load case
and the programme's first motion is, on each channel, a single planned reversal or none, never a
brief reversal back and forth at a small command. ``c`` makes the channel with the largest trend
for its range move :data:`PRE_ROLL_SHARE` of its range (at least three tolerances); a start
that would cross or leave 0 kgf on some channel shortens ``c`` (that channel starts at 0 kgf).
Without trends the pre-roll comes from behind the first motion. The programme's first commands,
due a delay before it starts, go out during the pre-roll: a programme that starts at full rate
(a sine) starts on time.

**Passes back to back** (an endurance test's flights, :mod:`endurance.flights`): a pass made
with ``unload=False`` ends at its programme's last sample, and one made with ``lead_in`` (the
last samples of the pass before, in its place of the pre-roll) takes over from it without an
approach (:meth:`LoadProgramme.begin_handover`: the way every rod last moved and the feedback's
integral carried on). The lead-in covers the next programme's first commands, due a delay
before it starts, as the pre-roll does.

**The gain monitor** (``monitor``, :mod:`loading.gain_monitor`): every cycle of the programme
feeds it every force and command; following, the feedforward is scaled by its factors; its
alarm holds every valve (``hold``) or unloads every channel keeping the load ratios (``unload``:
the abort asks the loop for its unload).

**Null pacing** (``pacing``, :mod:`loading.pacing`): the programme's one clock waits at a load
case where a channel turns until every channel's predicted force is within its tolerance of its
level (``static``), and slows for all while any channel lags (``dynamic``); the references, the
feedforward and the feedback's schedule are read at the clock's position (:attr:`positions`).

Everything that can be checked is checked before anything moves (:meth:`LoadProgramme.check`):
the controller's period and channels against the station's, every channel's programme against
its force limit, every valve's feedforward peak against the command limit (naming the channel
and the time).
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from core.errors import ParameterError
from loading.compensation import Compensation
from loading.controller import PIFeedforward
from loading.design import ControllerDesign
from loading.feedforward import Feedforward, feedback_scale, feedforward
from loading.gain_monitor import GAIN_ALARM, GainMonitor
from loading.minimum_time import FEEDFORWARD_SHARE
from loading.pacing import DEFAULT_TOLERANCE_SHARE, PACING_TIMEOUT, PacingOptions, ProgrammeClock
from loading.programme import ChannelProgramme, Programme, as_programme

from .experiments.phases import FORCE_NEAR_LIMIT, SET_POINT_NOT_REACHED, Dwell, SetPointApproach
from .experiments.rig import RigExperiment

#: the pre-roll into the programme's first load case: this share of the range of the channel
#: with the largest trend for its range (at least three times the approach's tolerance), in
#: this time (s)
PRE_ROLL_SHARE = 0.02
PRE_ROLL_S = 0.6
#: the line approach's peak rate (kgf/s, the channel that moves the most) and its command limit (%)
APPROACH_RATE_KGF_S = 1000.0
APPROACH_LIMIT_PCT = 20.0


def haversine_line(start: np.ndarray, end: np.ndarray, rate_kgf_s: float, period_s: float,
                   include_start: bool) -> np.ndarray:
    """(N, n): a haversine in time from ``start`` to ``end`` on every channel at once, its
    duration set by the channel that moves the most at ``rate_kgf_s`` peak rate."""
    span = float(np.max(np.abs(end - start)))
    if span < 1e-9:
        return np.zeros((len(start), 0))
    n = max(int(round(math.pi * span / (2 * rate_kgf_s) / period_s)), 1)
    s = (np.arange(n) if include_start else np.arange(1, n + 1)) / n
    return start[:, None] + (end - start)[:, None] * (1 - np.cos(np.pi * s))[None, :] / 2


def pre_roll_start(levels0: np.ndarray, levels1: np.ndarray, trends: np.ndarray,
                   ranges: np.ndarray, tolerance_kgf: float) -> np.ndarray:
    """The pre-roll's start (module docstring): ``L0 + c·Δ``, or from behind the first motion
    ``L1 − L0`` without trends; no channel's start on the other side of 0 kgf than its level
    (the channel that shortens ``c`` starts at 0 kgf)."""
    levels0 = np.asarray(levels0, float)
    direction = np.asarray(trends, float)
    if not np.any(direction):
        direction = -(np.asarray(levels1, float) - levels0)
    size = np.abs(direction)
    if not size.any():
        return levels0.copy()
    lead = int(np.argmax(size / np.maximum(ranges, 1.0)))
    # the lead channel moves this far (kgf), every other one in proportion to its direction
    reach = max(PRE_ROLL_SHARE * float(ranges[lead]), 3 * tolerance_kgf * (size[lead] / size.max()))
    move = reach * (direction / size[lead])
    start = levels0 + move
    crossing = (np.sign(start) != np.sign(levels0)) & (direction != 0)
    if np.any(crossing):
        share = np.full(len(start), np.inf)
        share[crossing] = np.abs(levels0[crossing]) / np.abs(move[crossing])
        j = int(np.argmin(share))
        start = levels0 + share[j] * move
        start[j] = 0.0
    return start


def pre_roll(programme: Programme, trends: Sequence[float], tolerance_kgf: float) -> np.ndarray:
    """(N, n): the pre-roll's samples before the programme's first (module docstring)."""
    R = programme.r_kgf
    moving = np.flatnonzero(np.any(R != R[:, :1], axis=0))
    first_move = R[:, moving[0]] if len(moving) else R[:, 0]
    start = pre_roll_start(R[:, 0], first_move, np.asarray(trends, float), programme.ranges_kgf, tolerance_kgf)
    n = max(int(round(PRE_ROLL_S / programme.period_s)), 1)
    s = np.arange(n) / n
    return start[:, None] + (R[:, 0] - start)[:, None] * (1 - np.cos(np.pi * s))[None, :] / 2


def held_direction(u: np.ndarray, way0: float) -> np.ndarray:
    """The sign of ``u`` with a zero keeping the last nonzero sign (``way0`` before the first):
    the way the valve's command points, as the rod's direction is counted."""
    sgn = np.sign(u)
    idx = np.maximum.accumulate(np.where(sgn != 0, np.arange(len(u)), -1))
    return np.where(idx >= 0, sgn[np.maximum(idx, 0)], float(way0))


@dataclass
class _ChannelPlan:
    u: np.ndarray          #: feedforward per cycle
    scale: np.ndarray      #: share of the feedback
    way: np.ndarray        #: sign to keep per cycle (0: free)
    factor: np.ndarray     #: the model's FLOW factor where the cycle's command acts


class OneWayApproach(SetPointApproach):
    """The set-point approach moving the rod one way only (``way``, ±1: toward the set point
    from where the force starts); a command the other way is held at 0."""

    way = 1.0

    def step(self, t: float, y: float) -> float | None:
        u = super().step(t, y)
        return 0.0 if u is not None and self.way * u < 0 else u


class SetPointLine:
    """One channel's approach (module docstring): :class:`OneWayApproach` to the pre-roll's
    start, moving the rod toward it from where the force starts; the station's interface
    (forces and commands as arrays of one)."""

    def __init__(self, target_kgf: np.ndarray, gain_pct_per_kgf: float = 0.02, limit_pct: float = 20.0,
                 tolerance_kgf: float = 20.0, max_s: float = 20.0) -> None:
        self.inner = OneWayApproach(float(target_kgf[0]), gain_pct_per_kgf, limit_pct, tolerance_kgf,
                                    max_s=max_s)
        self.target = np.asarray(target_kgf, float)
        self.tolerance, self.max_s = tolerance_kgf, max_s
        self.way = np.ones(1)

    @property
    def done_at(self) -> float | None:
        return self.inner.done_at

    @property
    def failed(self) -> bool:
        return self.inner.failed

    def begin(self, y0: np.ndarray) -> None:
        way = 1.0 if y0[0] <= self.target[0] else -1.0
        self.inner.way = way
        self.way = np.array([way])
        self.inner.begin(float(y0[0]))

    def step(self, t: float, y: np.ndarray) -> np.ndarray | None:
        u = self.inner.step(t, float(y[0]))
        return None if u is None else np.array([u])

    def failure_message(self, y: np.ndarray) -> str:
        return self.inner.failure_message(float(y[0]))


class RatioLine:
    """Every force to the pre-roll's start along one straight line (module docstring)."""

    def __init__(self, controller: ControllerDesign, target_kgf: np.ndarray, period_s: float,
                 tolerance_kgf: float = 20.0, hold_s: float = 0.1, max_s: float = 20.0,
                 rate_kgf_s: float = APPROACH_RATE_KGF_S, limit_pct: float = APPROACH_LIMIT_PCT) -> None:
        self.target = np.asarray(target_kgf, float)
        self.T = period_s
        self.tolerance = tolerance_kgf
        self.hold_s, self.max_s = hold_s, max_s
        self.line_rate, self.limit = rate_kgf_s, limit_pct
        model = controller.model
        #: rates (kgf/s) to commands (%): the base model's inverse
        self.to_command = np.linalg.inv(controller.G)
        self.Mkp = controller.M * np.array([c.kp_pct_per_kgf for c in controller.channels])[None, :]
        self.trend = np.array([m.delta for m in model.channels])
        #: the flows that hold every force against the trends (the base model's: −G⁻¹Δ)
        self.hold_flows = -self.to_command @ self.trend
        self.taus = np.array([m.tau for m in model.channels])
        self.done_at: float | None = None
        self.failed = False
        self.way = np.ones(len(self.target))

    def begin(self, y0: np.ndarray) -> None:
        y0 = np.asarray(y0, float)
        self.start = y0.copy()
        move = self.target - y0
        flows = self.to_command @ move
        self.way = np.where(flows < 0, -1.0, 1.0)
        #: after the line each valve holds against its trend: the way of the flow that holds
        #: the forces, −G⁻¹Δ (a valve whose move went the other way reverses once, as planned,
        #: where the line ends; a zero keeps the move's way)
        hold = self.hold_flows
        self.hold_way = np.where(hold > 0, 1.0, np.where(hold < 0, -1.0, self.way))
        self.duration = math.pi * float(np.max(np.abs(move))) / (2 * self.line_rate)
        self._settled = Dwell(self.hold_s)
        self.done_at = 0.0 if np.all(np.abs(move) <= self.tolerance) else None
        self.failed = False

    def reference(self, t: float) -> np.ndarray:
        """The line's forces at ``t``."""
        if t >= self.duration:
            return self.target
        s = t / self.duration
        return self.start + (self.target - self.start) * (1 - math.cos(math.pi * s)) / 2

    def rate(self, t: float) -> np.ndarray:
        """The line's force rates at ``t`` (kgf/s)."""
        if t >= self.duration or t < 0:
            return np.zeros_like(self.target)
        span = self.target - self.start
        return span * math.pi / (2 * self.duration) * math.sin(math.pi * t / self.duration)

    def feedforward(self, t: float) -> np.ndarray:
        """Each valve's command for the line, sent its own delay ahead: valve j makes the
        flow of the rates a delay ``τ_j`` later."""
        return np.array([self.to_command[j] @ (self.rate(t + tau) - self.trend)
                         for j, tau in enumerate(self.taus)])

    def step(self, t: float, y: np.ndarray) -> np.ndarray | None:
        """Every channel's command, or None once done (or failed: :attr:`failed`)."""
        if self.done_at is not None:
            return None
        r = self.reference(t)
        if self._settled(t, t >= self.duration and bool(np.all(np.abs(self.target - y) <= self.tolerance))):
            self.done_at = t
            return None
        if t >= self.max_s + self.duration:
            self.failed = True
            return None
        if t >= self.duration:
            self.way = self.hold_way
        u = self.feedforward(t) + self.Mkp @ (r - y)
        u = np.where(self.way * u < 0, 0.0, u)
        return np.clip(u, -self.limit, self.limit)

    def failure_message(self, y: np.ndarray) -> str:
        return (f"the forces did not reach the pre-roll's start within {self.tolerance:.0f} kgf in "
                f"{self.max_s:g} s after the line (last readings {', '.join(f'{v:.0f}' for v in y)} "
                "kgf); check the rig")


class LoadProgramme(RigExperiment):
    """One pass of a station's programme under its controller (module docstring).

    Stepped for every channel at once: :meth:`configure_rig`, :meth:`begin_rig` with the first
    forces, then :meth:`step_rig` each cycle until :meth:`finished_rig`."""

    name = "load"

    def __init__(self, programme: Programme | ChannelProgramme, controller: ControllerDesign,
                 compensation: Compensation | None = None, unload_kgf: float = 0.0,
                 settle_gain: float = 0.02, settle_limit_pct: float = 20.0,
                 settle_tolerance_kgf: float = 20.0, settle_max_s: float = 20.0,
                 guard_fraction: float = 0.95, monitor: GainMonitor | None = None,
                 pacing: PacingOptions | None = None, lead_in: np.ndarray | None = None,
                 unload: bool = True) -> None:
        programme = as_programme(programme)
        if list(programme.names) != list(controller.names):
            raise ParameterError(f"the programme is for the channels {', '.join(programme.names)}, the "
                                 f"controller for {', '.join(controller.names)}")
        self.pacing = pacing or PacingOptions()
        self.pacing.check()
        if self.pacing.on and not programme.load_cases:
            raise ParameterError(f"{programme.source}: pacing waits at load cases; per-channel "
                                 "sequences have none (leave --pacing out)")
        self.programme = programme
        self.controller = controller
        self.compensation = compensation
        self.names = list(programme.names)
        self.n = programme.n
        T = programme.period_s
        self.commanded = compensation.commanded(programme) if compensation is not None else programme
        model = controller.model
        self.trends = np.array([m.delta for m in model.channels])
        R = self.commanded.r_kgf
        if lead_in is None:
            pre = pre_roll(self.commanded, self.trends, settle_tolerance_kgf)
        else:
            pre = np.asarray(lead_in, float)
            if pre.ndim != 2 or pre.shape[0] != self.n or pre.shape[1] < 1 or not np.isfinite(pre).all():
                raise ParameterError(f"lead_in: {self.n} channels of finite forces expected, got shape "
                                     f"{pre.shape}")
        if unload:
            peak = float(np.abs(np.array([p.rate_kgf_s() for p in programme.channels])).max()) or 1000.0
            tail = haversine_line(R[:, -1], np.full(self.n, float(unload_kgf)), min(peak, 2500.0), T, False)
        else:
            tail = np.zeros((self.n, 0))
        #: with a lead-in: the pass takes over from one that ran to its first sample
        #: (:meth:`begin_handover`), no approach and no pre-roll of its own
        self.handover = lead_in is not None
        #: cycles of the main phase before the programme's start (the pre-roll or the lead-in)
        self.lead = pre.shape[1]
        self.reference = np.concatenate([pre, R, tail], axis=1)
        self.unload_kgf = unload_kgf
        #: the feedforward for every channel, planned for each way its rod may last have moved
        self.ff: dict[float, Feedforward] = {
            way: feedforward(model, self.reference, T, [way] * self.n, controller.feedforward)
            for way in (1.0, -1.0)}
        self.plans = {way: self._plans(ff, way) for way, ff in self.ff.items()}
        self.max_command_pct = controller.command_limit_pct
        self.law = PIFeedforward([c.kp_pct_per_kgf for c in controller.channels],
                                 [c.ti_s for c in controller.channels], T,
                                 controller.command_limit_pct, controller.M,
                                 share_integral=controller.feedforward == "rig")
        if self.n == 1:
            self.approach = SetPointLine(self.reference[:, 0], settle_gain, settle_limit_pct,
                                         settle_tolerance_kgf, settle_max_s)
        else:
            self.approach = RatioLine(controller, self.reference[:, 0], T, settle_tolerance_kgf,
                                      max_s=settle_max_s)
        #: the flows that hold the forces (the base model's, as the feedforward makes them)
        self.hold_flows = controller.hold_flows()
        self.guard_fraction = guard_fraction
        self.force_limits = np.full(self.n, math.inf)
        self.way = np.ones(self.n)
        self.main_start_s: float | None = None
        self.abort: tuple[str, str] | None = None
        self.abort_channel: int | None = None
        #: the gain monitor of the test, shared by its passes (loading.gain_monitor)
        self.monitor = monitor
        #: with pacing: the programme's clock of the pass, and its position per cycle of the main
        #: phase (samples of the reference, fractional while it slows)
        self.clock: ProgrammeClock | None = None
        self.positions: list[float] = []
        self._u = self._scale = self._hold = self._factor = None

    def _plans(self, ff: Feedforward, way: float) -> list[_ChannelPlan]:
        """Each channel's feedforward, feedback share and held sign when its rod last moved
        ``way`` (module docstring). Without a feedforward (feedback alone) no sign is held."""
        out = []
        mode = self.controller.feedforward
        for f, c in zip(ff.channels, self.controller.channels):
            scale = feedback_scale(f, c.boost)
            held = scale < 1.0
            held[:self.lead] = True
            if mode == "rig" and c.boost > 1.0:
                held[:] = True
            factor = f.flow_factor if f.flow_factor is not None else np.ones(len(f.u_pct))
            keep = held_direction(f.u_pct, way) if mode != "none" else np.zeros(len(f.u_pct))
            out.append(_ChannelPlan(f.u_pct, scale, np.where(held, keep, 0.0), factor))
        return out

    # -- what the loop and the reports read --------------------------------------------------
    @property
    def period_s(self) -> float:
        return self.programme.period_s

    @property
    def main_duration_s(self) -> float:
        return self.reference.shape[1] * self.period_s

    @property
    def duration_s(self) -> float:
        return self.main_duration_s

    @property
    def max_duration_s(self) -> float:
        slowest = self.pacing.min_speed if self.pacing.mode == "dynamic" else 1.0
        return self.approach.max_s + self.main_duration_s / slowest + 10.0

    @property
    def programme_start_s(self) -> float | None:
        """The run's time at the programme's start (None before the approach ended)."""
        if self.main_start_s is None:
            return None
        return self.main_start_s + self.lead * self.period_s

    def params(self) -> dict[str, Any]:
        """The run's experiment parameters (run.json): per channel, in the station's order; a
        one-channel stand's as one channel's values."""
        c = self.controller
        ff = self.ff[1.0]
        per_channel = {
            "kp_pct_per_kgf": [ch.kp_pct_per_kgf for ch in c.channels], "ti_s": [ch.ti_s for ch in c.channels],
            "feedforward_inverts": [f.inverted for f in ff.channels],
            "feedforward_does_not_invert": [f.not_inverted for f in ff.channels],
            "feedback_scale_min": [float(p.scale.min()) for p in self.plans[1.0]],
            "sign_held_share": [float(np.mean(p.way != 0)) for p in self.plans[1.0]],
            "pre_roll_from_kgf": self.reference[:, 0].tolist(),
            **({"pacing_tolerance_kgf": self.pacing_tolerances_kgf.tolist()} if self.pacing.on else {})}
        if self.programme.stand:
            out = {"programme": self.programme.source, "turning_points": int(len(self.programme.turning_idx)),
                   "range_kgf": float(self.programme.ranges_kgf[0]), "controller_model": c.channels[0].model_spec,
                   **{k: v[0] for k, v in per_channel.items()}}
        else:
            out = {"programme": self.programme.source, "channels": self.names,
                   "load_cases": int(len(self.programme.turning_idx)) if self.programme.load_cases else None,
                   "ranges_kgf": self.programme.ranges_kgf.tolist(), "feedback": c.feedback,
                   "feedforward": c.feedforward, "detuning": c.detuning,
                   "models": [ch.model_spec for ch in c.channels], **per_channel}
        return {**out, "compensated": self.compensation is not None, "unload_kgf": self.unload_kgf,
                "settle_tolerance_kgf": self.approach.tolerance, "settle_max_s": self.approach.max_s,
                "guard_fraction": self.guard_fraction, "pacing": self.pacing.mode,
                **({"pacing_min_speed": self.pacing.min_speed, "pacing_timeout_s": self.pacing.timeout_s}
                   if self.pacing.on else {}),
                **({"gain_monitor": dict(vars(self.monitor.options))} if self.monitor is not None else {})}

    def feedforward_covers(self) -> dict:
        """Per channel (by name): ``inverts``, what the feedforward inverts of the controller's
        model (its trend and force terms, G⁻¹ on a rig, its FLOW and invertible VALVE effects),
        and ``does_not_invert``, what it cannot (left to the feedback and the learning)."""
        return {n: {"inverts": list(f.inverted), "does_not_invert": list(f.not_inverted)}
                for n, f in zip(self.names, self.ff[1.0].channels)}

    @property
    def feedforward_pct(self) -> np.ndarray:
        """(N, samples): every channel's feedforward planned for each sample of the reference, for
        the way its rod last moved when the main phase began (None before)."""
        return self._u

    @property
    def pacing_tolerances_kgf(self) -> np.ndarray:
        """Every channel's ε: the given one, else :data:`DEFAULT_TOLERANCE_SHARE` of its
        programme's range (at least 5 kgf: a channel that keeps one level)."""
        if self.pacing.tolerance_kgf is not None:
            return np.full(self.n, float(self.pacing.tolerance_kgf))
        return np.maximum(DEFAULT_TOLERANCE_SHARE * self.programme.ranges_kgf, 5.0)

    def programme_times(self, t_s: np.ndarray) -> np.ndarray:
        """The run's times ``t_s`` on the programme's clock (0 at its start): with pacing, each
        cycle of the main phase at the clock's position then (a wait's cycles share a time)."""
        t = np.asarray(t_s, float)
        t0 = self.programme_start_s or 0.0
        if not self.positions or self.main_start_s is None:
            return t - t0
        T = self.period_s
        i = np.round((t - self.main_start_s) / T).astype(int)
        pos = np.asarray(self.positions)
        inside = (i >= 0) & (i < len(pos))
        return np.where(inside, (pos[np.clip(i, 0, len(pos) - 1)] - self.lead) * T, t - t0)

    def check(self, period_s: float, force_limits_kgf: Sequence[float], command_limit_pct: float) -> None:
        """Refuse what the station must not be asked for, before anything moves."""
        if abs(self.controller.period_s - period_s) > 1e-9:
            raise ParameterError(
                f"the controller was designed for a period of {self.controller.period_s * 1e3:g} ms but "
                f"the loop runs at {period_s * 1e3:g} ms; design it again with --period-ms {period_s * 1e3:g}")
        self.programme.check(force_limits_kgf)
        self.commanded.check(force_limits_kgf)
        limit = min(command_limit_pct, self.controller.command_limit_pct)
        worst = max(((i, ff) for ff in self.ff.values() for i in range(self.n)),
                    key=lambda x: x[1].channels[x[0]].peak_pct)
        i, ff = worst
        peak = ff.channels[i].peak_pct
        if peak > FEEDFORWARD_SHARE * limit:
            k = int(np.argmax(np.abs(ff.channels[i].u_pct)))
            at = f"at t = {(k - self.lead) * period_s:.2f} s"
            if self.n == 1:
                raise ParameterError(
                    f"{self.programme.source}: {at} the programme needs a valve command of {peak:.1f} % by "
                    f"the model, over {FEEDFORWARD_SHARE:.0%} of the command limit ±{limit:g} %: the valve "
                    "cannot follow this rate; lower --rate or --frequency")
            raise ParameterError(
                f"{self.programme.source}: channel {self.names[i]} {at} needs a valve command of {peak:.1f} % "
                f"by the rig's model, over {FEEDFORWARD_SHARE:.0%} of the command limit ±{limit:g} %: its "
                "valve cannot follow this rate (with the neighbours' flows through the structure); lower "
                "--rate or --frequency")

    # -- the loop's calls ----------------------------------------------------------------------
    def configure_rig(self, period_s: float, force_limits_kgf: Sequence[float]) -> None:
        self.force_limits = np.asarray(force_limits_kgf, float)

    def begin_rig(self, y0: Sequence[float]) -> None:
        self.abort = None
        self.abort_channel = None
        self.abort_action = "hold"
        self.main_start_s = None
        self.approach.begin(np.asarray(y0, float))
        self.way = self.approach.way.copy()
        if self.approach.done_at is not None:
            self._begin_main(0.0)

    def fresh(self) -> "LoadProgramme":
        """Another pass of the same programme with its own state, sharing what was computed
        for it (the feedforward and the plans, read only): the same flight flown again."""
        new = copy.copy(self)
        new.law = copy.copy(self.law)
        new.approach = copy.copy(self.approach)
        new.main_start_s = None
        new.abort, new.abort_channel = None, None
        new.positions, new.clock = [], None
        return new

    def begin_handover(self, ways: Sequence[float], integral_pct: Sequence[float]) -> None:
        """Begin at once, instead of :meth:`begin_rig`, where the pass before left off (this
        one made with its last samples as ``lead_in``): every rod last moved ``ways`` (±1 per
        channel: the plan of that way is taken) and the feedback's integral is ``integral_pct``
        (carried on, so the hand-over is bumpless). No approach, no pre-roll."""
        if not self.handover:
            raise ParameterError("begin_handover: this pass has no lead_in to take over on")
        self.abort = None
        self.abort_channel = None
        self.abort_action = "hold"
        self._begin_main(0.0, np.where(np.asarray(ways, float) < 0, -1.0, 1.0), handover=True)
        self.law.reset(integral_pct)

    def _begin_main(self, t: float, way: np.ndarray | None = None, handover: bool = False) -> None:
        """The main phase begins at ``t``: each channel's plan for ``way``; the gain monitor's
        pass begins, or on a hand-over goes on (the passes are one motion)."""
        self.main_start_s = t
        self.law.reset()
        self.way = (self.approach.way if way is None else way).copy()
        plans = [self.plans[float(w)][i] for i, w in enumerate(self.way)]
        self._u = np.array([p.u for p in plans])
        self._scale = np.array([p.scale for p in plans])
        self._hold = np.array([p.way for p in plans])
        self._factor = np.array([p.factor for p in plans])
        if self.monitor is not None and not (handover and self.monitor.in_pass):
            self.monitor.begin_pass()
        self.positions = []
        self.clock = None
        if self.pacing.on:
            T = self.period_s
            model = self.controller.model
            cases = self.commanded.turning_idx[self.commanded.turning_cases()]
            self.clock = ProgrammeClock(
                self.reference, self.lead + cases, [int(round(m.tau / T)) for m in model.channels],
                np.diag(self.controller.G), T, self.pacing, self.pacing_tolerances_kgf, start=self.lead)

    def finished_rig(self, t: float, ys: Sequence[float]) -> bool:
        if self.clock is not None:
            return self.main_start_s is not None and self.clock.finished
        return self.main_start_s is not None and t - self.main_start_s >= self.main_duration_s - 1e-9

    def step_rig(self, t: float, ys: Sequence[float]) -> tuple[list[float], list[float]]:
        """Every channel's command (%) and reference (kgf, NaN during the approach)."""
        y = np.asarray(ys, float)
        near = np.abs(y) >= self.guard_fraction * self.force_limits
        if np.any(near):
            i = int(np.flatnonzero(near)[0])
            self.abort_channel = i          # the message is the channel's (the loop names it)
            self.abort = (FORCE_NEAR_LIMIT,
                          f"force {y[i]:.0f} kgf reached {self.guard_fraction:.0%} of "
                          f"its force limit ±{self.force_limits[i]:.0f} kgf; the load stopped itself")
            return [0.0] * self.n, [math.nan] * self.n
        if self.main_start_s is None:
            u = self.approach.step(t, y)
            if u is not None:
                return u.tolist(), [math.nan] * self.n
            if self.approach.failed:
                self.abort = (SET_POINT_NOT_REACHED, self.approach.failure_message(y))
                return [0.0] * self.n, [math.nan] * self.n
            self._begin_main(t)
        if self.clock is not None:
            return self._paced_step(y)
        k = min(int(round((t - self.main_start_s) / self.period_s)), self.reference.shape[1] - 1)
        r = self.reference[:, k]
        u = self.law.step(r, y, self._followed(self._u[:, k]), self._scale[:, k], self._hold[:, k])
        if self.monitor is not None and self.abort is None:
            self._watch(y, u, k)
        return u.tolist(), r.tolist()

    def _followed(self, ff: np.ndarray) -> np.ndarray:
        """The feedforward as the gain monitor follows the station's gains (unchanged without
        it): through G⁻¹ the rows' factors, ``G⁻¹·diag(G_ii/ĝ_i)·G``; each channel's own
        feedforward its own ``G_ii/ĝ_i``."""
        monitor = self.monitor
        if monitor is None or not monitor.options.follow:
            return ff
        if self.controller.feedforward == "rig":
            return monitor.ff_matrix @ ff
        return monitor.ff_scales * ff

    def _paced_step(self, y: np.ndarray) -> tuple[list[float], list[float]]:
        """One cycle on the programme's clock (loading.pacing): the references and the
        feedforward at its position; while it waits at a load case, the flows that hold the
        forces and a P law on the predicted forces toward the levels."""
        clock = self.clock
        p = clock.advance(y)
        self.positions.append(p)
        r = clock.reference_at(p)
        if clock.waited_too_long():
            self._waited_too_long(clock, y)
            return [0.0] * self.n, r.tolist()
        k = int(p)
        k1 = min(k + 1, self.reference.shape[1] - 1)
        planned = self._u[:, k] + (p - k) * (self._u[:, k1] - self._u[:, k])
        s = clock.step_taken                 # the slowed programme's flows, holding while it waits
        ff = self._followed(s * planned + (1.0 - s) * self.hold_flows)
        if clock.waiting:
            if clock.wait_began:
                self.law.reset()
            gate = clock.gate
            u = self.law.wait_step(gate.levels_kgf - clock.predicted_kgf, ff, gate.way)
        else:
            u = self.law.step(r, y, ff, self._scale[:, k], self._hold[:, k], integrate=s >= 1.0)
        clock.sent(u, ff)
        if self.monitor is not None and self.abort is None:
            self._watch(y, u, k)
        return u.tolist(), r.tolist()

    def _waited_too_long(self, clock: ProgrammeClock, y: np.ndarray) -> None:
        """A wait beyond the timeout: the pass stops, naming the channel furthest from its level."""
        gate = clock.gate
        tol = self.pacing_tolerances_kgf
        i = self.abort_channel = int(np.argmax(clock.short_kgf(gate) / tol))
        if self.n == 1:
            what = f"the force did not reach the turning point {gate.levels_kgf[0]:.0f} kgf"
        else:
            k = int(np.flatnonzero(self.programme.turning_idx == gate.turning - self.lead)[0])
            label = (self.programme.case_labels or [str(j + 1) for j in range(k + 1)])[k]
            what = f"its force did not reach load case {label} ({gate.levels_kgf[i]:.0f} kgf)"
        self.abort = (PACING_TIMEOUT,
                      f"{what} within {tol[i]:.0f} kgf in {self.pacing.timeout_s:g} s of waiting (at "
                      f"{y[i]:.0f} kgf, {clock.predicted_kgf[i]:.0f} predicted): the "
                      + ("stand" if self.n == 1 else "rig") + " cannot reach it; check the "
                      + ("stand" if self.n == 1 else "channel") + ", the model and the programme's levels")

    def _watch(self, y: np.ndarray, u: np.ndarray, k: int) -> None:
        """The gain monitor's cycle, and its alarm's action on the whole station."""
        monitor = self.monitor
        before = monitor.alarm
        monitor.add(y, u, self._factor[:, k])
        if monitor.alarm is None or before is not None or monitor.options.action == "note":
            return
        i = self.abort_channel = monitor.alarm_channel
        own = monitor.channels[i].alarm[1]          # the loop names the channel
        if monitor.options.action == "unload":
            self.abort_action = "unload"
            self.abort = (GAIN_ALARM, own + ("; the stand unloads" if self.n == 1 else
                                             "; every channel unloads keeping the load ratios"))
        else:
            self.abort = (GAIN_ALARM, own + ("; the valve holds" if self.n == 1 else "; every valve holds"))
