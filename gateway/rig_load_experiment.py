r"""The rig's load experiment: one pass of a multi-channel programme under the rig's controller.

Every channel at once, each cycle (the experiment is stepped with every channel's force and
returns every channel's command: :meth:`RigLoadProgramme.step_rig`)::

    approach   every force along one straight line (a haversine in time) to the pre-roll's
               start, the feedforward of the base model through the controller's G⁻¹ and the
               designed P gains through its mixing matrix, each valve moving one way only
               (holding rather than reversing), then held until every force is within the
               tolerance, each valve then on the way of the flow that holds its force
               against the trends (−G⁻¹Δ: one planned reversal where the line ends)
    pre-roll   a straight line into the first load case (:data:`PRE_ROLL_S`) along the rig's
               trend, so that every valve keeps the sign of the command that holds the forces
    programme  u = feedforward through the rig model's inverse + PI through M
               (loading.rig_controller)
    unload     a straight line from the last load case to the unload level (every channel in the
               same time: the ratios kept), tracked the same way

**The pre-roll along the trend.** A held rig needs the flows ``w = −G^{-1}Δ`` (Δ the channels'
trends); a pre-roll that moves the forces by ``d`` needs ``G^{-1}(d·ḣ − Δ)``. With ``d = −c·Δ``
(``c > 0``) both have the same sign at every valve, so every valve's command keeps one sign from
the pre-roll into the hold at the first load case and the programme's first motion is, on each
channel, a single planned reversal or none (the one-channel pre-roll's reason,
:mod:`gateway.load_experiment`). ``c`` makes the channel with the largest trend for its range
move :data:`PRE_ROLL_SHARE` of its range (at least three tolerances); a start that would cross
0 kgf on some channel shortens ``c``. A rig without trends pre-rolls the way the programme
first moves.

**The way each rod last moved** is known from the approach (each valve moves one way), and the
feedforward is planned both ways for every channel before the run; at the approach's end each
channel takes the plan of its own way.

**The gain monitor** (``monitor``, :mod:`loading.rig_gain_monitor`): every cycle of the
programme feeds it every force and command; following, the feedforward is multiplied by its
matrix; its alarm holds every valve (``hold``) or unloads every channel keeping the load ratios
(``unload``: the abort asks the loop for the rig's unload).

**Null pacing** (``pacing``, :mod:`loading.rig_pacing`): the programme's one clock waits at a
load case's gate until every channel's predicted force is within its tolerance of its level
(``static``), and slows for all while any channel lags (``dynamic``); the references, the feedforward and the feedback's schedule are read at the clock's
position (:attr:`RigLoadProgramme.positions`, per cycle).

**No reversal the model does not plan**, per valve, as for one channel: where the model
predicts a gain above the channel's ρ and during the pre-roll the valve keeps its feedforward's
sign or holds.

Everything that can be checked is checked before anything moves (:meth:`RigLoadProgramme.check`):
the controller's period and channels against the rig's, every channel's programme against its
force limit, every valve's feedforward peak against the command limit (naming the channel and
the time).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from core.errors import ParameterError
from loading.feedforward import feedback_scale
from loading.gain_monitor import GAIN_ALARM
from loading.minimum_time import FEEDFORWARD_SHARE
from loading.pacing import DEFAULT_TOLERANCE_SHARE, PACING_TIMEOUT, PacingOptions
from loading.rig_compensation import RigCompensation
from loading.rig_controller import RigPIFeedforward
from loading.rig_design import RigControllerDesign
from loading.rig_feedforward import RigFeedforward, channel_feedforward, rig_feedforward
from loading.rig_gain_monitor import RigGainMonitor
from loading.rig_pacing import RigProgrammeClock
from loading.rig_programme import RigProgramme

from .experiments.phases import FORCE_NEAR_LIMIT, SET_POINT_NOT_REACHED, Dwell
from .experiments.rig import RigExperiment

PRE_ROLL_SHARE = 0.02
PRE_ROLL_S = 0.6
#: the approach's peak rate (kgf/s, the channel that moves the most) and its command limit (%)
APPROACH_RATE_KGF_S = 1000.0
APPROACH_LIMIT_PCT = 20.0


def _line(start: np.ndarray, end: np.ndarray, rate_kgf_s: float, period_s: float,
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
    """The pre-roll's start (module docstring): ``L0 + c·Δ``, or against the first motion
    without trends."""
    ranges = np.maximum(ranges, 1.0)
    direction = np.asarray(trends, float)
    if not np.any(direction):
        direction = -(levels1 - levels0)
    rel = np.max(np.abs(direction) / ranges)
    if rel == 0:
        return levels0.copy()
    c = PRE_ROLL_SHARE / rel
    c = max(c, 3 * tolerance_kgf / float(np.max(np.abs(direction))))
    start = levels0 + c * direction
    crossing = (np.sign(start) != np.sign(levels0)) & (direction != 0) & (levels0 != 0)
    if np.any(crossing):          # no channel's pre-roll crosses 0 kgf: a shorter one for all
        c = min(c, float(np.min(np.abs(levels0[crossing] / direction[crossing]))))
        start = levels0 + c * direction
    return start


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


class RigApproach:
    """Every force to the pre-roll's start along one straight line (module docstring)."""

    def __init__(self, controller: RigControllerDesign, target_kgf: np.ndarray, period_s: float,
                 tolerance_kgf: float = 20.0, hold_s: float = 0.1, max_s: float = 20.0,
                 rate_kgf_s: float = APPROACH_RATE_KGF_S, limit_pct: float = APPROACH_LIMIT_PCT) -> None:
        self.target = np.asarray(target_kgf, float)
        self.T = period_s
        self.tolerance = tolerance_kgf
        self.hold_s, self.max_s = hold_s, max_s
        self.line_rate, self.limit = rate_kgf_s, limit_pct
        G = controller.G
        self.model = controller.model
        #: rates (kgf/s) to commands (%): the base model's inverse, the rig's or each channel's
        self.to_command = np.linalg.inv(G)
        self.Mkp = controller.M * np.array([c.kp_pct_per_kgf for c in controller.channels])[None, :]
        self.trend = np.array([m.delta for m in self.model.channels])
        #: the flows that hold every force against the trends (the base model's: −G⁻¹Δ)
        self.hold_flows = -self.to_command @ self.trend
        self.taus = np.array([m.tau for m in self.model.channels])
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


class RigLoadProgramme(RigExperiment):
    """One pass of a rig's programme under the rig's controller (module docstring).

    Stepped for every channel at once: :meth:`configure_rig`, :meth:`begin_rig` with the first
    forces, then :meth:`step_rig` each cycle until :meth:`finished_rig`."""

    name = "load"

    def __init__(self, programme: RigProgramme, controller: RigControllerDesign,
                 compensation: RigCompensation | None = None, unload_kgf: float = 0.0,
                 settle_tolerance_kgf: float = 20.0, settle_max_s: float = 20.0,
                 guard_fraction: float = 0.95, monitor: RigGainMonitor | None = None,
                 pacing: PacingOptions | None = None) -> None:
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
        self.commanded = (programme.with_levels(compensation.levels(programme))
                          if compensation is not None else programme)
        model = controller.model
        self.trends = np.array([m.delta for m in model.channels])
        R = self.commanded.r_kgf
        first_move = R[:, np.argmax(np.any(R != R[:, :1], axis=0))] if np.any(R != R[:, :1]) else R[:, 0]
        start = pre_roll_start(R[:, 0], first_move, self.trends, programme.ranges_kgf, settle_tolerance_kgf)
        n_pre = max(int(round(PRE_ROLL_S / T)), 1)
        s = np.arange(n_pre) / n_pre
        pre = start[:, None] + (R[:, 0] - start)[:, None] * (1 - np.cos(np.pi * s))[None, :] / 2
        rates = np.abs(np.array([p.rate_kgf_s() for p in programme.channels]))
        peak = float(rates.max()) or 1000.0
        tail = _line(R[:, -1], np.full(self.n, float(unload_kgf)), min(peak, 2500.0), T, False)
        #: cycles of the main phase before the programme's start (the pre-roll)
        self.lead = n_pre
        self.reference = np.concatenate([pre, R, tail], axis=1)
        self.unload_kgf = unload_kgf
        make = rig_feedforward if controller.feedforward == "rig" else channel_feedforward
        #: the feedforward for every channel, planned for each way its rod may last have moved
        self.ff: dict[float, RigFeedforward] = {
            way: make(model, self.reference, T, directions=[way] * self.n) for way in (1.0, -1.0)}
        self.plans = {way: self._plans(ff, way) for way, ff in self.ff.items()}
        self.max_command_pct = controller.command_limit_pct
        self.law = RigPIFeedforward([c.kp_pct_per_kgf for c in controller.channels],
                                    [c.ti_s for c in controller.channels], T,
                                    controller.command_limit_pct, controller.M)
        self.approach = RigApproach(controller, self.reference[:, 0], T, settle_tolerance_kgf,
                                    max_s=settle_max_s)
        self.guard_fraction = guard_fraction
        self.force_limits = np.full(self.n, math.inf)
        self.way = np.ones(self.n)
        self.main_start_s: float | None = None
        self.abort: tuple[str, str] | None = None
        self.abort_channel: int | None = None
        #: the gain monitor of the test, shared by its passes (loading.rig_gain_monitor)
        self.monitor = monitor
        #: with pacing: the programme's clock of the pass, and its position per cycle of the main
        #: phase (samples of the reference, fractional while it slows)
        self.clock: RigProgrammeClock | None = None
        self.positions: list[float] = []
        self._u = self._scale = self._hold = self._factor = None

    def _plans(self, ff: RigFeedforward, way: float) -> list[_ChannelPlan]:
        """Each channel's feedforward, feedback share and held sign when its rod last moved
        ``way``. The rig's feedforward holds each valve's sign everywhere its channel's model
        has a reversal boost (ρ > 1; module docstring); the independent baseline holds it as
        the one-channel experiment does (where the model's gain exceeds ρ, and the pre-roll)."""
        out = []
        everywhere = self.controller.feedforward == "rig"
        for f, c in zip(ff.channels, self.controller.channels):
            scale = feedback_scale(f, c.boost)
            held = scale < 1.0
            held[:self.lead] = True
            if everywhere and c.boost > 1.0:
                held[:] = True
            factor = f.flow_factor if f.flow_factor is not None else np.ones(len(f.u_pct))
            out.append(_ChannelPlan(f.u_pct, scale, np.where(held, held_direction(f.u_pct, way), 0.0),
                                    factor))
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
        c = self.controller
        ff = self.ff[1.0]
        return {"programme": self.programme.source, "channels": self.names,
                "load_cases": int(len(self.programme.turning_idx)) if self.programme.load_cases else None,
                "ranges_kgf": self.programme.ranges_kgf.tolist(), "feedback": c.feedback,
                "feedforward": c.feedforward, "detuning": c.detuning,
                "kp_pct_per_kgf": [ch.kp_pct_per_kgf for ch in c.channels],
                "ti_s": [ch.ti_s for ch in c.channels],
                "models": [ch.model_spec for ch in c.channels],
                "feedforward_inverts": [f.inverted for f in ff.channels],
                "feedforward_does_not_invert": [f.not_inverted for f in ff.channels],
                "feedback_scale_min": [float(p.scale.min()) for p in self.plans[1.0]],
                "pre_roll_from_kgf": self.reference[:, 0].tolist(),
                "compensated": self.compensation is not None, "unload_kgf": self.unload_kgf,
                "settle_tolerance_kgf": self.approach.tolerance, "settle_max_s": self.approach.max_s,
                "guard_fraction": self.guard_fraction, "pacing": self.pacing.mode,
                **({"pacing_tolerance_kgf": self.pacing_tolerances_kgf.tolist(),
                    "pacing_timeout_s": self.pacing.timeout_s} if self.pacing.on else {}),
                **({"gain_monitor": dict(vars(self.monitor.options))} if self.monitor is not None else {})}

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
        """Refuse what the rig must not be asked for, before anything moves."""
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
            raise ParameterError(
                f"{self.programme.source}: channel {self.names[i]} at t = {(k - self.lead) * period_s:.2f} s "
                f"needs a valve command of {peak:.1f} % by the rig's model, over "
                f"{FEEDFORWARD_SHARE:.0%} of the command limit ±{limit:g} %: its valve cannot follow "
                "this rate (with the neighbours' flows through the structure); lower --rate or --frequency")

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

    def _begin_main(self, t: float) -> None:
        self.main_start_s = t
        self.law.reset()
        self.way = self.approach.way.copy()
        plans = [self.plans[float(w)][i] for i, w in enumerate(self.way)]
        self._u = np.array([p.u for p in plans])
        self._scale = np.array([p.scale for p in plans])
        self._hold = np.array([p.way for p in plans])
        self._factor = np.array([p.factor for p in plans])
        if self.monitor is not None:
            self.monitor.begin_pass()
        self.positions = []
        self.clock = None
        if self.pacing.on:
            T = self.period_s
            model = self.controller.model
            self.clock = RigProgrammeClock(
                self.reference, self.lead + self.programme.turning_idx[1:],
                [int(round(m.tau / T)) for m in model.channels], np.diag(self.controller.G), T,
                self.pacing, self.pacing_tolerances_kgf, start=self.lead)

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
                self.abort = (SET_POINT_NOT_REACHED,
                              f"the forces did not reach the pre-roll's start within "
                              f"{self.approach.tolerance:.0f} kgf in {self.approach.max_s:g} s after the "
                              f"line (last readings {', '.join(f'{v:.0f}' for v in y)} kgf); check the rig")
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
        """The feedforward as the gain monitor follows the rig's gains (unchanged without it)."""
        monitor = self.monitor
        return monitor.ff_matrix @ ff if monitor is not None and monitor.options.follow else ff

    def _paced_step(self, y: np.ndarray) -> tuple[list[float], list[float]]:
        """One cycle on the programme's clock (loading.rig_pacing): the references and the
        feedforward at its position; while it waits at a load case, the flows that hold the
        forces and a P law on the predicted forces toward the levels."""
        clock = self.clock
        p = clock.advance(y)
        self.positions.append(p)
        r = clock.reference_at(p)
        if clock.waited_too_long():
            gate = clock.gate
            short = clock.short_kgf(gate)
            tol = self.pacing_tolerances_kgf
            i = self.abort_channel = int(np.argmax(short / tol))
            k = int(np.flatnonzero(self.programme.turning_idx == gate.turning - self.lead)[0])
            label = (self.programme.case_labels or [str(j + 1) for j in range(k + 1)])[k]
            self.abort = (PACING_TIMEOUT,
                          f"its force did not reach load case {label} ({gate.levels_kgf[i]:.0f} kgf) within "
                          f"{tol[i]:.0f} kgf in {self.pacing.timeout_s:g} s of waiting (at {y[i]:.0f} kgf, "
                          f"{clock.predicted_kgf[i]:.0f} predicted): the rig cannot reach it; check the "
                          "channel, the model and the load case")
            return [0.0] * self.n, r.tolist()
        k = int(p)
        k1 = min(k + 1, self.reference.shape[1] - 1)
        planned = self._u[:, k] + (p - k) * (self._u[:, k1] - self._u[:, k])
        s = clock.step_taken                 # the slowed programme's flows, holding while it waits
        ff = self._followed(s * planned + (1.0 - s) * self.approach.hold_flows)
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

    def _watch(self, y: np.ndarray, u: np.ndarray, k: int) -> None:
        """The gain monitor's cycle, and its alarm's action on the whole rig."""
        monitor = self.monitor
        before = monitor.alarm
        monitor.add(y, u, self._factor[:, k])
        if monitor.alarm is None or before is not None or monitor.options.action == "note":
            return
        i = self.abort_channel = monitor.alarm_channel
        own = monitor.channels[i].alarm[1]          # the loop names the channel
        if monitor.options.action == "unload":
            self.abort_action = "unload"
            self.abort = (GAIN_ALARM, own + "; every channel unloads keeping the load ratios")
        else:
            self.abort = (GAIN_ALARM, own + "; every valve holds")
