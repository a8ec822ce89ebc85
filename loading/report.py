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

**A station** (:func:`tracking_report`): per channel the report above (:class:`ChannelReport`,
the error as % of its own programme's range). Every load case is part of the load
distribution, so on a station of load cases every channel is judged at every load case (the
first and the last left out): at its own peaks and valleys, and where it passes or holds its
level (no peak or valley of its own, kind 'rising' or 'falling'; its achieved level the force
at the load case's moment), in its p95 and max; its compensation learns at each
(:mod:`loading.compensation`, by load case). For several channels on load cases:

Per load case (load-case programmes only, the first and the last left out as the one-channel
report leaves them), the **ratio deviation**: a load case asks the channels' forces in fixed
ratios ``L_i/L_m``. The lead channel ``m`` is the one with the largest level for its range
(``|L_i|/R_i``); each other channel's deviation is how far its achieved level is from the one
the lead's achieved level asks of it in the load case's ratio,

.. math::  d_i = 100\,\frac{A_i - A_m\,L_i/L_m}{R_i}\ \%,

in % of channel i's range (as its peak/valley error; with ``A = L + e`` it is
``(e_i − e_m·L_i/L_m)/R_i``: a common scaling of the whole case, every channel off in the same
proportion, does not count). ``A_i`` is the channel's achieved level at the case (the extreme
near it for a peak or a valley, else the force at the case's moment, read from a straight line
through the samples within :data:`PASSING_WINDOW_S`). ``ratio_error_pct`` is the largest
``|d_i|`` of the pass. Between two load cases each channel's **shape**: the force's deviation
from the reference less the haversine share of the two ends' (:attr:`ChannelReport.shapes`,
what a station's compensation learns from), and how far the force went back against the
reference's way there (:attr:`ChannelReport.retreats`: an extra cycle in the making).

The JSON summary (``hydrostand-load/1``): the worst channel's figures at the top level (the
one-channel keys: the channel with the largest peak/valley p95, named in ``worst_channel``),
``channels`` → per channel the same keys, ``ratio_error_pct`` (null for one channel and for
per-channel sequences), ``load_cases`` (load cases: per case its ``case`` label, ``lead``,
``largest_pct``, every channel's ``deviation_pct`` and level ``error_pct``), and ``passes`` with
the same for every pass; from the second pass on, how its load cases moved from the pass
before's (:func:`case_moves`: ``cases_worse``, ``cases_closer``, ``cases_within_band``).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .programme import ChannelProgramme, Programme, as_programme, shape_basis, shape_modes, turning_points

SCHEMA = "hydrostand-load/1"
#: extra cycles are counted above this share of the programme's range (%)
GATE_PCT = 0.5
#: a load case is worse (or closer) than in the pass before when its largest deviation moved by
#: more than this (% of a channel's range): what noise alone moves it by (a deviation reads two
#: channels; the same pass again with other noise moved a case by up to 0.08 %, sd 0.03 %)
CASE_BAND_PCT = 0.1


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
    #: a station's load case (its position from 0; None for one channel's turning points):
    #: what a station's compensation learns by (loading.compensation)
    case: int | None = None


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
    #: a station's load cases: per segment (from load case k to k + 1) the force's deviation
    #: from the reference between them, less the haversine share of the two ends' (kgf), told in
    #: :func:`~loading.programme.shape_basis` (least squares): what the shape learns from
    shapes: dict | None = None
    #: the same segments: how far the force went back against the reference's way (kgf; a
    #: segment that holds its level: either way), the start of an extra cycle
    retreats: dict | None = None

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
            achieved = _at(programme.t_s[idx[j]], t, y)
        else:
            achieved = float(near.max() if kinds[j] == "peak" else near.min())
        err = achieved - level
        over = max(err, 0.0) if kinds[j] == "peak" else max(-err, 0.0) if kinds[j] == "valley" else 0.0
        points.append(TurningPoint(int(idx[j]), float(programme.t_s[idx[j]]), kinds[j], float(level),
                                   achieved, float(err), 100 * float(err) / R, float(over),
                                   j if cases is not None else None))
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
    shapes, retreats = _shapes(programme, t, y, eps, gate) if cases is not None else (None, None)
    return ChannelReport(
        turning_points=points, range_kgf=R, shapes=shapes, retreats=retreats,
        peak_valley_error_pct={"max": float(errs.max()), "p95": float(np.percentile(errs, 95))},
        rms_error_pct=100 * float(np.sqrt(np.mean((y - r) ** 2))) / R if len(y) else float("nan"),
        extra_cycles=float(extra), largest_extra_cycle_kgf=float(largest),
        overshoot_max_pct=100 * max((p.overshoot_kgf for p in points), default=0.0) / R)


#: a station's channel that passes its level at a load case is read there from a straight line
#: through its force within this time either side (s): a few cycles, the noise averaged
PASSING_WINDOW_S = 0.01


def _at(moment: float, t: np.ndarray, y: np.ndarray) -> float:
    """The force at ``moment``: a least-squares line through the samples within
    :data:`PASSING_WINDOW_S` of it (the nearest samples' interpolation with fewer than 3)."""
    near = np.abs(t - moment) <= PASSING_WINDOW_S + 1e-9
    if np.count_nonzero(near) < 3 or np.ptp(t[near]) <= 0:
        return float(np.interp(moment, t, y))
    slope, at = np.polyfit(t[near] - moment, y[near], 1)
    return float(at)


def _shapes(programme: ChannelProgramme, t: np.ndarray, y: np.ndarray, eps: float,
            gate_kgf: float) -> tuple[dict, dict]:
    """Per segment between two turning points: the shape of the force's deviation from the
    reference (:attr:`ChannelReport.shapes`) and how far the force went back against the
    reference's way there (:attr:`ChannelReport.retreats`, kgf)."""
    idx = programme.turning_idx
    shapes, retreats = {}, {}
    for k in range(len(idx) - 1):
        a, b = int(idx[k]), int(idx[k + 1])
        ts = programme.t_s[a:b + 1]
        if b - a < 2 or ts[0] < t[0] - eps or ts[-1] > t[-1] + eps:
            continue
        f = np.interp(ts, t, y)
        r = programme.r_kgf[a:b + 1]
        e = f - r
        h = (1 - np.cos(np.pi * np.linspace(0.0, 1.0, b - a + 1))) / 2
        rest = e - (e[0] + (e[-1] - e[0]) * h)
        shapes[k] = np.linalg.lstsq(shape_basis(b - a + 1, shape_modes(ts[-1] - ts[0])), rest, rcond=None)[0].tolist()
        ways = [1.0] if r[-1] > r[0] else [-1.0] if r[-1] < r[0] else [1.0, -1.0]
        retreats[k] = max(_retreat(w * f, gate_kgf / 4) for w in ways)
    return shapes, retreats


def _retreat(x: np.ndarray, noise: float) -> float:
    """How far ``x`` fell back after rising, from its lowest point on (a late turn at the start
    is no retreat), its samples smoothed over a few cycles."""
    if len(x) > 9:
        x = np.convolve(x, np.ones(5) / 5, mode="valid")
    x = x[int(np.argmin(x)):]
    return float(np.max(np.maximum.accumulate(x) - x)) if len(x) else 0.0


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
    #: each channel's level error there, % of its range (its turning point's, or the force at
    #: the load case's moment)
    error_pct: list[float] = field(default_factory=list)

    @property
    def largest_pct(self) -> float:
        return float(np.max(np.abs(self.deviation_pct)))

    def to_summary(self, names: list[str]) -> dict:
        """The load case as the JSON summary gives it, per pass."""
        return {"case": self.label, "lead": self.lead, "largest_pct": self.largest_pct,
                "deviation_pct": dict(zip(names, self.deviation_pct)),
                "error_pct": dict(zip(names, self.error_pct))}


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
        out = {**self.channel(worst).figures(), "worst_channel": worst,
               "ratio_error_pct": self.ratio_error_pct,
               "channels": {n: r.figures() for n, r in zip(self.names, self.channels)}}
        if self.cases is not None:
            out["load_cases"] = [c.to_summary(self.names) for c in self.cases]
        return out

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
            lines.append(f"load cases: {len(self.cases)}, deviation from the distribution: largest "
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
    cases = programme.turning_idx[1:-1] if programme.load_cases and programme.n > 1 else None
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
        A = np.array([achieved_at[i].get(int(idx[k]), _at(at, t, Y[i])) for i in range(programme.n)])
        lv = L[:, k]
        m = int(np.argmax(np.abs(lv) / R))
        if lv[m] == 0:
            continue
        d = 100 * (A - A[m] * lv / lv[m]) / R
        d[m] = 0.0
        out.append(LoadCase(labels[k], int(idx[k]), float(at), lv.tolist(), A.tolist(),
                            programme.names[m], d.tolist(), (100 * (A - lv) / R).tolist()))
    return out


def case_moves(before: list[dict], now: list[dict]) -> dict:
    """How a pass's load cases moved from the pass before's (their ``to_summary``): the cases
    whose largest deviation grew by more than :data:`CASE_BAND_PCT` (``cases_worse``, their
    labels), and how many fell by more (``cases_closer``) or stayed within it
    (``cases_within_band``)."""
    was = {c["case"]: c["largest_pct"] for c in before}
    worse, closer, same = [], 0, 0
    for c in now:
        d = c["largest_pct"] - was.get(c["case"], c["largest_pct"])
        if d > CASE_BAND_PCT:
            worse.append(c["case"])
        elif d < -CASE_BAND_PCT:
            closer += 1
        else:
            same += 1
    return {"cases_worse": worse, "cases_closer": closer, "cases_within_band": same}


def cases_table(passes: list[TrackingReport]) -> str:
    """Every pass's load cases side by side: per case its lead and, per pass, the largest
    deviation from its distribution (% of a channel's range) with the channel it is on, marked
    ``worse`` where it grew by more than :data:`CASE_BAND_PCT` from the pass before."""
    if not passes or passes[0].cases is None:
        return ""
    rows = {}
    for i, p in enumerate(passes):
        for c in p.cases:
            j = int(np.argmax(np.abs(c.deviation_pct)))
            rows.setdefault(c.label, {"lead": c.lead})[i] = (c.largest_pct, p.names[j])
    width = max(len(n) for n in passes[0].names)
    head = f"{'case':>5}  {'lead':<{width}}" + "".join(f"  {f'pass {i + 1}':<{width + 14}}" for i in range(len(passes)))
    lines = ["load cases: the largest deviation from the distribution, % of a channel's range, per pass "
             f"(worse: by more than {CASE_BAND_PCT:g} % than the pass before)", head]
    for label, row in rows.items():
        cells = []
        for i in range(len(passes)):
            if i not in row:
                cells.append(" " * (width + 14))
                continue
            v, name = row[i]
            mark = " worse" if i and (i - 1) in row and v - row[i - 1][0] > CASE_BAND_PCT else ""
            cells.append(f"{v:6.3f} {name:<{width}}{mark:<7}")
        lines.append(f"{label:>5}  {row['lead']:<{width}}" + "".join(f"  {c}" for c in cells))
    return "\n".join(lines)


def load_summary(passes: list[TrackingReport], end_reason: str | None,
                 extras: list[dict] | None = None) -> dict:
    """The ``--json`` object of ``stand load`` (schema ``hydrostand-load/1``, module
    docstring): the last pass's figures at the top level and every pass's in ``passes``;
    ``extras``: more figures per pass (the programme's time, the minimum, pacing), merged into
    each."""
    extras = list(extras or []) + [{}] * (len(passes) - len(extras or []))
    figures = [{**p.figures(), **x} for p, x in zip(passes, extras)]
    for before, now in zip(figures, figures[1:]):
        if "load_cases" in now:
            now.update(case_moves(before["load_cases"], now["load_cases"]))
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
