"""Figures for compare/diagnose/report (matplotlib, Agg backend: files only, no display).

* :func:`plot_overlay` — measurement and model overlaid, the residual below, window boundaries,
  the worst windows shaded and marked, the post-reversal regime tinted; zooms on the worst
  windows beneath. Long records are drawn as min/max envelopes (fast, faithful to the extremes).
* :func:`plot_regimes` — RMSE and slope error per regime, with the noise floor.
* :func:`plot_correlations` — residual autocorrelation and input–residual cross-correlation with
  their ±1.96/√N bands.
* :func:`plot_history` — the error of each model version of a data set, falling as effects are
  added, with the noise floor.
* :func:`plot_candidates` — the diagnosis: RMSE of the starting model and of each candidate.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from ..identification.metrics import Evaluation, reversal_mask


def pyplot():
    """matplotlib's pyplot on the Agg backend, imported on first use: loading it costs about
    0.2 s, which no command that draws nothing (``stand emulate``, ``stand run``) should pay."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt

MEAS = "#1f77b4"
MODEL = "#d62728"
RESID = "#444444"
WORST = "#ff7f0e"
AFTER = "#2ca02c"


def _target(path):
    """A file name becomes a Path; a binary file object (BytesIO) is written to as PNG."""
    return Path(path) if isinstance(path, (str, Path)) else path


def _envelope(t: np.ndarray, y: np.ndarray, max_points: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """Min/max decimation: at most ``max_points`` points that keep every extreme."""
    n = len(t)
    if n <= max_points:
        return t, y
    b = int(math.ceil(n / (max_points // 2)))
    m = n // b
    tt = t[:m * b].reshape(m, b)
    yy = y[:m * b].reshape(m, b)
    lo, hi = yy.argmin(axis=1), yy.argmax(axis=1)
    first = np.minimum(lo, hi)
    second = np.maximum(lo, hi)
    rows = np.arange(m)
    t_out = np.column_stack([tt[rows, first], tt[rows, second]]).reshape(-1)
    y_out = np.column_stack([yy[rows, first], yy[rows, second]]).reshape(-1)
    return t_out, y_out


def _spans(mask: np.ndarray, t: np.ndarray) -> list[tuple[float, float]]:
    z = np.concatenate([[0], mask.astype(int), [0]])
    edges = np.flatnonzero(np.diff(z))
    return [(float(t[a]), float(t[min(b, len(t)) - 1])) for a, b in zip(edges[::2], edges[1::2])]


def plot_overlay(ev: Evaluation, path: str | Path, title: str = "", worst: int = 3) -> Path:
    """Measurement vs model (windowed free run) and residual, per record; worst windows below."""
    plt = pyplot()
    from matplotlib.ticker import MaxNLocator
    path = _target(path)
    sims = ev.sims
    worst_w = ev.worst_windows(worst)
    nrec = len(sims)
    fig = plt.figure(figsize=(12, 3.2 * nrec + 2.8), constrained_layout=True)
    gs = fig.add_gridspec(2 * nrec + 1, max(1, len(worst_w)),
                          height_ratios=[2.2, 1.0] * nrec + [1.9])
    for i, s in enumerate(sims):
        ax = fig.add_subplot(gs[2 * i, :])
        axr = fig.add_subplot(gs[2 * i + 1, :], sharex=ax)
        t, y, yh, r = s.t, s.y, s.yhat, s.r
        ax.plot(*_envelope(t, y), color=MEAS, lw=0.8, label="measured y")
        ax.plot(*_envelope(t, yh), color=MODEL, lw=0.8, alpha=0.85, label="model ŷ (free run per window)")
        axr.plot(*_envelope(t, r), color=RESID, lw=0.6)
        axr.axhline(0, color="k", lw=0.5)
        for b in ev.noise_floor * np.array([-1, 1]):
            axr.axhline(b, color=RESID, lw=0.5, ls=":")
        dur = t[-1] - t[0] if len(t) > 1 else 1.0
        if dur / (s.window * s.record.dt) <= 80:
            for wstart in t[::s.window]:
                for a in (ax, axr):
                    a.axvline(wstart, color="0.85", lw=0.5, zorder=0)
        if dur <= 120:
            _, after = reversal_mask(s.q, s.record.dt)
            for a, b in _spans(after, t)[:400]:
                axr.axvspan(a, b, color=AFTER, alpha=0.12, lw=0)
        for k, w in enumerate(worst_w):
            if w.record == s.index and s.t[0] <= w.t_start <= s.t[-1]:
                for a in (ax, axr):
                    a.axvspan(w.t_start, w.t_end, color=WORST, alpha=0.18, lw=0)
                ax.annotate(f"#{k + 1}", (w.t_start, 1.0), xycoords=("data", "axes fraction"),
                            va="bottom", fontsize=8, color=WORST)
        name = Path(str(s.record.source)).name
        ax.set_title(f"{name}: RMSE {math.sqrt(np.mean(r ** 2)):.3g} kgf" if nrec > 1 else
                     (title or f"{ev.model.spec}: RMSE {ev.rmse:.3g} kgf, fit {ev.fit_percent:.1f} %"),
                     fontsize=10, loc="left")
        ax.set_ylabel("force, kgf")
        axr.set_ylabel("ŷ − y, kgf")
        if i == 0:
            ax.legend(loc="upper right", fontsize=8)
        if i == nrec - 1:
            axr.set_xlabel("time, s  (shaded: worst windows; green: first "
                           "0.2 s after reversals; dotted: ± noise floor)")
    for k, w in enumerate(worst_w):
        ax = fig.add_subplot(gs[-1, k])
        s = next(x for x in sims if x.index == w.record and x.t[0] <= w.t_start <= x.t[-1])
        sel = (s.t >= w.t_start) & (s.t <= w.t_end)
        ax.plot(s.t[sel], s.y[sel], color=MEAS, lw=0.9)
        ax.plot(s.t[sel], s.yhat[sel], color=MODEL, lw=0.9)
        ax2 = ax.twinx()
        ax2.plot(s.t[sel], s.r[sel], color=RESID, lw=0.6, alpha=0.7)
        ax2.set_ylabel("ŷ − y", fontsize=7, color=RESID)
        ax2.tick_params(labelsize=7)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(4))
        ax.set_title(f"#{k + 1} worst: {w.t_start:.1f}–{w.t_end:.1f} s, {w.rmse:.3g} kgf ({w.regime})",
                     fontsize=8, color=WORST, loc="left")
    fig.savefig(path, dpi=90, format="png")
    plt.close(fig)
    return path


def plot_regimes(ev: Evaluation, path: str | Path) -> Path:
    """RMSE per regime (bars) and slope error relative to the model's slope (dots)."""
    plt = pyplot()
    path = _target(path)
    regs = ev.regimes
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 0.32 * len(regs) + 1.8), constrained_layout=True)
    names = [f"{r.group}: {r.name}" for r in regs]
    y = np.arange(len(regs))[::-1]
    ax.barh(y, [r.rmse for r in regs], color=[WORST if r.sse_share > 1.5 * r.time_share else MEAS for r in regs])
    ax.axvline(ev.noise_floor, color="k", ls=":", lw=1, label="noise floor")
    ax.set_yticks(y, names, fontsize=8)
    ax.set_xlabel("windowed RMSE, kgf (orange: error share > 1.5 × time share)")
    ax.legend(fontsize=8)
    rel = [100 * r.rate_bias_rel if math.isfinite(r.rate_bias_rel) and abs(r.rate_bias_rel) < 10 else np.nan
           for r in regs]
    ax2.scatter(rel, y, color=MODEL)
    ax2.axvline(0, color="k", lw=0.5)
    ax2.set_yticks(y, [""] * len(y))
    ax2.set_xlabel("model slope error, % of the model's slope (+: model too fast)")
    fig.savefig(path, dpi=90, format="png")
    plt.close(fig)
    return path


def plot_correlations(ev: Evaluation, path: str | Path) -> Path:
    plt = pyplot()
    path = _target(path)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 3.2), constrained_layout=True)
    dt = ev.sims[0].record.dt
    for ax, test, title in ((a1, ev.whiteness, "residual autocorrelation"),
                            (a2, ev.input_correlation, "input–residual cross-correlation")):
        lags = np.asarray(test.lags) * dt
        ax.vlines(lags, 0, test.values, color=RESID, lw=0.8)
        ax.axhline(test.band, color=MODEL, ls="--", lw=0.8)
        ax.axhline(-test.band, color=MODEL, ls="--", lw=0.8)
        ax.axhline(0, color="k", lw=0.5)
        verdict = "white" if test.white else "structure left"
        ax.set_title(f"{title} (±1.96/√N = ±{test.band:.2g}; p = {test.p_value:.2g}: {verdict})",
                     fontsize=9, loc="left")
        ax.set_xlabel("lag, s")
    fig.savefig(path, dpi=90, format="png")
    plt.close(fig)
    return path


def _error_bars(labels: Sequence[str], rmse: Sequence[float], floor: float | None, title: str,
                path: str | Path) -> Path:
    """Bars: the windowed RMSE of a sequence of models, the last highlighted; dotted: the noise
    floor."""
    plt = pyplot()
    path = _target(path)
    fig, ax = plt.subplots(figsize=(max(6, 1.3 * len(rmse) + 3), 3.6), constrained_layout=True)
    x = np.arange(len(rmse))
    bars = ax.bar(x, rmse, color=[MEAS] * (len(rmse) - 1) + [MODEL])
    for b, v in zip(bars, rmse):
        ax.annotate(f"{v:.3g}", (b.get_x() + b.get_width() / 2, b.get_height()), ha="center",
                    va="bottom", fontsize=8)
    if floor:
        ax.axhline(floor, color="k", ls=":", lw=1, label=f"noise floor {floor:.3g} kgf")
        ax.legend(fontsize=8)
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_ylabel("windowed RMSE, kgf")
    if max(rmse) / max(min(rmse), 1e-9) > 30:
        ax.set_yscale("log")
    ax.set_title(title, fontsize=10, loc="left")
    fig.savefig(path, dpi=90, format="png")
    plt.close(fig)
    return path


def plot_history(versions: Sequence[dict], path: str | Path) -> Path:
    """Bars: RMSE of each model version; dotted: the noise floor."""
    return _error_bars([f"v{v['version']}\n{v['model'].replace('base+', '+').replace('+', ' +')}"
                        for v in versions], [v["metrics"]["rmse"] for v in versions],
                       versions[-1]["metrics"].get("noise_floor_rmse"),
                       "error of each model version", path)


def plot_candidates(diag, path: str | Path) -> Path:
    """The diagnosis at a glance: starting model and each candidate's RMSE."""
    plt = pyplot()
    path = _target(path)
    names = [diag.model] + [f"+{c.effect}" for c in diag.candidates]
    rmse = [diag.base_eval.rmse] + [c.rmse for c in diag.candidates]
    colors = [RESID] + [MODEL if c.effect == diag.best else (MEAS if c.earns else "0.7") for c in diag.candidates]
    fig, ax = plt.subplots(figsize=(9, 0.35 * len(names) + 1.5), constrained_layout=True)
    y = np.arange(len(names))[::-1]
    ax.barh(y, rmse, color=colors)
    ax.axvline(diag.base_eval.noise_floor, color="k", ls=":", lw=1, label="noise floor")
    ax.set_yticks(y, names, fontsize=9)
    ax.set_xlabel("windowed RMSE, kgf (red: best, blue: earns its parameters)")
    if max(rmse) / max(min(rmse), 1e-9) > 30:
        ax.set_xscale("log")
    ax.legend(fontsize=8)
    ax.set_title(f"verdict: {diag.verdict}", fontsize=10, loc="left")
    fig.savefig(path, dpi=90, format="png")
    plt.close(fig)
    return path


def plot_stepwise(result, path: str | Path) -> Path:
    """The build-up at a glance: the error after each added effect, against the noise floor."""
    steps = result.steps
    labels = ["base" if i == 0 else f"+{steps[i - 1].added}" for i in range(len(steps))]
    return _error_bars(labels, [s.rmse for s in steps], steps[-1].diagnosis.base_eval.noise_floor,
                       f"stepwise: {result.verdict} with {result.model.spec}", path)


def plot_rig_forces(records: Sequence, path: str | Path, title: str = "") -> Path:
    """A rig's runs (:class:`analysis.rig.record.RigRecord`), one column of panels per run,
    one panel per channel: its force (kgf) and, on the right axis, its valve command (%).
    What a person looks at first after a rig meander: which forces followed the driven valve."""
    plt = pyplot()
    records = list(records)
    n = records[0].n
    fig, axes = plt.subplots(n, len(records), figsize=(4.5 + 3.5 * len(records), 1.6 * n + 1),
                             sharex="col", squeeze=False)
    for col, rec in enumerate(records):
        moving = {rec.names[i] for i in range(rec.n) if np.ptp(rec.u[i]) > 0}
        u_max = 1.1 * max(float(np.abs(rec.u).max()), 1.0)     # one command scale per run
        for row, (name, ch) in enumerate(zip(rec.names, rec.channels)):
            ax = axes[row, col]
            ax.plot(*_envelope(ch.t, ch.y), color=MEAS, lw=0.8)
            ax.set_ylabel(f"{name}\nkgf", fontsize=8)
            ax.tick_params(labelsize=7)
            cmd = ax.twinx()
            cmd.plot(*_envelope(ch.t, ch.u), color=MODEL if name in moving else RESID, lw=0.6,
                     alpha=0.7)
            cmd.set_ylim(-u_max, u_max)
            cmd.set_ylabel("u %", fontsize=7)
            cmd.tick_params(labelsize=7)
            if row == 0:
                ax.set_title(f"{Path(rec.source).name}: {', '.join(sorted(moving)) or 'none'} driven",
                             fontsize=9)
        axes[-1, col].set_xlabel("t, s", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90, format="png")
    plt.close(fig)
    return Path(path)
