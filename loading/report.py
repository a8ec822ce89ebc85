r"""How well a pass tracked its programme: every channel's turning points, RMS error and
self-oscillation, and each load case's ratios between the channels.

Per turning point of a channel's programme (its peaks and valleys) the **achieved level** is the extreme
of the force (the maximum near a peak, the minimum near a valley) within the stretch from half
way after the turning point before to half way before the one after, so a late peak still
counts. Errors are given as % of the programme's range ``R = max r − min r``:

.. math::  e_i = 100\,\frac{y_i^{achieved} - L_i}{R},\qquad
           \text{RMS} = 100\,\frac{\sqrt{\overline{(y - r)^2}}}{R}.

ISO 4965-1 asks the dynamic force error to stay within 1 % of the range; overshoot at a
reversal is an overload, so its maximum is reported on its own.

**Self-oscillation** is counted as rainflow cycles (ASTM E1049, the ``rainflow`` package) of the
achieved force that the programme does not have. Both signals are first reduced to their
reversals by more than the gate (0.5 % of the range by default; a range filter, as fatigue
counting does), so noise is not counted; then each is rainflow-counted (a half cycle counts ½,
the residue as half cycles) and the extra cycles are the achieved force's count above the gate
minus the programme's. A lag or an overshoot changes no count; ringing after a reversal adds
one cycle per swing beyond the gate.

ratios between the channels.

**A station** (:func:`tracking_report`): per channel the report above (:class:`ChannelReport`,
the error as % of its own programme's range). At a load case where some channel turns, a channel
that passes its level on the way (no peak or valley of its own) is as much part of the load
distribution as one that turns there: it is judged too, its achieved level the force at the
load case's moment (kind 'rising' or 'falling'), in its p95 and max, and its compensation learns
there (:mod:`loading.compensation`). For several channels on load cases:

Per load case (load-case programmes only, the first and the last left out as the one-channel
report leaves them), the **ratio deviation**: a load case asks the channels' forces in fixed
ratios ``L_i/L_m``. The lead channel ``m`` is the one with the largest level for its range
(``|L_i|/R_i``); each other channel's deviation is how far its achieved level is from the one
the lead's achieved level asks of it in the load case's ratio,

.. math::  d_i = 100\,\frac{A_i - A_m\,L_i/L_m}{R_i}\ \%,

in % of channel i's range (as its peak/valley error; with ``A = L + e`` it is
``(e_i − e_m·L_i/L_m)/R_i``: a common scaling of the whole case, every channel off in the same
proportion, does not count). ``A_i`` is the channel's achieved level at the case (the extreme
near it for a peak or a valley, else the force at the case's moment). ``ratio_error_pct`` is
the largest ``|d_i|`` of the pass.

The JSON summary (``hydrostand-load/1``): the worst channel's figures at the top level (the
one-channel keys: the channel with the largest peak/valley p95, named in ``worst_channel``),
``channels`` → per channel the same keys, ``ratio_error_pct`` (null for one channel and for
per-channel sequences), and ``passes`` with the same for every pass.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .programme import ChannelProgramme, Programme, as_programme, turning_points

SCHEMA = "hydrostand-load/1"
#: extra cycles are counted above this share of the programme's range (%)
GATE_PCT = 0.5


@dataclass
class TurningPoint:
    index: int             #: sample of the programme
    time_s: float
    kind: str              #: "peak" | "valley" | "rising" | "falling" (a level passed at a load case)
    commanded_kgf: float
    achieved_kgf: float
    error_kgf: float       #: achieved − commanded
    error_pct: float       #: of the programme's range
    overshoot_kgf: float   #: beyond the level in the direction of travel (0 if short of it)


@dataclass
class ChannelReport:
    """How one channel tracked its programme (module docstring)."""

    turning_points: list[TurningPoint]
    range_kgf: float
    peak_valley_error_pct: dict     #: {"max": ..., "p95": ...} of |error|
    rms_error_pct: float
    extra_cycles: float
    largest_extra_cycle_kgf: float
    overshoot_max_pct: float

    def figures(self) -> dict:
        """The pass's figures as the JSON summary gives them."""
        return {"peak_valley_error_pct": self.peak_valley_error_pct,
                "rms_error_pct": self.rms_error_pct, "extra_cycles": self.extra_cycles,
                "largest_extra_cycle_kgf": self.largest_extra_cycle_kgf,
                "overshoot_max_pct": self.overshoot_max_pct, "range_kgf": self.range_kgf,
                "turning_points": len(self.turning_points)}

    def to_dict(self) -> dict:
        return {**self.figures(), "points": [asdict(tp) for tp in self.turning_points]}

    def worst(self, n: int = 3) -> list[TurningPoint]:
        return sorted(self.turning_points, key=lambda tp: -abs(tp.error_kgf))[:n]

    def text(self) -> str:
        pv = self.peak_valley_error_pct
        lines = [f"{len(self.turning_points)} turning points over a range of {self.range_kgf:.0f} kgf",
                 f"peak/valley error: p95 {pv['p95']:.2f} %, max {pv['max']:.2f} % of the range",
                 f"RMS tracking error: {self.rms_error_pct:.2f} % of the range",
                 f"largest overshoot: {self.overshoot_max_pct:.2f} % of the range",
                 f"extra cycles above {GATE_PCT:g} % of the range (self-oscillation): "
                 f"{self.extra_cycles:g}" + (f", the largest {self.largest_extra_cycle_kgf:.0f} kgf"
                                            if self.extra_cycles else "")]
        for tp in self.worst():
            lines.append(f"  worst: {tp.kind} {tp.commanded_kgf:.0f} kgf at {tp.time_s:.2f} s reached "
                         f"{tp.achieved_kgf:.0f} kgf ({tp.error_pct:+.2f} %)")
        return "\n".join(lines)


def _cycle_ranges(x: np.ndarray, gate: float) -> list[tuple[float, float]]:
    """(range, count) of the rainflow cycles of ``x`` above ``gate`` after the range filter."""
    import rainflow
    rev = x[turning_points(x, gate)]
    return [(rng, count) for rng, _mean, count, _i, _j in rainflow.extract_cycles(rev) if rng > gate]


def channel_report(programme: ChannelProgramme, t_s, y_kgf, gate_pct: float = GATE_PCT,
                   cases: np.ndarray | None = None) -> ChannelReport:
    """How the achieved force ``y_kgf`` tracked one channel's ``programme`` (the one asked for,
    not a compensated copy). ``t_s``: each sample's time on the programme's clock (0 at its
    start), non-decreasing: a programme that waited for the force (null pacing) gives the
    samples of the wait the same time. Samples outside the programme are left out. ``cases``:
    a station's load cases (their samples) where the channel is judged too when it passes its
    level there ('rising', 'falling': the force at the load case's moment)."""
    t = np.asarray(t_s, float)
    y_all = np.asarray(y_kgf, float)
    eps = programme.period_s * 1e-3
    inside = (t >= -eps) & (t <= programme.duration_s + eps)
    t, y = t[inside], y_all[inside]
    r = np.interp(t, programme.t_s, programme.r_kgf)
    R = programme.range_kgf
    idx = programme.turning_idx
    kinds = programme.kinds()
    judged = set() if cases is None else {int(c) for c in cases}
    points = []
    for j in range(1, len(idx) - 1):
        passing = kinds[j] in ("rising", "falling") and int(idx[j]) in judged
        if kinds[j] not in ("peak", "valley") and not passing:
            continue
        lo = programme.t_s[(idx[j - 1] + idx[j]) // 2] - eps
        hi = programme.t_s[(idx[j] + idx[j + 1]) // 2] + eps
        near = y[np.searchsorted(t, lo, "left"):np.searchsorted(t, hi, "right")]
        level = programme.r_kgf[idx[j]]
        if not len(near):
            continue
        if passing:
            achieved = float(np.interp(programme.t_s[idx[j]], t, y))
        else:
            achieved = float(near.max() if kinds[j] == "peak" else near.min())
        err = achieved - level
        over = max(err, 0.0) if kinds[j] == "peak" else max(-err, 0.0) if kinds[j] == "valley" else 0.0
        points.append(TurningPoint(int(idx[j]), float(programme.t_s[idx[j]]), kinds[j], float(level),
                                   achieved, float(err), 100 * float(err) / R, float(over)))
    errs = np.abs([p.error_pct for p in points]) if points else np.zeros(1)
    gate = gate_pct / 100 * R
    got = sorted(_cycle_ranges(y, gate)) if len(y) > 1 else []
    want = sum(c for _, c in _cycle_ranges(programme.r_kgf, gate))
    extra = max(sum(c for _, c in got) - want, 0.0)
    largest = 0.0
    if extra:
        left = extra
        for rng, c in got:             # the smallest cycles are the ones the programme lacks
            if left <= 0:
                break
            largest = rng
            left -= c
    return ChannelReport(
        turning_points=points, range_kgf=R,
        peak_valley_error_pct={"max": float(errs.max()), "p95": float(np.percentile(errs, 95))},
        rms_error_pct=100 * float(np.sqrt(np.mean((y - r) ** 2))) / R if len(y) else float("nan"),
        extra_cycles=float(extra), largest_extra_cycle_kgf=float(largest),
        overshoot_max_pct=100 * max((p.overshoot_kgf for p in points), default=0.0) / R)


def _plot_channel(programme: ChannelProgramme, t_s, y_kgf, report: ChannelReport, path: str | Path,
                  title: str = "") -> Path:
    """One channel: commanded vs achieved force over the whole programme, and the worst
    turning points zoomed below it."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    worst = report.worst(3)
    fig = plt.figure(figsize=(11, 7))
    top = fig.add_subplot(2, 1, 1)
    top.plot(programme.t_s, programme.r_kgf, lw=1, label="programme")
    top.plot(t_s, y_kgf, lw=1, label="achieved")
    for tp in worst:
        top.axvline(tp.time_s, color="0.7", lw=0.8)
    top.set_xlabel("t, s")
    top.set_ylabel("force, kgf")
    top.legend(loc="upper right")
    top.set_title(title or programme.source)
    span = max(programme.duration_s / max(len(programme.turning_idx), 1), 0.2)
    for k, tp in enumerate(worst):
        ax = fig.add_subplot(2, max(len(worst), 1), max(len(worst), 1) + k + 1)
        m = np.abs(programme.t_s - tp.time_s) <= span
        n = np.abs(np.asarray(t_s) - tp.time_s) <= span
        ax.plot(programme.t_s[m], programme.r_kgf[m], lw=1)
        ax.plot(np.asarray(t_s)[n], np.asarray(y_kgf)[n], lw=1)
        ax.axhline(tp.commanded_kgf, color="0.6", lw=0.8, ls="--")
        ax.set_title(f"{tp.kind} {tp.commanded_kgf:.0f} kgf: {tp.error_pct:+.2f} %", fontsize=9)
        ax.set_xlabel("t, s")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


@dataclass
class LoadCase:
    """One load case of a pass: every channel's level and achieved level, the ratio deviations."""

    label: str
    index: int                    #: sample of the programme
    time_s: float
    commanded_kgf: list[float]
    achieved_kgf: list[float]
    lead: str                     #: the channel the ratios are taken against
    deviation_pct: list[float]    #: d_i per channel (0 for the lead)

    @property
    def largest_pct(self) -> float:
        return float(np.max(np.abs(self.deviation_pct)))


@dataclass
class TrackingReport:
    """How a station's pass tracked its programme (module docstring)."""

    names: list[str]
    channels: list[ChannelReport]
    cases: list[LoadCase] | None          #: None: per-channel sequences (no load cases)

    @property
    def ratio_error_pct(self) -> float | None:
        if self.cases is None:
            return None
        return max((c.largest_pct for c in self.cases), default=0.0)

    @property
    def worst_channel(self) -> str:
        """The channel with the largest peak/valley p95 (then max)."""
        key = [(r.peak_valley_error_pct["p95"], r.peak_valley_error_pct["max"]) for r in self.channels]
        return self.names[max(range(len(key)), key=lambda i: key[i])]

    def channel(self, name: str) -> ChannelReport:
        return self.channels[self.names.index(name)]

    @property
    def worst(self) -> ChannelReport:
        """The worst channel's report: its figures are the pass's (the JSON's top level, and
        for one channel its only one)."""
        return self.channel(self.worst_channel)

    # the pass's figures: the worst channel's
    peak_valley_error_pct = property(lambda self: self.worst.peak_valley_error_pct)
    rms_error_pct = property(lambda self: self.worst.rms_error_pct)
    extra_cycles = property(lambda self: self.worst.extra_cycles)
    largest_extra_cycle_kgf = property(lambda self: self.worst.largest_extra_cycle_kgf)
    overshoot_max_pct = property(lambda self: self.worst.overshoot_max_pct)
    range_kgf = property(lambda self: self.worst.range_kgf)
    turning_points = property(lambda self: self.worst.turning_points)

    def figures(self) -> dict:
        """The pass's figures as the JSON summary gives them (module docstring)."""
        worst = self.worst_channel
        return {**self.channel(worst).figures(), "worst_channel": worst,
                "ratio_error_pct": self.ratio_error_pct,
                "channels": {n: r.figures() for n, r in zip(self.names, self.channels)}}

    def to_dict(self) -> dict:
        d = self.figures()
        d["points"] = {n: r.to_dict()["points"] for n, r in zip(self.names, self.channels)}
        if self.cases is not None:
            d["load_cases"] = [vars(c) for c in self.cases]
        return d

    def text(self) -> str:
        if len(self.channels) == 1:
            return self.channels[0].text()
        width = max(len(n) for n in self.names)
        lines = [f"{'channel':<{width}}  points  range kgf   p95 %   max %   RMS %  overshoot %  extra cycles"]
        for n, r in zip(self.names, self.channels):
            pv = r.peak_valley_error_pct
            lines.append(f"{n:<{width}}  {len(r.turning_points):6d}  {r.range_kgf:8.0f}  {pv['p95']:6.3f}  "
                         f"{pv['max']:6.3f}  {r.rms_error_pct:6.3f}  {r.overshoot_max_pct:11.3f}  {r.extra_cycles:g}")
        lines.append(f"worst channel: {self.worst_channel}")
        if self.cases is not None:
            worst = sorted(self.cases, key=lambda c: -c.largest_pct)[:3]
            lines.append(f"load cases: {len(self.cases)}, ratio deviation at a turning point: largest "
                         f"{self.ratio_error_pct:.3f} % of a channel's range"
                         + (f", p95 {np.percentile([c.largest_pct for c in self.cases], 95):.3f} %"
                            if self.cases else ""))
            for c in worst:
                i = int(np.argmax(np.abs(c.deviation_pct)))
                lines.append(f"  worst: case {c.label} at {c.time_s:.2f} s: {self.names[i]} "
                             f"{c.achieved_kgf[i]:.0f} kgf for {c.commanded_kgf[i]:.0f} against lead {c.lead} "
                             f"({c.deviation_pct[i]:+.3f} %)")
        return "\n".join(lines)


def tracking_report(programme: Programme | ChannelProgramme, t_s, y_kgf) -> TrackingReport:
    """How the forces ``y_kgf`` (N, K) tracked the station's ``programme`` (the one asked for,
    not a compensated copy); ``t_s``: each sample's time on the programme's clock (0 at its
    start), non-decreasing: a programme that waited for the forces (null pacing) gives the
    samples of the wait the same time. Samples outside the programme are left out."""
    programme = as_programme(programme)
    t = np.asarray(t_s, float)
    Y = np.atleast_2d(np.asarray(y_kgf, float))
    cases = programme.turning_idx[programme.turning_cases()] if programme.load_cases and programme.n > 1 else None
    reports = [channel_report(p, t, y, cases=cases) for p, y in zip(programme.channels, Y)]
    cases = _load_cases(programme, reports, t, Y) if programme.load_cases and programme.n > 1 else None
    return TrackingReport(list(programme.names), reports, cases)


def _load_cases(programme: Programme, reports: list[ChannelReport], t: np.ndarray,
                Y: np.ndarray) -> list[LoadCase]:
    idx = programme.turning_idx
    L = programme.levels_kgf
    R = np.maximum(programme.ranges_kgf, 1e-9)
    labels = programme.case_labels or [str(k + 1) for k in range(len(idx))]
    achieved_at = [{tp.index: tp.achieved_kgf for tp in r.turning_points} for r in reports]
    out = []
    for k in range(1, len(idx) - 1):
        at = programme.t_s[idx[k]]
        if at < t[0] - 1e-9 or at > t[-1] + 1e-9:
            continue
        A = np.array([achieved_at[i].get(int(idx[k]), float(np.interp(at, t, Y[i])))
                      for i in range(programme.n)])
        lv = L[:, k]
        m = int(np.argmax(np.abs(lv) / R))
        if lv[m] == 0:
            continue
        d = 100 * (A - A[m] * lv / lv[m]) / R
        d[m] = 0.0
        out.append(LoadCase(labels[k], int(idx[k]), float(at), lv.tolist(), A.tolist(),
                            programme.names[m], d.tolist()))
    return out


def load_summary(passes: list[TrackingReport], end_reason: str | None,
                 extras: list[dict] | None = None) -> dict:
    """The ``--json`` object of ``stand load`` (schema ``hydrostand-load/1``, module
    docstring): the last pass's figures at the top level and every pass's in ``passes``;
    ``extras``: more figures per pass (the programme's time, the minimum, pacing), merged into
    each."""
    extras = list(extras or []) + [{}] * (len(passes) - len(extras or []))
    figures = [{**p.figures(), **x} for p, x in zip(passes, extras)]
    last = figures[-1] if figures else {}
    return {"schema": SCHEMA, **last, "end_reason": end_reason, "passes": figures}


def plot_tracking(programme: Programme | ChannelProgramme, t_s, y_kgf, report: TrackingReport,
                  path: str | Path, title: str = "") -> Path:
    """``tracking.png``: for one channel its programme and the achieved force over the whole
    pass with the worst turning points zoomed below; for several a grid, per channel (a row)
    the same with its worst turning point zoomed beside it."""
    programme = as_programme(programme)
    if programme.n == 1:
        return _plot_channel(programme.channels[0], t_s, np.atleast_2d(y_kgf)[0], report.channels[0], path, title)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    n = programme.n
    t = np.asarray(t_s, float)
    Y = np.asarray(y_kgf, float)
    fig, axes = plt.subplots(n, 2, figsize=(12, 2.2 * n + 0.8), squeeze=False,
                             gridspec_kw={"width_ratios": [3, 1]})
    span = max(programme.duration_s / max(len(programme.channels[0].turning_idx), 1), 0.2)
    for i, (name, p, rep) in enumerate(zip(programme.names, programme.channels, report.channels)):
        ax, zoom = axes[i]
        ax.plot(p.t_s, p.r_kgf, lw=0.8, label="programme")
        ax.plot(t, Y[i], lw=0.8, label="achieved")
        pv = rep.peak_valley_error_pct
        ax.set_ylabel(f"{name}, kgf")
        ax.set_title(f"{name}: p95 {pv['p95']:.2f} %, max {pv['max']:.2f} %, extra cycles {rep.extra_cycles:g}",
                     fontsize=9, loc="left")
        worst = rep.worst(1)
        if worst:
            tp = worst[0]
            ax.axvline(tp.time_s, color="0.7", lw=0.8)
            m = np.abs(p.t_s - tp.time_s) <= span
            k = np.abs(t - tp.time_s) <= span
            zoom.plot(p.t_s[m], p.r_kgf[m], lw=1)
            zoom.plot(t[k], Y[i][k], lw=1)
            zoom.axhline(tp.commanded_kgf, color="0.6", lw=0.8, ls="--")
            zoom.set_title(f"{tp.kind} {tp.commanded_kgf:.0f} kgf: {tp.error_pct:+.2f} %", fontsize=9)
    axes[0][0].legend(loc="upper right", fontsize=8)
    axes[-1][0].set_xlabel("t, s")
    axes[-1][1].set_xlabel("t, s")
    fig.suptitle(title or programme.source, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path
