"""Controlled unload of every channel together, keeping the load ratios.

When a channel of a rig trips, the structure must never see a load distribution it was not
designed for: a channel unloading alone drags its neighbours through the coupling
(../shared/notes/rig.md). So every channel's force follows the same scale of its own load at
the trip, ``r_i(t) = s(t)·y_i(t0)``, as ``s`` falls from 1 to 0 at the rate the slowest channel
can follow: ``ds/dt = −min_i R_i/|y_i(t0)|`` (``R_i`` the channel's unload rate, kgf/s), lowered
further when the rig's ``G`` is known and the flow the ramp needs, ``G⁻¹·ṡ·y(t0)``, would take
more than :data:`FEEDFORWARD_SHARE` of a valve's unload command bound. On a rig the ramp reaches
that rate over :data:`SMOOTH_S` (``s`` parabolic at first): the channels' flows, and what they do
to each other through the structure, start gently, while the tripping channel's command in flight
and its reversal boost die out (on the coupled example rig the largest deviation fell from 54 to
31 kgf with it).

Each channel follows its reference with the supervisor's gentle loop,
``u_i = clip(u_ff,i + K_i·(r_i − y_i), ±u_max)``. With ``G`` known each channel's gain is set
for the same bandwidth, ``K_i = K·g_ref/G_ii`` (``g_ref`` = :data:`G_REF`, the gain ``K`` is
stated for), so every channel lags its reference by the same share of its load and the ratios
hold through the ramp; the feedforward ``u_ff = G⁻¹·ṡ·y(t0)`` (static decoupling) takes the
coupling out of the ramp. Without ``G`` every channel has gain ``K``: equal channels still lag
alike.

The deviation from the ratios is measured against the common scale the forces actually have,
``σ(t) = Σ y_i(t0)·y_i(t) / Σ y_i(t0)²`` (least squares over the unloading channels):
``d_i(t) = y_i(t) − σ(t)·y_i(t0)``, zero while the forces keep the distribution of ``t0``,
whatever their common lag. The largest ``|d_i|``, where and when, goes into run.json.

**No reversal during the ramp.** Where the feedforward plans a flow, the feedback may slow the
valve to a hold (0) but not turn it the other way: a channel ahead of its reference waits for it.
A valve reversing at a small command meets the reversal boost of its plant (many times the
steady gain): on the coupled example rig a channel with small planned flows (outer, tip) turned
back and forth every 0.2 s, ±50-130 kgf, and the deviation from the ratios reached 1.2-2.6 % of a
range from a stop in the middle of a flight (``tests/test_endurance_e2e.py``). After the ramp,
and without G (no feedforward), the loop is free as before.

Channels whose valve is already in its own safe state (or that cannot be read) are excluded:
they hold, the others unload. For one channel this is the supervisor's unload
(:class:`gateway.supervisor.Unloader`): the same reference, gain and ends, and the same record.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .limits import SafetyLimits
from .supervisor import Unloader

#: the plant gain the unload gain ``K`` is stated for, kgf/(%·s) (docs/safety.md)
G_REF = 120.0
#: the feedforward may take at most this share of a valve's unload command bound
FEEDFORWARD_SHARE = 0.5
#: a rig's ramp reaches its rate over this long, s
SMOOTH_S = 0.5


@dataclass
class Deviation:
    """The largest deviation from the ratios of one channel during the unload."""

    kgf: float = 0.0
    at_s: float = 0.0
    scale: float = 1.0           #: σ at that moment


@dataclass
class RatioUnloader:
    """Unload the channels marked ``active`` keeping the ratios of ``y0`` (module docstring).

    ``step(ys, fresh)`` every cycle gives the commands (%) and references (kgf); :attr:`done`
    and :attr:`outcome` ("unloaded", "force_rising", "timeout") as :class:`Unloader`'s, and
    :attr:`culprit`: the channel whose force rose."""

    y0: list[float]
    active: list[bool]
    limits: list[SafetyLimits]
    period_s: float
    names: list[str] = field(default_factory=list)
    G: np.ndarray | None = None
    #: a rig: the ramp reaches its rate over this long (s); one channel: 0, the supervisor's ramp
    smooth_s: float | None = None
    t: float = 0.0
    done: bool = False
    outcome: str | None = None
    cycles: int = 0
    culprit: int | None = None

    def __post_init__(self) -> None:
        n = len(self.y0)
        if self.smooth_s is None:
            self.smooth_s = SMOOTH_S if n > 1 else 0.0
        if not self.names:
            self.names = [str(i) for i in range(n)]
        lims = self.limits
        scale = [1.0] * n
        if self.G is not None:
            diag = np.diag(self.G)
            scale = [G_REF / float(diag[i]) if diag[i] > 0 else 1.0 for i in range(n)]
        self.gains = [lims[i].unload_gain_pct_per_kgf * scale[i] for i in range(n)]
        rates = [(lims[i].unload_rate_kgf_per_s / abs(self.y0[i]), i) for i in range(n)
                 if self.active[i] and self.y0[i] != 0.0]
        #: ds/dt, 1/s, and the channel that sets it
        self.rate, self.slowest = min(rates) if rates else (math.inf, None)
        self.limited_by = "unload rate" if self.slowest is not None else None
        self.feedforward = [0.0] * n
        self._feedforward_flow()
        self.deviation = [Deviation() for _ in range(n)]
        self.largest: int | None = None

    def _feedforward_flow(self) -> None:
        """``u_ff = G⁻¹·(−ṡ·y0)`` over the unloading channels, the rate lowered until it fits."""
        idx = [i for i, a in enumerate(self.active) if a]
        if self.G is None or len(self.y0) < 2 or not idx or not math.isfinite(self.rate):
            return
        G = np.asarray(self.G, float)[np.ix_(idx, idx)]
        want = -np.array([self.y0[i] for i in idx])          # force rate per unit of ṡ
        try:
            per_rate = np.linalg.solve(G, want)               # flow per unit of ṡ, %
        except np.linalg.LinAlgError:
            return
        room = min(FEEDFORWARD_SHARE * self.limits[i].unload_max_pct for i in idx)
        peak = float(np.max(np.abs(per_rate))) * self.rate
        if peak > room:
            self.rate *= room / peak
            self.slowest = idx[int(np.argmax(np.abs(per_rate)))]
            self.limited_by = "valve flow"
        for k, i in enumerate(idx):
            self.feedforward[i] = float(per_rate[k]) * self.rate

    def scale_at(self, t: float) -> float:
        """``s(t)``: from 1 down at :attr:`rate`, the rate reached over :attr:`smooth_s` (a
        parabolic start: every channel's flow, and the coupling's, rises gently)."""
        if not math.isfinite(self.rate):
            return 0.0
        ts = self.smooth_s
        if t < ts:
            return 1.0 - self.rate * t * t / (2.0 * ts)
        return max(0.0, 1.0 - self.rate * (t - ts / 2.0))

    def _rate_share(self, t: float) -> float:
        """``|ds/dt|`` over :attr:`rate` at ``t`` (the feedforward's share)."""
        ts = self.smooth_s
        return min(1.0, t / ts) if ts > 0 and t < ts else 1.0

    def step(self, ys: Sequence[float], fresh: bool = True) -> tuple[list[float], list[float]]:
        """One cycle: the commands (%) and references (kgf, NaN for excluded channels).
        ``fresh``: every unloading channel's reading is new this cycle (the deviation is
        measured only then)."""
        n = len(self.y0)
        s = self.scale_at(self.t)
        ramp_over = s <= 0.0 if n > 1 else \
            self.limits[0].unload_rate_kgf_per_s * self.t >= abs(self.y0[0])
        if fresh and self.cycles:
            self._measure(ys)
        us = [0.0] * n
        rs = [math.nan] * n
        for i in range(n):
            if self.active[i]:
                rs[i] = self.y0[i] * s if n > 1 else self._one_channel_reference()
        self.t += self.period_s
        self.cycles += 1
        settled = True
        for i in range(n):
            if not self.active[i]:
                continue
            lim = self.limits[i]
            rise = abs(ys[i]) - abs(self.y0[i])
            if rise > 0.1 * lim.force_limit_kgf or (self.t > Unloader.GRACE_S
                                                    and rise > lim.unload_tolerance_kgf):
                self.done, self.outcome, self.culprit = True, "force_rising", i
                return [0.0] * n, rs
            if not abs(ys[i]) <= lim.unload_tolerance_kgf:
                settled = False
        if ramp_over and settled:
            self.done, self.outcome = True, "unloaded"
            return us, rs
        if self.t > max(self.limits[i].unload_timeout_s for i in range(n) if self.active[i]):
            self.done, self.outcome = True, "timeout"
            return us, rs
        for i in range(n):
            if self.active[i]:
                lim = self.limits[i]
                ff = 0.0 if ramp_over else self.feedforward[i] * self._rate_share(self.t - self.period_s)
                u = ff + self.gains[i] * (rs[i] - ys[i])
                if not ramp_over and self.feedforward[i] * u < 0:
                    u = 0.0            # the feedback slows the rod, never reverses it (docstring)
                us[i] = max(-lim.unload_max_pct, min(lim.unload_max_pct, u))
        return us, rs

    def _one_channel_reference(self) -> float:
        """One channel: the supervisor's reference, ``y0 − sign(y0)·min(R·t, |y0|)``, computed
        as :class:`Unloader` computes it."""
        y0 = self.y0[0]
        drop = min(self.limits[0].unload_rate_kgf_per_s * self.t, abs(y0))
        return y0 - math.copysign(drop, y0)

    def _measure(self, ys: Sequence[float]) -> None:
        idx = [i for i, a in enumerate(self.active) if a]
        den = sum(self.y0[i] * self.y0[i] for i in idx)
        if not idx or den <= 0.0:
            return
        sigma = sum(self.y0[i] * ys[i] for i in idx) / den
        at = self.t
        for i in idx:
            d = ys[i] - sigma * self.y0[i]
            dev = self.deviation[i]
            if abs(d) > abs(dev.kgf):
                dev.kgf, dev.at_s, dev.scale = d, at, sigma
                big = self.largest
                if big is None or abs(d) > abs(self.deviation[big].kgf):
                    self.largest = i

    def record(self, ys_end: Sequence[float], ranges_kgf: Sequence[float] | None = None) -> dict[str, Any]:
        """run.json ``safety.unload``: for one channel exactly :meth:`Unloader.record`'s."""
        n = len(self.y0)
        if n == 1:
            return {"from_kgf": self.y0[0], "to_kgf": ys_end[0], "duration_s": self.t,
                    "outcome": self.outcome}
        ranges = list(ranges_kgf) if ranges_kgf is not None else [math.nan] * n
        channels = {}
        for i, name in enumerate(self.names):
            entry: dict[str, Any] = {"from_kgf": self.y0[i], "to_kgf": ys_end[i],
                                     "unloaded": self.active[i]}
            if self.active[i]:
                dev = self.deviation[i]
                entry.update(gain_pct_per_kgf=self.gains[i], feedforward_pct=self.feedforward[i],
                             max_deviation_kgf=abs(dev.kgf),
                             max_deviation_pct_of_range=100 * abs(dev.kgf) / ranges[i],
                             max_deviation_at_s=dev.at_s)
            channels[name] = entry
        out: dict[str, Any] = {
            "outcome": self.outcome, "duration_s": self.t,
            "rate_per_s": self.rate if math.isfinite(self.rate) else None,
            "slowest_channel": None if self.slowest is None else self.names[self.slowest],
            "rate_limited_by": self.limited_by,
            "ratio_measure": "d_i = y_i - sigma*y_i(t0), sigma the least-squares common scale",
            "channels": channels}
        if self.largest is not None:
            i = self.largest
            dev = self.deviation[i]
            from0 = max(abs(self.y0[k]) for k in range(n) if self.active[k])
            out["largest_deviation"] = {
                "channel": self.names[i], "kgf": abs(dev.kgf),
                "pct_of_range": 100 * abs(dev.kgf) / ranges[i],
                "pct_of_largest_load": 100 * abs(dev.kgf) / from0 if from0 else None,
                "at_s": dev.at_s, "scale": dev.scale}
        if self.culprit is not None:
            out["force_rising_channel"] = self.names[self.culprit]
        return out
