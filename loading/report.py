r"""How well a pass tracked its programme: turning points, RMS error, self-oscillation.

Per turning point of the programme (its peaks and valleys) the **achieved level** is the extreme
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
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .programme import Programme, turning_points

SCHEMA = "hydrostand-load/1"
#: extra cycles are counted above this share of the programme's range (%)
GATE_PCT = 0.5


@dataclass
class TurningPoint:
    index: int             #: sample of the programme
    time_s: float
    kind: str              #: "peak" | "valley"
    commanded_kgf: float
    achieved_kgf: float
    error_kgf: float       #: achieved − commanded
    error_pct: float       #: of the programme's range
    overshoot_kgf: float   #: beyond the level in the direction of travel (0 if short of it)


@dataclass
class TrackingReport:
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


def tracking_report(programme: Programme, t_s, y_kgf, gate_pct: float = GATE_PCT) -> TrackingReport:
    """How the achieved force ``y_kgf`` tracked the ``programme`` (the one the user asked for,
    not a compensated copy). ``t_s``: each sample's time on the programme's clock (0 at its
    start), non-decreasing: a programme that waited for the force (null pacing) gives the
    samples of the wait the same time. Samples outside the programme are left out."""
    t = np.asarray(t_s, float)
    y_all = np.asarray(y_kgf, float)
    eps = programme.period_s * 1e-3
    inside = (t >= -eps) & (t <= programme.duration_s + eps)
    t, y = t[inside], y_all[inside]
    r = np.interp(t, programme.t_s, programme.r_kgf)
    R = programme.range_kgf
    idx = programme.turning_idx
    kinds = programme.kinds()
    points = []
    for j in range(1, len(idx) - 1):
        if kinds[j] not in ("peak", "valley"):
            continue
        lo = programme.t_s[(idx[j - 1] + idx[j]) // 2] - eps
        hi = programme.t_s[(idx[j] + idx[j + 1]) // 2] + eps
        near = y[np.searchsorted(t, lo, "left"):np.searchsorted(t, hi, "right")]
        level = programme.r_kgf[idx[j]]
        if not len(near):
            continue
        achieved = float(near.max() if kinds[j] == "peak" else near.min())
        err = achieved - level
        over = max(err, 0.0) if kinds[j] == "peak" else max(-err, 0.0)
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
    return TrackingReport(
        turning_points=points, range_kgf=R,
        peak_valley_error_pct={"max": float(errs.max()), "p95": float(np.percentile(errs, 95))},
        rms_error_pct=100 * float(np.sqrt(np.mean((y - r) ** 2))) / R if len(y) else float("nan"),
        extra_cycles=float(extra), largest_extra_cycle_kgf=float(largest),
        overshoot_max_pct=100 * max((p.overshoot_kgf for p in points), default=0.0) / R)


def load_summary(passes: list[TrackingReport], end_reason: str | None,
                 extras: list[dict] | None = None) -> dict:
    """The ``--json`` object of ``stand load`` (schema ``hydrostand-load/1``): the last pass's
    figures at the top level and every pass's in ``passes``; ``extras``: more figures per pass
    (the programme's time, the minimum, pacing), merged into each."""
    extras = list(extras or []) + [{}] * (len(passes) - len(extras or []))
    figures = [{**p.figures(), **x} for p, x in zip(passes, extras)]
    last = figures[-1] if figures else {}
    return {"schema": SCHEMA, **last, "end_reason": end_reason, "passes": figures}


def plot_tracking(programme: Programme, t_s, y_kgf, report: TrackingReport, path: str | Path,
                  title: str = "") -> Path:
    """Commanded vs achieved force over the whole programme, and the worst turning points
    zoomed below it."""
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

