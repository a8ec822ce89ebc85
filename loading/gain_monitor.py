r"""A gain that adapts and watches the specimen: every channel's gain re-estimated block by block.

During a loading run the force and the commands say how strongly the stand answers. Over a
*chunk* of ``c`` cycles (:data:`MonitorOptions.chunk_s`) the model says

.. math::  a = y_{end} - y_{start} - \Delta\,c\,T
           \;=\; \kappa \cdot b,\qquad b = g\,T \sum_{k} G_k\,\tilde q_k,

with ``q̃_k = (1 − f)·u_{k−m} + f·u_{k−m−1}`` the commands actually sent, delayed by
``τ = (m + f)·T``, ``G_k`` the model's FLOW factor on the planned flow there (the reversal
boost, an asymmetry: :attr:`loading.feedforward.ChannelFeedforward.flow_factor`) and ``κ`` the stand's
gain over the model's. Only chunks where the model says the stand is steady count: ``G`` within
:data:`MonitorOptions.steady_factor` along the whole chunk (away from a reversal's boost) and
the flow one way, at least ``min_flow_pct``. A block lasts ``block_s`` of stand time, or
longer until it holds ``min_chunks`` such chunks (a fast programme of short segments is
rarely steady), at most :data:`LONGEST_BLOCK` times as long. Per block the least squares
estimate and its 95 % interval are

.. math::  \hat\kappa = \frac{\sum a b}{\sum b^2},\qquad
           s^2 = \frac{\sum (a - \hat\kappa b)^2}{n - 1},\qquad
           \hat\kappa \pm t_{0.975,\,n-1}\,\frac{s}{\sqrt{\sum b^2}},

``ĝ = κ̂·g`` (a few float operations a cycle; the sums close at each chunk).

**The feedforward follows it** (``follow``): from the next block on, the feedforward is scaled
by ``g/ĝ`` (exact for the base model; first order for FLOW effects), within
``follow_limit_pct`` of the model's g. **The margins are re-checked**: the PI is left as
designed, so its loop gain moves with ``ĝ``; the gain margin scales exactly as ``g/ĝ``, the
phase margin is interpolated from the design's loop computed beforehand at gains across
``[g/2, 2g]``; a block whose margins at ``ĝ`` (the boosted gain ``ĝ·ρ`` for the gain margin)
fall below the design's requirements (gain margin 2; phase margin 45°, less
:data:`PHASE_MARGIN_SLACK_DEG`: the design sits on it) is flagged.

**The alarm**: a fall of g beyond ``fall_pct`` (a crack: the structure softens) or a rise
beyond ``rise_pct`` (a jammed part), relative to the model's g (the stand as identified): the
estimate beyond the threshold, its 95 % interval clear of the model's g (a change, not the
noise), in ``confirm`` consecutive blocks; or margins below the design's. Its action: ``note`` (recorded, the test goes on), ``hold`` (the valve holds, the
pass ends) or ``unload`` (a controlled unload, then hold).

**A station of channels** (:class:`GainMonitor`; one channel's estimator is
:class:`ChannelGainMonitor`, above). On a rig the structure answers channel i's force to every
channel's flow,
``ẏ_i = Σ_j G_ij·w_j(t − τ_j) + Δ_i``. A crack near an attachment point softens the structure
there, and channel i's force answers all the flows less. The monitor follows one factor per
channel, ``κ_i``, on its row of G (the stand's row over the model's), with the one-channel
estimator: over a chunk of ``c`` cycles

.. math::  a_i = y_{i,end} - y_{i,start} - Δ_i\,c\,T = κ_i\,b_i,\qquad
           b_i = G_{ii}\,T \sum_k \sum_j \frac{G_{ij}}{G_{ii}}\,F_{j,k}\,\tilde q_{j,k}

(``q̃_j``: the commands channel j actually sent, delayed by its own ``τ_j``; ``F_j`` its model's
FLOW factor there), least squares per block, its 95 % interval, ``ĝ_i = κ_i·G_ii`` reported as
channel i's gain. A chunk counts for channel i where every flow that reaches it (``G_ij ≠ 0``)
is steady and the commands that reach it, ``Σ_j (G_ij/G_ii)·q̃_j``, keep one way with at least
``min_flow_pct`` (in channel i's own command units). One channel with ``G = [g]`` is the
one-channel monitor, sample for sample; its loop's margins are re-checked as one loop's
(:meth:`GainMonitor.for_controller`).

**The alarm** is the one-channel alarm per channel (a fall beyond ``fall_pct``, a rise beyond
``rise_pct``, the interval clear of the model's, ``confirm`` blocks running), named after the
channel, the first to fire for the rig. Its action acts on the whole rig: ``note``, ``hold``
(every valve holds) or ``unload`` (every channel unloads keeping the load ratios, the rig's
safety: :mod:`gateway.unload`). A rig's design margins are not re-checked in the loop (they
are the characteristic loci of the whole loop, :mod:`loading.margins`, not a gain per channel).

**The feedforward follows it** (``follow``): with the rows scaled, the flows that make the
rates are ``w' = G⁻¹·diag(1/κ)·(ṙ − d) = G⁻¹·diag(1/κ)·G·w``, so from the next block on the
feedforward of every cycle is multiplied by ``M = G⁻¹·diag(G_ii/ĝ_i)·G`` (exact for the base
model, first order for FLOW effects; each ``ĝ_i`` within ``follow_limit_pct`` of ``G_ii``); a
feedforward from each channel's own model is multiplied by its own ``G_ii/ĝ_i``.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from typing import Sequence

import numpy as np

from core.errors import ParameterError
from plant.rig import RigModel

from .programme import STAND

ALARM_ACTIONS = ("note", "hold", "unload")
#: a block with too few steady chunks goes on, up to this many times its length
LONGEST_BLOCK = 10
#: the design puts the phase margin on its requirement (45°): a block's may be this much below
#: (about 10 % more gain) before its margins count as below the design's
PHASE_MARGIN_SLACK_DEG = 5.0
#: the reason a pass ends on a gain alarm with action hold or unload
GAIN_ALARM = "gain_alarm"


@dataclass(frozen=True)
class MonitorOptions:
    """How g is estimated and watched (module docstring)."""

    block_s: float = 10.0
    chunk_s: float = 0.05
    steady_factor: float = 1.03
    min_flow_pct: float = 2.0
    fall_pct: float = 2.0
    rise_pct: float = 5.0
    action: str = "note"
    follow: bool = True
    follow_limit_pct: float = 20.0
    confirm: int = 2
    min_chunks: int = 5

    def check(self) -> None:
        for name, v, lo, hi in (("block_s", self.block_s, 0.05, 3600.0), ("chunk_s", self.chunk_s, 0.004, 1.0),
                                ("steady_factor", self.steady_factor, 1.0, 10.0),
                                ("min_flow_pct", self.min_flow_pct, 0.0, 100.0),
                                ("fall_pct", self.fall_pct, 0.01, 90.0), ("rise_pct", self.rise_pct, 0.01, 900.0),
                                ("follow_limit_pct", self.follow_limit_pct, 0.0, 90.0)):
            if not (math.isfinite(v) and lo <= v <= hi):
                raise ParameterError(f"gain monitor: {name} = {v} is out of range: give {lo:g} to {hi:g}")
        if self.chunk_s * 2 > self.block_s:
            raise ParameterError(f"gain monitor: a block ({self.block_s:g} s) must hold several chunks "
                                 f"({self.chunk_s:g} s)")
        if self.action not in ALARM_ACTIONS:
            raise ParameterError(f"gain alarm action {self.action!r}: choose one of {', '.join(ALARM_ACTIONS)}")
        if self.confirm < 1 or self.min_chunks < 3:
            raise ParameterError("gain monitor: confirm >= 1 block and min_chunks >= 3")


@dataclass
class GainBlock:
    """One block's estimate (``g`` None when the block had too few steady chunks)."""

    index: int                  #: across the test (all passes)
    pass_index: int
    start_s: float              #: stand time of the test (passes one after the other), s
    end_s: float
    chunks: int
    g: float | None = None      #: ĝ, kgf/(%·s)
    low: float | None = None    #: 95 % interval
    high: float | None = None
    change_pct: float | None = None          #: ĝ over the reference g, minus 1, %
    gain_margin: float | None = None         #: at the boosted ĝ·ρ
    phase_margin_deg: float | None = None    #: the smaller at ĝ and ĝ·ρ
    margins_ok: bool | None = None
    follow_g: float | None = None            #: the g the feedforward uses from the next block
    alarm: str | None = None                 #: "fall" | "rise" | "margins" when it fired here

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class MarginTable:
    """The designed loop's margins across gain ratios, computed before the run."""

    ratios: list[float]
    gain_margin_boosted: float           #: at ratio 1 (it scales as 1/ratio)
    phase_margin_deg: list[float]        #: the smaller of nominal and boosted, per ratio
    gain_margin_min: float
    phase_margin_min_deg: float

    def at(self, ratio: float) -> tuple[float, float]:
        return (self.gain_margin_boosted / ratio,
                float(np.interp(ratio, self.ratios, self.phase_margin_deg)))


def margin_table(kp: float, ti: float, g: float, tau: float, period_s: float, rho: float,
                 points: int = 2000) -> MarginTable:
    """:class:`MarginTable` of the PI (kp, ti) on ``g·e^{-sτ}/s`` at ``T``, boost ρ."""
    from .design import GAIN_MARGIN_MIN, PHASE_MARGIN_MIN_DEG, margins
    ratios = list(np.geomspace(0.5, 2.0, 25))
    pm = [min(margins(kp, ti, g * k, tau, period_s, check=False, points=points).phase_margin_deg,
              margins(kp, ti, g * k * rho, tau, period_s, check=False, points=points).phase_margin_deg)
          for k in ratios]
    gm = margins(kp, ti, g * rho, tau, period_s, check=False, points=points).gain_margin
    return MarginTable(ratios, float(gm), [float(v) for v in pm], GAIN_MARGIN_MIN, PHASE_MARGIN_MIN_DEG)


def _t_quantiles(n: int = 200) -> list[float]:
    from scipy.stats import t
    return [math.inf] + [float(t.ppf(0.975, k)) for k in range(1, n + 1)]


class ChannelGainMonitor:
    """One channel's block-by-block estimate of g, the feedforward's gain, the alarm (module
    docstring).

    It lives through a whole test (every pass) inside the station's :class:`GainMonitor`:
    :meth:`begin_pass` at each pass's main phase, :meth:`add_flow` every cycle, :attr:`ff_scale`
    for the feedforward, :attr:`alarm` once the alarm fired (``(kind, message)``)."""

    def __init__(self, g_kgf_pct_s: float, tau_s: float, delta_kgf_s: float, period_s: float,
                 options: MonitorOptions, margins: MarginTable | None = None) -> None:
        options.check()
        self.options = options
        self.g_ref = float(g_kgf_pct_s)
        self.T = float(period_s)
        whole = tau_s / period_s
        self.m = int(math.floor(whole + 1e-9))
        self.f = whole - self.m
        self.delta = float(delta_kgf_s)
        self.margins = margins
        self.chunk_cycles = max(2, int(round(options.chunk_s / period_s)))
        self.block_cycles = max(self.chunk_cycles * 2, int(round(options.block_s / period_s)))
        self.longest_block_cycles = LONGEST_BLOCK * self.block_cycles
        self._tq = _t_quantiles()
        self.blocks: list[GainBlock] = []
        #: blocks closed over the test (its owner may keep fewer in :attr:`blocks`)
        self.closed_blocks = 0
        self.alarm: tuple[str, str] | None = None
        self.g_follow = self.g_ref
        self._run = 0                  # consecutive blocks beyond a threshold
        self._run_kind = ""
        self.test_s = 0.0              # stand time of the finished passes
        self.pass_index = 0
        self._in_pass = False

    # -- the feedforward's gain ----------------------------------------------------------------
    @property
    def ff_scale(self) -> float:
        """The factor on the feedforward: the model's g over the one it follows."""
        return self.g_ref / self.g_follow

    # -- per pass, per cycle -------------------------------------------------------------------
    def begin_pass(self) -> None:
        self.pass_index += 1
        self._in_pass = True
        self._cycle = 0
        self._block_start = 0
        self._reset_chunk(math.nan)
        self._sab = self._sbb = self._saa = 0.0
        self._n = 0

    def end_pass(self) -> bool:
        """Close the pass: its last block if it holds enough, and the test's clock. False if
        no pass was going (its main phase never began)."""
        if not self._in_pass:
            return False
        self._in_pass = False
        if self._cycle - self._block_start >= self.block_cycles // 2:
            self._close_block()
        self.test_s += self._cycle * self.T
        return True

    def _reset_chunk(self, y: float) -> None:
        self._y0 = y                   # the reading the chunk starts from
        self._b = 0.0                  # Σ G·q̃ over its cycles
        self._k = 0                    # its cycles so far
        self._ok = True                # steady, one way, enough flow throughout
        self._sign = 0.0

    def add_flow(self, y: float, flow: float, q: float, steady: bool) -> None:
        """One cycle, the flow already known: the force read now, the model's flow ``G·q̃``
        acting until the next reading (in the command's units, what ``g`` multiplies), the
        flow whose size and way qualify the chunk (at least ``min_flow_pct``, one way) and
        whether the model's FLOW factor is steady there: each channel's flow through the
        structure, from the commands sent (:meth:`GainMonitor.add`)."""
        o = self.options
        self._cycle += 1
        if self._k == self.chunk_cycles:                     # y is the chunk's last reading
            if self._ok and math.isfinite(self._y0):
                a = y - self._y0 - self.delta * self._k * self.T
                b = self.g_ref * self.T * self._b
                self._sab += a * b
                self._sbb += b * b
                self._saa += a * a
                self._n += 1
            self._reset_chunk(y)
        elif self._k == 0:
            self._y0 = y
        sign = 1.0 if q > 0 else -1.0
        if not (steady and abs(q) >= o.min_flow_pct and self._sign in (0.0, sign)):
            self._ok = False
        self._sign = sign
        self._b += flow
        self._k += 1
        length = self._cycle - self._block_start
        if length >= self.block_cycles and (self._n >= o.min_chunks or length >= self.longest_block_cycles):
            self._close_block()

    # -- per block -------------------------------------------------------------------------------
    def _close_block(self) -> None:
        o = self.options
        start = self.test_s + self._block_start * self.T
        end = self.test_s + self._cycle * self.T
        self.closed_blocks += 1
        block = GainBlock(self.closed_blocks, self.pass_index, start, end, self._n)
        n, sbb = self._n, self._sbb
        if n >= o.min_chunks and sbb > 0:
            kappa = self._sab / sbb
            ssr = max(self._saa - 2 * kappa * self._sab + kappa * kappa * sbb, 0.0)
            se = math.sqrt(ssr / (n - 1) / sbb)
            tq = self._tq[min(n - 1, len(self._tq) - 1)] if n - 1 < len(self._tq) else 1.96
            g = kappa * self.g_ref
            block.g, block.low, block.high = g, g - tq * se * self.g_ref, g + tq * se * self.g_ref
            block.change_pct = 100.0 * (kappa - 1.0)
            if self.margins is not None:
                gm, pm = self.margins.at(kappa)
                block.gain_margin, block.phase_margin_deg = gm, pm
                block.margins_ok = (gm >= self.margins.gain_margin_min
                                    and pm >= self.margins.phase_margin_min_deg - PHASE_MARGIN_SLACK_DEG)
            self._judge(block)
            if o.follow:
                lim = o.follow_limit_pct / 100.0
                self.g_follow = min(max(g, self.g_ref * (1 - lim)), self.g_ref * (1 + lim))
        block.follow_g = self.g_follow
        self.blocks.append(block)
        self._block_start = self._cycle
        self._sab = self._sbb = self._saa = 0.0
        self._n = 0

    def _judge(self, block: GainBlock) -> None:
        o = self.options
        kind = ""
        if block.g < self.g_ref * (1 - o.fall_pct / 100) and block.high < self.g_ref:
            kind = "fall"
        elif block.g > self.g_ref * (1 + o.rise_pct / 100) and block.low > self.g_ref:
            kind = "rise"
        elif block.margins_ok is False:
            kind = "margins"
        self._run = self._run + 1 if kind and kind == self._run_kind else (1 if kind else 0)
        self._run_kind = kind
        if kind and self._run >= o.confirm and self.alarm is None:
            block.alarm = kind
            if kind == "fall":
                what = f"fell {-block.change_pct:.1f} % (beyond {o.fall_pct:g} %: the structure softens, a crack?)"
            elif kind == "rise":
                what = f"rose {block.change_pct:.1f} % (beyond {o.rise_pct:g} %: a jammed part?)"
            else:
                what = (f"is {block.change_pct:+.1f} %: the loop's margins there (gain "
                        f"{block.gain_margin:.2f}, phase {block.phase_margin_deg:.0f}°) are below the design's")
            self.alarm = (kind, f"block {block.index} ({block.start_s:.0f}-{block.end_s:.0f} s of the test): "
                                f"the stand's g = {block.g:.1f} kgf/(%·s) [{block.low:.1f}, {block.high:.1f}] "
                                f"{what}; the model's g is {self.g_ref:.1f}")

    @property
    def in_pass(self) -> bool:
        return self._in_pass

    #: what :meth:`state` keeps: the gain the feedforward follows, the alarm's run, the alarm,
    #: the test's clock and counts (the blocks themselves are history)
    _STATE = ("g_follow", "_run", "_run_kind", "alarm", "test_s", "pass_index", "closed_blocks")

    def state(self) -> dict:
        """What a test stopped between passes needs to go on (JSON-ready): the estimate the
        feedforward follows, the alarm and the run of blocks toward one, the test's clock."""
        return {k.lstrip("_"): (list(v) if isinstance(v, tuple) else v)
                for k, v in ((k, getattr(self, k)) for k in self._STATE)}

    def restore(self, state: dict) -> None:
        """Go on from :meth:`state` (between passes)."""
        for k in self._STATE:
            v = state[k.lstrip("_")]
            setattr(self, k, tuple(v) if k == "alarm" and v is not None else v)

    def text(self) -> str:
        """The blocks in a few lines: the estimates' span, the last, the alarm."""
        est = [b for b in self.blocks if b.g is not None]
        if not est:
            return f"gain: no block had enough steady motion for an estimate ({len(self.blocks)} blocks)"
        last = est[-1]
        lines = [f"gain: {len(est)} of {len(self.blocks)} blocks estimated, g from {min(b.g for b in est):.1f} "
                 f"to {max(b.g for b in est):.1f} kgf/(%·s) (model {self.g_ref:.1f}); last "
                 f"{last.g:.1f} [{last.low:.1f}, {last.high:.1f}] ({last.change_pct:+.1f} %), feedforward at "
                 f"g = {self.g_follow:.1f}"]
        if self.alarm is not None:
            lines.append(f"gain alarm ({self.alarm[0]}, action {self.options.action}): {self.alarm[1]}")
        return "\n".join(lines)

    def summary(self) -> dict:
        est = [b for b in self.blocks if b.g is not None]
        return {"g_reference": self.g_ref, "blocks_total": len(self.blocks), "blocks_estimated": len(est),
                "last_g": est[-1].g if est else None, "alarm": self.alarm[0] if self.alarm else None,
                "alarm_message": self.alarm[1] if self.alarm else None,
                "alarm_block": next((b.index for b in self.blocks if b.alarm), None),
                "action": self.options.action, "fall_pct": self.options.fall_pct,
                "rise_pct": self.options.rise_pct, "block_s": self.options.block_s,
                "follows": self.options.follow, "g_follow": self.g_follow}


class GainMonitor:
    """A :class:`ChannelGainMonitor` per channel, fed through G (module docstring). One lives through a whole test: :meth:`begin_pass` at each pass's main phase,
    :meth:`add` every cycle, :attr:`ff_matrix` for the feedforward, :attr:`alarm` once it fired
    (``(kind, message)``, :attr:`alarm_channel` the channel's index)."""

    def __init__(self, model: RigModel, period_s: float, options: MonitorOptions,
                 margins: Sequence[MarginTable | None] | None = None) -> None:
        options.check()
        self.options = options
        self.names = list(model.names)
        self.G = np.asarray(model.G, float)
        self.Ginv = np.linalg.inv(self.G)
        diag = np.diag(self.G)
        #: the row of G per channel over its own gain: what each flow does to its force
        self.rows = self.G / diag[:, None]
        self.reaches = self.rows != 0.0
        margins = list(margins) if margins is not None else [None] * len(diag)
        self.channels = [ChannelGainMonitor(G_ii, m.tau, m.delta, period_s, options, table)
                         for G_ii, m, table in zip(diag, model.channels, margins)]
        self.m = np.array([c.m for c in self.channels])
        self.f = np.array([c.f for c in self.channels])
        self._len = int(self.m.max()) + 2
        self.alarm: tuple[str, str] | None = None
        self.alarm_channel: int | None = None
        self._follow: tuple[float, ...] | None = None
        self._matrix = np.eye(len(self.names))

    @classmethod
    def for_controller(cls, controller, period_s: float, options: MonitorOptions) -> "GainMonitor":
        """The monitor of a station's controller: the model's G and, for one channel, its loop's
        margins across gains to re-check (a rig's loops share their margins: the
        characteristic loci, not a margin per channel)."""
        tables = None
        if controller.n == 1:
            c = controller.channels[0]
            m = c.model
            tables = [margin_table(c.kp_pct_per_kgf, c.ti_s, m.g, m.tau, period_s, c.boost)]
        return cls(controller.model, period_s, options, tables)

    @property
    def n(self) -> int:
        return len(self.channels)

    @property
    def pass_index(self) -> int:
        return self.channels[0].pass_index

    # -- the feedforward's gain ----------------------------------------------------------------
    @property
    def ff_scales(self) -> np.ndarray:
        """Each channel's factor on its own feedforward, ``G_ii/ĝ_i`` (a feedforward from each
        channel's own model follows its own gain)."""
        return np.array([c.ff_scale for c in self.channels])

    @property
    def ff_matrix(self) -> np.ndarray:
        """The factor on every cycle's feedforward (N×N): ``G⁻¹·diag(G_ii/ĝ_i)·G`` (identity
        while every channel follows its model's gain)."""
        follow = tuple(c.g_follow for c in self.channels)
        if follow != self._follow:
            self._follow = follow
            scale = np.array([c.g_ref / g for c, g in zip(self.channels, follow)])
            self._matrix = self.Ginv @ (scale[:, None] * self.G)
        return self._matrix

    # -- per pass, per cycle -------------------------------------------------------------------
    def begin_pass(self) -> None:
        for c in self.channels:
            c.begin_pass()
        self._u = np.zeros((self.n, self._len))          # the last commands, a ring
        self._g = np.ones((self.n, self._len))           # their FLOW factors
        self._steady = np.zeros((self.n, self._len), bool)
        self._pos = 0

    def end_pass(self) -> bool:
        """Close the pass on every channel (:meth:`ChannelGainMonitor.end_pass`)."""
        return all([c.end_pass() for c in self.channels])

    @property
    def in_pass(self) -> bool:
        """A pass is going (begun, not ended)."""
        return self.channels[0].in_pass

    def state(self) -> dict:
        """Every channel's :meth:`ChannelGainMonitor.state` and the station's alarm (JSON-ready)."""
        return {"channels": {n: c.state() for n, c in zip(self.names, self.channels)},
                "alarm": list(self.alarm) if self.alarm else None,
                "alarm_channel": self.alarm_channel}

    def restore(self, state: dict) -> None:
        """Go on from :meth:`state` (between passes); refused for other channels."""
        if list(state["channels"]) != self.names:
            raise ParameterError(f"gain monitor: a state of the channels {', '.join(state['channels'])}, "
                                 f"this station has {', '.join(self.names)}")
        for n, c in zip(self.names, self.channels):
            c.restore(state["channels"][n])
        self.alarm = tuple(state["alarm"]) if state["alarm"] else None
        self.alarm_channel = state["alarm_channel"]

    def add(self, y: Sequence[float], u_pct: Sequence[float], flow_factor: Sequence[float]) -> None:
        """One cycle of the main phase: every force read now, every command sent now and each
        channel's model FLOW factor where its command will act (its delay later)."""
        o = self.options
        L = self._len
        self._pos = pos = (self._pos + 1) % L
        factor = np.asarray(flow_factor, float)
        self._u[:, pos] = u_pct
        self._g[:, pos] = factor
        self._steady[:, pos] = np.abs(factor - 1.0) <= o.steady_factor - 1.0
        rows = np.arange(self.n)
        now, before = (pos - self.m) % L, (pos - self.m - 1) % L
        q = (1 - self.f) * self._u[rows, now] + self.f * self._u[rows, before]
        flows = self.rows @ (self._g[rows, now] * q)
        commanded = self.rows @ q
        unsteady = ~self._steady[rows, now]
        steady = ~(self.reaches & unsteady[None, :]).any(axis=1)
        for i, c in enumerate(self.channels):
            c.add_flow(float(y[i]), float(flows[i]), float(commanded[i]), bool(steady[i]))
            if c.alarm is not None and self.alarm is None:
                self.alarm_channel = i
                self.alarm = (c.alarm[0], c.alarm[1] if self.n == 1 else f"channel {self.names[i]}: {c.alarm[1]}")

    # -- what the reports read -------------------------------------------------------------------
    def summary(self) -> dict:
        """The ``gain`` of ``report.json``: the alarm, the options and every channel's summary
        (a one-channel stand's also at the top level, as :meth:`ChannelGainMonitor.summary`)."""
        o = self.options
        return {**(self.channels[0].summary() if self.n == 1 else {}),
                "alarm": self.alarm[0] if self.alarm else None,
                "alarm_channel": self.names[self.alarm_channel] if self.alarm else None,
                "alarm_message": self.alarm[1] if self.alarm else None,
                "action": o.action, "fall_pct": o.fall_pct, "rise_pct": o.rise_pct,
                "block_s": o.block_s, "follows": o.follow,
                "channels": {n: c.summary() for n, c in zip(self.names, self.channels)}}

    def blocks(self, pass_index: int | None = None) -> dict[str, list[dict]] | list[dict]:
        """Every channel's blocks (of one pass, or all) as dicts, by channel (a one-channel
        stand's: the list)."""
        out = {n: [b.to_dict() for b in c.blocks if pass_index is None or b.pass_index == pass_index]
               for n, c in zip(self.names, self.channels)}
        return out[STAND] if self.names == [STAND] else out

    def text(self) -> str:
        """A line per channel: its estimates' span, the last, then the alarm."""
        if self.n == 1:
            return self.channels[0].text()
        lines = []
        width = max(len(n) for n in self.names)
        for n, c in zip(self.names, self.channels):
            est = [b for b in c.blocks if b.g is not None]
            if not est:
                lines.append(f"gain {n:<{width}}: no block had enough steady flow for an estimate "
                             f"({len(c.blocks)} blocks)")
                continue
            last = est[-1]
            lines.append(f"gain {n:<{width}}: {len(est)} of {len(c.blocks)} blocks estimated, ĝ from "
                         f"{min(b.g for b in est):.1f} to {max(b.g for b in est):.1f} kgf/(%·s) (model "
                         f"G_ii {c.g_ref:.1f}); last {last.g:.1f} [{last.low:.1f}, {last.high:.1f}] "
                         f"({last.change_pct:+.1f} %), feedforward at {c.g_follow:.1f}")
        if self.alarm is not None:
            lines.append(f"gain alarm ({self.alarm[0]}, action {self.options.action}): {self.alarm[1]}")
        return "\n".join(lines)
