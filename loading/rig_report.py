r"""How a rig tracked a multi-channel programme: every channel's report, and each load case's
ratios between the channels.

Per channel, the one-channel tracking report (:mod:`loading.report`): its peaks and valleys, the
error as % of its own programme's range, p95 and max, RMS, overshoot, extra rainflow cycles.

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

The JSON summary (``hydrostand-load/1``, extended): the worst channel's figures at the top level
(today's keys: the channel with the largest peak/valley p95, named in ``worst_channel``),
``channels`` → per channel the same keys, ``ratio_error_pct``, and ``passes`` with the same for
every pass.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .report import SCHEMA, TrackingReport, tracking_report
from .rig_programme import RigProgramme


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
class RigTrackingReport:
    names: list[str]
    channels: list[TrackingReport]
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

    def channel(self, name: str) -> TrackingReport:
        return self.channels[self.names.index(name)]

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


def rig_tracking_report(programme: RigProgramme, t_s, y_kgf) -> RigTrackingReport:
    """How the forces ``y_kgf`` (N, K) tracked ``programme`` (the one asked for, not a
    compensated copy); ``t_s``: each sample's time on the programme's clock (0 at its start)."""
    t = np.asarray(t_s, float)
    Y = np.asarray(y_kgf, float)
    reports = [tracking_report(p, t, y) for p, y in zip(programme.channels, Y)]
    cases = _load_cases(programme, reports, t, Y) if programme.load_cases else None
    return RigTrackingReport(list(programme.names), reports, cases)


def _load_cases(programme: RigProgramme, reports: list[TrackingReport], t: np.ndarray,
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


def rig_load_summary(passes: list[RigTrackingReport], end_reason: str | None,
                     extras: list[dict] | None = None) -> dict:
    """The ``--json`` object of ``stand load --rig`` (module docstring)."""
    extras = list(extras or []) + [{}] * (len(passes) - len(extras or []))
    figures = [{**p.figures(), **x} for p, x in zip(passes, extras)]
    last = figures[-1] if figures else {}
    return {"schema": SCHEMA, **last, "end_reason": end_reason, "passes": figures}


def plot_rig_tracking(programme: RigProgramme, t_s, y_kgf, report: RigTrackingReport,
                      path: str | Path, title: str = "") -> Path:
    """A grid: per channel (a row) the programme and the achieved force over the whole pass,
    and its worst turning point zoomed beside it."""
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
