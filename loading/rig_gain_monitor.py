r"""The rig's gain, re-estimated block by block and watched: a crack softens the structure.

On a rig the structure answers channel i's force to every channel's flow,
``ẏ_i = Σ_j G_ij·w_j(t − τ_j) + Δ_i``. A crack near an attachment point softens the structure
there, and channel i's force answers all the flows less. The monitor follows one factor per
channel, ``κ_i``, on its row of G (the stand's row over the model's), with the one-channel
estimator (:mod:`loading.gain_monitor`): over a chunk of ``c`` cycles

.. math::  a_i = y_{i,end} - y_{i,start} - Δ_i\,c\,T = κ_i\,b_i,\qquad
           b_i = G_{ii}\,T \sum_k \sum_j \frac{G_{ij}}{G_{ii}}\,F_{j,k}\,\tilde q_{j,k}

(``q̃_j``: the commands channel j actually sent, delayed by its own ``τ_j``; ``F_j`` its model's
FLOW factor there), least squares per block, its 95 % interval, ``ĝ_i = κ_i·G_ii`` reported as
channel i's gain. A chunk counts for channel i where every flow that reaches it (``G_ij ≠ 0``)
is steady and the sum of them keeps one way with at least ``min_flow_pct`` (in channel i's own
command units). One channel with ``G = [g]`` is the one-channel monitor, sample for sample.

**The alarm** is the one-channel alarm per channel (a fall beyond ``fall_pct``, a rise beyond
``rise_pct``, the interval clear of the model's, ``confirm`` blocks running), named after the
channel, the first to fire for the rig. Its action acts on the whole rig: ``note``, ``hold``
(every valve holds) or ``unload`` (every channel unloads keeping the load ratios, the rig's
safety: :mod:`gateway.unload`). The design's margins are not re-checked in the loop (the rig's
are the characteristic loci of the whole loop, :mod:`loading.rig_margins`, not a gain per
channel).

**The feedforward follows it** (``follow``): with the rows scaled, the flows that make the
rates are ``w' = G⁻¹·diag(1/κ)·(ṙ − d) = G⁻¹·diag(1/κ)·G·w``, so from the next block on the
feedforward of every cycle is multiplied by ``M = G⁻¹·diag(G_ii/ĝ_i)·G`` (exact for the base
model, first order for FLOW effects; each ``ĝ_i`` within ``follow_limit_pct`` of ``G_ii``).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from plant.rig import RigModel

from .gain_monitor import GainMonitor, MonitorOptions


class RigGainMonitor:
    """A :class:`~loading.gain_monitor.GainMonitor` per channel, fed through G (module
    docstring). One lives through a whole test: :meth:`begin_pass` at each pass's main phase,
    :meth:`add` every cycle, :attr:`ff_matrix` for the feedforward, :attr:`alarm` once it fired
    (``(kind, message)``, :attr:`alarm_channel` the channel's index)."""

    def __init__(self, model: RigModel, period_s: float, options: MonitorOptions) -> None:
        options.check()
        self.options = options
        self.names = list(model.names)
        self.G = np.asarray(model.G, float)
        self.Ginv = np.linalg.inv(self.G)
        diag = np.diag(self.G)
        #: the row of G per channel over its own gain: what each flow does to its force
        self.rows = self.G / diag[:, None]
        self.reaches = self.rows != 0.0
        self.channels = [GainMonitor(G_ii, m.tau, m.delta, period_s, options)
                         for G_ii, m in zip(diag, model.channels)]
        self.m = np.array([c.m for c in self.channels])
        self.f = np.array([c.f for c in self.channels])
        self._len = int(self.m.max()) + 2
        self.alarm: tuple[str, str] | None = None
        self.alarm_channel: int | None = None
        self._follow: tuple[float, ...] | None = None
        self._matrix = np.eye(len(self.names))

    @property
    def n(self) -> int:
        return len(self.channels)

    @property
    def pass_index(self) -> int:
        return self.channels[0].pass_index

    # -- the feedforward's gain ----------------------------------------------------------------
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
        """Close the pass on every channel (:meth:`GainMonitor.end_pass`)."""
        return all([c.end_pass() for c in self.channels])

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
        unsteady = ~self._steady[rows, now]
        steady = ~(self.reaches & unsteady[None, :]).any(axis=1)
        for i, c in enumerate(self.channels):
            c.add_flow(float(y[i]), float(flows[i]), float(flows[i]), bool(steady[i]))
            if c.alarm is not None and self.alarm is None:
                self.alarm_channel = i
                self.alarm = (c.alarm[0], f"channel {self.names[i]}: {c.alarm[1]}")

    # -- what the reports read -------------------------------------------------------------------
    def summary(self) -> dict:
        o = self.options
        return {"alarm": self.alarm[0] if self.alarm else None,
                "alarm_channel": self.names[self.alarm_channel] if self.alarm else None,
                "alarm_message": self.alarm[1] if self.alarm else None,
                "action": o.action, "fall_pct": o.fall_pct, "rise_pct": o.rise_pct,
                "block_s": o.block_s, "follows": o.follow,
                "channels": {n: c.summary() for n, c in zip(self.names, self.channels)}}

    def blocks(self, pass_index: int | None = None) -> dict[str, list[dict]]:
        """Every channel's blocks (of one pass, or all) as dicts."""
        return {n: [b.to_dict() for b in c.blocks if pass_index is None or b.pass_index == pass_index]
                for n, c in zip(self.names, self.channels)}

    def text(self) -> str:
        """A line per channel: its estimates' span, the last, then the alarm."""
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
