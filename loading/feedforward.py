r"""Feedforward through the model's inverse: every channel's command that makes the model follow a
programme.

The programme is known in advance, so the whole command can be computed before the run. For the
paper's model ``dy/dt = g·u(t−τ) + Δ`` the force must rise by ``r[k+1] − r[k]`` over step k, so
one channel's flow command is

.. math::  q_k = \frac{(r_{k+1} - r_k)/T - \Delta - \sum_j F_j(r_k)}{g}

(``F_j``: the model's force-dependent rate terms, e.g. a leakage), sent ``τ = (m + f)·T``
earlier: ``u_k = (1 − f)·q_{k+m} + f·q_{k+m+1}``. Where the model has them, its effects are
inverted on the way:

* **FLOW** effects (a gain factor ``G(q, ·)``: the reversal boost, an asymmetry, a supply sag,
  a plug-in's law): ``q·G(q) = v`` is solved per sample by bisection on ``|q|`` with the sign of
  ``v``, through the effect's own hooks (so any FLOW effect is inverted, the catalogue's and a
  user's alike), iterating when the effect's state depends on ``q`` itself;
* **VALVE** effects through their own :meth:`~plant.Effect.invert` where they have one: a
  dead zone (``u = q + d·sign q``), a valve lag (``u = q + T_v·dq/dt``), a plug-in's.

Effects it cannot invert (saturation, a play, a sensor filter, disturbances) are listed in
:attr:`ChannelFeedforward.not_inverted`: the feedback handles what they do.

**A station of channels** (:func:`feedforward`): for the rig's model ``dy/dt = G·w(t − τ) + Δ +
F(y)`` (:mod:`plant.rig`) the forces follow the references ``r`` when the flows are

.. math::  w_k = G^{-1}\Big(\frac{r_{k+1} - r_k}{T} - \Delta - F(r_k)\Big),

and each channel's flow ``w_j`` is then made by its own valve as above (its FLOW effects
inverted, knowing the way its rod last moved; its VALVE effects; its command sent its own delay
``τ_j`` ahead). That is the mode ``rig``; the mode ``channel`` gives each channel the feedforward
of its own model (``w_j = (ṙ_j − Δ_j − F_j)/g_j``: the coupling left to the feedback, the
independent baseline; for one channel the same flows), and ``none`` no feedforward (feedback
alone). Through G⁻¹ a valve whose channel's force is made by its neighbours runs at small flows
for long, so there no flow command below the valve's resolution is planned
(:data:`RESOLUTION_PCT`): a flow of a fraction of a count would be a reversal the rod never
makes.

**The gain the feedback meets.** Along the planned flow the FLOW effects also say how strongly
the stand answers a small change of the command: the secant slope of ``q·ΠG(q)`` over
:data:`SECANT_PCT` either side of the planned ``q`` (the larger side),
:attr:`Feedforward.gain_factor`. Right after a reversal, while the planned flow is still small,
the reversal boost makes it far larger than its value at ``u_ref`` that the design's ``ρ``
counts (``1 + b·(u_ref/0.5 %)^p``: 17× for b = 2, p = 0.7, against ρ = 3); the load experiment
lowers the feedback's gain there so the loop never meets more than ``ρ``
(:func:`feedback_scale`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from plant import PlantModel, Stage
from plant.rig import RigModel

#: bisection steps on |q| (2^-40 of the bracket)
BISECTION_STEPS = 40
#: the largest flow command the inversion looks for (%)
Q_MAX = 400.0
#: the change of the flow command over which the local gain is taken (%): about what the
#: feedback adds to the feedforward near a turning point
SECANT_PCT = 0.5


#: the valve command's resolution (%): one count of the CiA 408 setpoint (16384 counts per
#: 100 %, dbc.profile); the feedforward through G⁻¹ plans no flow below it
RESOLUTION_PCT = 100.0 / 16384


@dataclass
class ChannelFeedforward:
    """One channel's command to send in each cycle of a programme (%), and what the inversion
    covered."""

    u_pct: np.ndarray
    q_pct: np.ndarray          #: the flow command the model needs at each step (before the valve)
    inverted: list[str] = field(default_factory=list)
    not_inverted: list[str] = field(default_factory=list)
    #: per cycle, aligned with ``u_pct`` (τ ahead): the largest factor by which the model's
    #: FLOW effects raise the stand's gain to a change of the command, from a delay before to
    #: a delay after the cycle's command acts (1 without FLOW effects)
    gain_factor: np.ndarray | None = None
    #: per cycle, aligned with ``u_pct``: the model's FLOW factor ``ΠG`` on the planned flow
    #: where the cycle's command acts (1: steady; the gain monitor reads the stand there)
    flow_factor: np.ndarray | None = None

    @property
    def peak_pct(self) -> float:
        return float(np.max(np.abs(self.u_pct))) if len(self.u_pct) else 0.0


def _flow(flows, aux, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``q·ΠG(q)``: the flow the FLOW effects make of the command ``q`` (their state ``aux``)."""
    out = q.copy()
    for e, a in zip(flows, aux):
        out = out * e.gain(q[None, :], a, r[None, :])[0]
    return out


def _flow_inverse(model: PlantModel, v: np.ndarray, r: np.ndarray, dt: float,
                  t: np.ndarray, direction: float | None = None, resolution_pct: float = 0.0
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve ``q·ΠG(q) = v`` for q per sample through the model's FLOW effects' hooks; also
    the local gain factor along q and the factor ``ΠG`` itself (see the module docstring).
    ``direction``: the way the rod last moved before the programme (±1; default: the way it
    first moves). ``resolution_pct``: a command below it is 0 (the valve cannot be sent less),
    so the reversals the inversion plans are the ones the valve will make."""
    flows = [e for e in model.effects if e.stage is Stage.FLOW]
    q = v.copy()
    if not flows:
        return q, np.ones_like(q), np.ones_like(q)
    # the flow of the first m steps was commanded before the programme began and is never
    # sent: the inversion starts at step m, the rod moving already the way it goes there (or
    # the way it is known to have moved)
    m = min(model.delay_steps(dt), len(v) - 1)
    head, v, r, t = v[:m], v[m:], r[m:], t[m:]
    q = v.copy()
    sign = np.where(v >= 0, 1.0, -1.0)
    target = np.abs(v)
    moving = np.flatnonzero(np.abs(v) > 1e-9)
    u0 = v[moving[:1]] if len(moving) else v[:1]
    if direction:
        u0 = np.array([float(direction)])

    def prepared(q):
        aux = []
        for e in flows:
            state = e.init_state(1, u0)
            kw = {}
            if e.reads_command:
                kw["command"] = np.r_[q[m:], np.full(m, q[-1])][None, :]
            if e.reads_time:
                kw["t"] = t[None, :]
            aux.append(e.prepare(q[None, :], dt, state, **kw))
        return aux

    zero = np.zeros(len(q), bool)             # planned as no flow (resolution_pct)
    for _ in range(3 if resolution_pct <= 0 else 8):
        aux = prepared(q)
        lo = np.zeros_like(target)
        hi = np.full_like(target, Q_MAX)
        for _ in range(BISECTION_STEPS):
            mid = (lo + hi) / 2
            above = np.abs(_flow(flows, aux, sign * mid, r)) > target
            hi = np.where(above, mid, hi)
            lo = np.where(above, lo, mid)
        new = sign * (lo + hi) / 2
        if resolution_pct > 0:
            zero |= _below_resolution(new, resolution_pct, u0[0] if len(u0) else 0.0)
            new[zero] = 0.0
        if np.allclose(new, q, atol=1e-6):
            q = new
            break
        q = new
    aux = prepared(q)
    h = SECANT_PCT
    at = _flow(flows, aux, q, r)
    gain = np.maximum(_flow(flows, aux, q + h, r) - at, at - _flow(flows, aux, q - h, r)) / h
    moving = np.abs(q) > 1e-9
    factor = np.where(moving, at / np.where(moving, q, 1.0), _flow(flows, aux, np.full_like(q, 1e-3), r) / 1e-3)
    ones = np.ones(len(head))
    return np.r_[head, q], np.r_[ones, np.maximum(gain, 0.0)], np.r_[ones, factor]


#: a planned excursion of the flow command the other way whose largest command is under this
#: many resolution steps is not planned (no flow instead): its reversal and back would move the
#: rod by a few counts' worth, and whether the valve makes it depends on the rounding
BLIP_STEPS = 4


def _below_resolution(q: np.ndarray, resolution_pct: float, direction0: float) -> np.ndarray:
    """Where the planned flow command ``q`` is to be no flow: under half a resolution step
    (the valve rounds it to 0), and every excursion the other way (a run between two commands
    of the held direction, a zero keeping the last direction) whose largest command is under
    :data:`BLIP_STEPS` steps."""
    out = np.abs(q) < resolution_pct / 2
    sgn = np.where(out, 0.0, np.sign(q))
    moving = np.flatnonzero(sgn != 0)
    if not len(moving):
        return out
    # runs of one sign among the nonzero commands
    s = sgn[moving]
    edges = np.flatnonzero(np.diff(s) != 0) + 1
    starts, ends = np.r_[0, edges], np.r_[edges, len(s)]
    before = np.r_[direction0 if direction0 else s[0], s[starts[1:] - 1]]
    for a, b, prev in zip(starts, ends, before):
        nxt = s[b] if b < len(s) else prev
        if s[a] != prev and nxt == prev and np.max(np.abs(q[moving[a:b]])) < BLIP_STEPS * resolution_pct:
            lo = moving[a - 1] + 1 if a > 0 else 0
            hi = moving[b] if b < len(s) else len(q)
            out[lo:hi] = True
    return out


def channel_feedforward(model: PlantModel, r_kgf: np.ndarray, period_s: float,
                        t_s: np.ndarray | None = None, direction: float | None = None) -> ChannelFeedforward:
    """The command (%) for each cycle that makes ``model`` follow the reference ``r_kgf``
    sampled at ``period_s`` (see the module docstring). ``direction`` (±1): the way the rod
    last moved before the reference starts, where it is known (a first motion the other way
    is then a reversal, with what the model's FLOW effects do at one)."""
    r = np.asarray(r_kgf, float)
    rate, inverted = own_rate(model, r, period_s)
    return feedforward_flow(model, rate / model.g, r, period_s, t_s, direction, inverted)


def own_rate(model: PlantModel, r_kgf: np.ndarray, period_s: float) -> tuple[np.ndarray, list[str]]:
    r"""The force rate the channel's flow must make for the reference: ``(r[k+1] − r[k])/T − Δ
    − ΣF_j(r[k])`` (kgf/s per step), with the names of what it took off (the base's trend and
    every FORCE effect)."""
    r = np.asarray(r_kgf, float)
    rate = np.r_[np.diff(r), 0.0] / float(period_s) - model.delta
    taken = ["base"]
    for e in model.effects:
        if e.stage is Stage.FORCE:
            rate = rate - e.force_rate(r[None, :])[0]
            taken.append(e.name)
    return rate, taken


def feedforward_flow(model: PlantModel, flow_pct: np.ndarray, r_kgf: np.ndarray, period_s: float,
                     t_s: np.ndarray | None = None, direction: float | None = None,
                     inverted: list[str] | None = None, resolution_pct: float = 0.0) -> ChannelFeedforward:
    r"""The command (%) for each cycle that makes the channel's flow ``w = q·ΠG(q)`` (in the
    units of the command, the flow the base's ``g`` multiplies) be ``flow_pct`` per step, its
    own force following ``r_kgf``: the FLOW effects inverted per sample, then the VALVE
    effects, then sent the model's delay ahead (module docstring). :func:`channel_feedforward`
    is the case ``w = (ṙ − Δ − ΣF)/g``; a rig's channel gets its ``w`` from ``G⁻¹``
    (:func:`feedforward`). ``inverted``: what made ``flow_pct`` (names);
    ``resolution_pct``: the valve's command resolution, a planned flow command below it is 0
    (where a valve runs at small flows for long, as a rig's may, a planned flow of a fraction
    of a count would be a reversal the rod never makes)."""
    r = np.asarray(r_kgf, float)
    dt = float(period_s)
    t = np.arange(len(r)) * dt if t_s is None else np.asarray(t_s, float)
    inverted, skipped = list(inverted or []), []
    v = np.asarray(flow_pct, float)
    q, gain, factor = _flow_inverse(model, v, r, dt, t, direction, resolution_pct)
    u = q.copy()
    for e in reversed([e for e in model.effects if e.stage is Stage.VALVE]):
        before = e.invert(u, dt)
        if before is None:
            skipped.append(e.name)
            continue
        u = np.asarray(before, float)
        inverted.append(e.name)
    for e in model.effects:
        if e.stage is Stage.FLOW:
            inverted.append(e.name)
        elif e.stage in (Stage.DISTURBANCE, Stage.SENSOR):
            skipped.append(e.name)
    whole = model.tau / dt
    m = int(np.floor(whole + 1e-9))
    f = whole - m
    pad = np.r_[u, np.zeros(m + 2)]
    ahead = (1 - f) * pad[m:m + len(u)] + f * pad[m + 1:m + 1 + len(u)]
    # the gain a command meets when it acts (τ later), the largest within a delay either side
    acts = np.r_[np.ones(m), gain, np.ones(3 * m + 2)]
    acts = np.maximum(acts[:-1], acts[1:])
    window = np.lib.stride_tricks.sliding_window_view(acts, 2 * m + 1)[m:m + len(u)].max(axis=1)
    # the FLOW factor where each cycle's command acts (a delay later)
    flow = np.r_[factor, np.full(m + 2, factor[-1] if len(factor) else 1.0)]
    flow_ahead = (1 - f) * flow[m:m + len(u)] + f * flow[m + 1:m + 1 + len(u)]
    return ChannelFeedforward(ahead, q, inverted, skipped, window, flow_ahead)


def feedback_scale(ff: ChannelFeedforward, rho: float) -> np.ndarray:
    """Per cycle, the share of the designed feedback gain that keeps the loop's gain within
    the ``rho`` the design's margins were computed at: ``min(1, ρ/gain_factor)`` (1 wherever the
    model's gain stays within ρ, so a model without FLOW effects keeps its full feedback)."""
    if ff.gain_factor is None:
        return np.ones_like(ff.u_pct)
    return np.minimum(1.0, max(rho, 1.0) / np.maximum(ff.gain_factor, 1e-12))


# -- a station ----------------------------------------------------------------------------------
#: the station's feedforward modes (module docstring)
MODES = ("rig", "channel", "none")


@dataclass
class Feedforward:
    """Every channel's :class:`ChannelFeedforward` for one programme, and the flows ``w``
    (N, K) they were made for."""

    channels: list[ChannelFeedforward]
    flow_pct: np.ndarray

    @property
    def u_pct(self) -> np.ndarray:
        """(N, K): every channel's command per cycle."""
        return np.array([f.u_pct for f in self.channels])

    @property
    def peak_pct(self) -> np.ndarray:
        return np.array([f.peak_pct for f in self.channels])

    def scales(self, boosts: Sequence[float]) -> np.ndarray:
        """(N, K): each valve's share of the feedback (:func:`feedback_scale` at its channel's ρ)."""
        return np.array([feedback_scale(f, b) for f, b in zip(self.channels, boosts)])


def required_flows(model: RigModel, r_kgf: np.ndarray, period_s: float) -> tuple[np.ndarray, list[list[str]]]:
    """``w`` (N, K) for the references ``r_kgf`` (N, K) through G⁻¹ (module docstring), and per
    channel the names of what was taken off its rate (``base``, its FORCE effects)."""
    R = np.asarray(r_kgf, float)
    rates, taken = [], []
    for m, r in zip(model.channels, R):
        rate, names = own_rate(m, r, period_s)
        rates.append(rate)
        taken.append(names)
    return np.linalg.solve(model.G, np.array(rates)), taken


def feedforward(model: RigModel, r_kgf: np.ndarray, period_s: float,
                directions: Sequence[float | None] | None = None, mode: str = "rig",
                resolution_pct: float = RESOLUTION_PCT) -> Feedforward:
    """Every channel's command for the references ``r_kgf`` (N, K) (module docstring):
    ``mode`` ``rig`` through G⁻¹ (no planned flow command below ``resolution_pct``),
    ``channel`` each channel from its own model, ``none`` zero commands (feedback alone);
    ``directions``: per channel the way its rod last moved before the references start (±1,
    None: the way it first moves)."""
    R = np.asarray(r_kgf, float)
    directions = list(directions) if directions is not None else [None] * model.n
    if mode == "rig":
        w, taken = required_flows(model, R, period_s)
        ffs = [feedforward_flow(m, w[i], R[i], period_s, direction=directions[i], inverted=taken[i] + ["G⁻¹"],
                                resolution_pct=resolution_pct)
               for i, m in enumerate(model.channels)]
        return Feedforward(ffs, w)
    if mode == "channel":
        ffs = [channel_feedforward(m, R[i], period_s, direction=directions[i])
               for i, m in enumerate(model.channels)]
        return Feedforward(ffs, np.array([f.q_pct for f in ffs]))
    if mode == "none":
        ffs = [ChannelFeedforward(np.zeros(R.shape[1]), np.zeros(R.shape[1]), [], ["all: feedback alone"])
               for _ in model.channels]
        return Feedforward(ffs, np.zeros_like(R))
    raise ValueError(f"feedforward mode {mode!r}: one of {', '.join(MODES)}")
