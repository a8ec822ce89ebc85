"""The campaign report: per-experiment tables (CSV), figures (PNG) and a summary of g and τ.

Input: estimates of many runs (a campaign's ``runs/`` or any recorded runs and CSV files);
output, in one directory::

    summary.csv / summary.txt        g and τ per experiment and method, 95 % intervals, truth beside
    estimates.json                   every input's estimate (schema hydrostand-estimate/1)
    meander_portions.csv             g per portion and u0 with intervals (tables behind Figs. 11, 12)
    meander_contrast.csv             transitional / main gain per u0
    pfeedback_grid.csv               g over the (ω, A_r) grid (Figs. 15-18)
    relay_grid.csv                   exact and eq. (4) estimates over the (u0, r) grid (Figs. 21-23)
    fig*.png                         the figures, named after the paper's

The truth (the emulator's parameters) comes from each run's ``truth.json``; this module is the
only reader of that file; the estimators never see it.
"""
from __future__ import annotations

import csv
import json
import math
from collections import defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from gateway.errors import StandError
from gateway.runs import is_run_dir, read_truth

from ..estimators.dispatch import Estimate, EstimateOptions, error_json, estimate_record, result_json
from ..estimators.meander import MeanderEstimate, mean_ci
from ..estimators.pfeedback import PFeedbackEstimate
from ..estimators.relay import DF_PEAK_BIAS, RelayEstimate
from ..records.load import load
from ..records.record import Record
from .plots import pyplot


@dataclass
class ReportInput:
    """One input of the report: its estimate (or the error), its truth if emulated."""

    source: str
    estimate: Estimate | None = None
    error: str | None = None
    truth: dict[str, Any] | None = None
    record: Record | None = None


@dataclass
class SummaryRow:
    experiment: str
    quantity: str                   #: "g" | "tau" | "delta"
    method: str
    estimate: float
    ci_low: float
    ci_high: float
    unit: str
    truth: float | None
    error_pct: float | None
    runs: int
    note: str = ""


@dataclass
class CampaignReport:
    out_dir: Path
    summary: list[SummaryRow]
    tables: list[Path] = field(default_factory=list)
    figures: list[Path] = field(default_factory=list)
    failures: list[tuple[str, str]] = field(default_factory=list)
    truth: dict[str, Any] | None = None
    text: str = ""


# -- inputs ------------------------------------------------------------------------------------
def expand_inputs(paths: Iterable[str | Path]) -> list[Path]:
    """Run directories, CSV files and campaign directories (their ``runs/*``), in order."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir() and not is_run_dir(p) and (p / "runs").is_dir():
            out += sorted(d for d in (p / "runs").iterdir() if is_run_dir(d))
        else:
            out.append(p)
    return out


def estimate_inputs(paths: Iterable[str | Path], options: EstimateOptions | None = None,
                    keep_records: bool = True, channel: str | None = None) -> list[ReportInput]:
    """Estimate every input; failures are kept with their message, never as numbers.
    ``channel``: the channel of a rig run."""
    items = []
    for path in expand_inputs(paths):
        item = ReportInput(str(path) if channel is None else f"{path}#{channel}")
        try:
            rec = load(path, channel)
            item.estimate = estimate_record(rec, options)
            item.record = rec if keep_records else None
        except StandError as exc:
            item.error = str(exc)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:   # unusable numbers
            item.error = f"{path}: the estimate failed on these data ({type(exc).__name__}: {exc})"
        if path.is_dir():
            try:
                item.truth = read_truth(path)
            except (OSError, json.JSONDecodeError):
                item.truth = None
        items.append(item)
    return items


# -- summary -------------------------------------------------------------------------------------
def _truth_value(items: list[ReportInput], key: str) -> float | None:
    values = {round(float(i.truth["params"][key]), 12) for i in items
              if i.truth and key in (i.truth.get("params") or {})}
    return values.pop() if len(values) == 1 else None


def _row(experiment: str, quantity: str, method: str, values: list[float], unit: str,
         truth: float | None, note: str = "", pooled: tuple[float, float, float] | None = None) -> SummaryRow | None:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    if not vals:
        return None
    m, lo, hi = pooled if pooled else mean_ci(vals)
    if len(vals) == 1 and not pooled:
        lo = hi = math.nan
    err = 100.0 * (m - truth) / truth if truth else None
    return SummaryRow(experiment, quantity, method, m, lo, hi, unit, truth, err, len(vals), note)


def summarize(items: list[ReportInput]) -> list[SummaryRow]:
    """g and τ per experiment and method: means over the runs with 95 % intervals."""
    by = defaultdict(list)
    for i in items:
        if i.estimate is not None:
            by[i.estimate.experiment].append(i)
    g_true, tau_true, d_true = (_truth_value(items, k) for k in ("g", "tau", "delta"))
    rows: list[SummaryRow | None] = []
    ms = [i.estimate.result for i in by.get("meander", [])]
    if ms:
        seg_main = [s.g_main for m in ms for s in m.segments]
        seg_tr = [s.g_transitional for m in ms for s in m.segments]
        rows += [
            _row("meander", "g", "eq. (2), main portions (pooled segments)", seg_main, "kgf/(%·s)", g_true,
                 pooled=mean_ci(seg_main)),
            _row("meander", "g", "eq. (2), transitional portions (pooled segments)", seg_tr, "kgf/(%·s)",
                 g_true, "transitional gain: above g where the rod reversal adds force", pooled=mean_ci(seg_tr)),
            _row("meander", "delta", "trend Δ of eq. (2)", [m.delta for m in ms], "kgf/s", d_true),
            _row("meander", "tau", "rough: force extrema after the reversals", [m.tau for m in ms if m.tau],
                 "s", tau_true),
        ]
    ps = [i.estimate.result for i in by.get("pfeedback", [])]
    if ps:
        rows += [
            _row("pfeedback", "g", "eq. (3), mean over the (ω, A_r) grid", [p.g for p in ps], "kgf/(%·s)", g_true),
            _row("pfeedback", "tau", "phase of y against u", [p.tau for p in ps if p.tau is not None], "s",
                 tau_true, "model-sensitive: any unmodelled phase enters it"),
        ]
    rs = [i.estimate.result for i in by.get("relay", [])]
    if rs:
        rows += [
            _row("relay", "g", "exact limit cycle 4A/(u0·P) (recommended)", [r.g for r in rs], "kgf/(%·s)", g_true),
            _row("relay", "tau", "exact limit cycle P/4 − T/2 (recommended)", [r.tau for r in rs], "s", tau_true),
            _row("relay", "g", "eq. (4) with the peak A (paper; biased ×π²/8)", [r.g_df_peak for r in rs],
                 "kgf/(%·s)", g_true, f"biased: overestimates g by π²/8 = {DF_PEAK_BIAS:.3f}"),
            _row("relay", "g", "eq. (4) with the first harmonic A₁", [r.g_df_harmonic for r in rs],
                 "kgf/(%·s)", g_true),
            _row("relay", "tau", "eq. (4) π/(2ω) = P/4 (no sampling correction)", [r.tau_df for r in rs],
                 "s", tau_true, "biased by +T/2 (the sampling)"),
        ]
    return [r for r in rows if r is not None]


# -- tables --------------------------------------------------------------------------------------
def _write_csv(path: Path, rows: list[dict[str, Any]]) -> Path:
    with path.open("w", newline="") as fh:
        if not rows:
            fh.write("")
            return path
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: _cell(v) for k, v in r.items()})
    return path


def _cell(v: Any) -> Any:
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.6g}"
    if v is None:
        return ""
    return v


def meander_rows(items: list[ReportInput]) -> tuple[list[dict], list[dict]]:
    portions, contrast = [], []
    for i in items:
        if i.estimate is None or i.estimate.experiment != "meander":
            continue
        m: MeanderEstimate = i.estimate.result
        for p in m.portions:
            portions.append({"run": i.source, "u0_pct": p.amplitude_pct, "portion": p.portion, "g": p.g,
                             "ci_low": p.ci_low, "ci_high": p.ci_high, "n": p.n,
                             "transitional_s": m.transitional_s})
        for amp in sorted({p.amplitude_pct for p in m.portions}):
            main = [s.g_main for s in m.segments if round(abs(s.u), 6) == amp]
            tr = [s.g_transitional for s in m.segments if round(abs(s.u), 6) == amp]
            gm, gt = mean_ci(main)[0], mean_ci(tr)[0]
            contrast.append({"run": i.source, "u0_pct": amp, "g_main": gm, "g_transitional": gt,
                             "ratio": gt / gm if gm else math.nan, "transitional_s": m.transitional_s,
                             "transitional_detected": m.transitional_detected})
    contrast.sort(key=lambda r: r["u0_pct"])
    return portions, contrast


def pfeedback_rows(items: list[ReportInput]) -> list[dict]:
    rows = []
    for i in items:
        if i.estimate is None or i.estimate.experiment != "pfeedback":
            continue
        p: PFeedbackEstimate = i.estimate.result
        rows.append({"run": i.source, "omega_rad_s": p.omega_rad_s, "A_r_kgf": p.reference_kgf,
                     "k_pct_per_kgf": p.gain, "A_u_pct": p.amplitude_u_pct, "A_y_kgf": p.amplitude_y_kgf,
                     "g": p.g, "ci_low": p.g_ci[0], "ci_high": p.g_ci[1],
                     "tau_phase_s": p.tau if p.tau is not None else math.nan, "periods": p.periods,
                     "transient_s": p.transient_s, "warnings": " | ".join(p.warnings)})
    rows.sort(key=lambda r: (r["omega_rad_s"], r["A_r_kgf"]))
    return rows


def relay_rows(items: list[ReportInput]) -> list[dict]:
    rows = []
    for i in items:
        if i.estimate is None or i.estimate.experiment != "relay":
            continue
        r: RelayEstimate = i.estimate.result
        a = r.asymmetry
        rows.append({"run": i.source, "u0_pct": r.amplitude_pct, "r_kgf": r.reference_kgf,
                     "g": r.g, "g_ci_low": r.g_ci[0], "g_ci_high": r.g_ci[1],
                     "tau_s": r.tau, "tau_ci_low": r.tau_ci[0], "tau_ci_high": r.tau_ci[1],
                     "g_eq4_peak": r.g_df_peak, "g_eq4_harmonic": r.g_df_harmonic, "tau_eq4_s": r.tau_df,
                     "eq4_peak_bias": r.df_bias, "period_s": r.period_s, "peak_kgf": r.peak_kgf,
                     "hysteresis_kgf": r.hysteresis_kgf, "cycles": r.cycles,
                     "slope_asymmetry": a["slope_rise_vs_fall"], "halfperiod_asymmetry": a["time_plus_vs_minus"],
                     "peak_asymmetry": a["peak_above_vs_below"], "warnings": " | ".join(r.warnings)})
    rows.sort(key=lambda r: (r["u0_pct"], r["r_kgf"]))
    return rows


# -- figures -------------------------------------------------------------------------------------
def _save(plt, fig, path: Path) -> Path:
    """Lay out, write (PNG, 110 dpi) and close one figure; returns its path."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _truth_line(ax, value: float | None, label: str = "truth (emulator)") -> None:
    if value is not None:
        ax.axhline(value, color="k", ls="--", lw=1, label=label)


def _errbar(ax, x, y, lo, hi, **kw) -> None:
    x, y, lo, hi = map(lambda a: np.asarray(a, float), (x, y, lo, hi))
    yerr = np.vstack([np.where(np.isfinite(lo), y - lo, 0), np.where(np.isfinite(hi), hi - y, 0)])
    ax.errorbar(x, y, yerr=yerr, capsize=3, marker="o", **kw)


def meander_figures(portions: list[dict], g_true: float | None, out: Path) -> list[Path]:
    if not portions:
        return []
    plt = pyplot()
    files = []
    for fig_no, kind, title in ((11, "main", "main portions"), (12, "transitional", "transitional portions")):
        fig, ax = plt.subplots(figsize=(6, 4))
        for name, style in ((f"{kind}_rise", "-"), (f"{kind}_fall", "--")):
            rows = sorted((r for r in portions if r["portion"] == name), key=lambda r: r["u0_pct"])
            if rows:
                _errbar(ax, [r["u0_pct"] for r in rows], [r["g"] for r in rows], [r["ci_low"] for r in rows],
                        [r["ci_high"] for r in rows], ls=style, label=name.replace("_", " "))
        _truth_line(ax, g_true, "g of the model (truth)")
        ax.set_xlabel("u0, %")
        ax.set_ylabel("g by eq. (2), kgf/(%·s)")
        ax.set_title(f"Fig. {fig_no}: gain g during the {title} (95 % CI)")
        ax.grid(alpha=0.3)
        ax.legend()
        files.append(_save(plt, fig, out / f"fig{fig_no}_meander_{kind}.png"))
    return files


def pfeedback_figures(rows: list[dict], g_true: float | None, out: Path) -> list[Path]:
    if not rows:
        return []
    plt = pyplot()
    files = []
    omegas = sorted({r["omega_rad_s"] for r in rows})
    amps = sorted({round(r["A_r_kgf"]) for r in rows})
    if len(omegas) >= 2 and len(amps) >= 2:
        G = np.full((len(amps), len(omegas)), np.nan)
        for r in rows:
            G[amps.index(round(r["A_r_kgf"])), omegas.index(r["omega_rad_s"])] = r["g"]
        fig = plt.figure(figsize=(7, 5))
        ax = fig.add_subplot(projection="3d")
        W, A = np.meshgrid(omegas, amps)
        ax.plot_surface(W, A, G, cmap="viridis", edgecolor="k", lw=0.3, alpha=0.9)
        ax.set_xlabel("ω, rad/s")
        ax.set_ylabel("A_r, kgf")
        ax.set_zlabel("g, kgf/(%·s)")
        ax.set_title("Fig. 15: g by eq. (3) over ω and A_r")
        files.append(_save(plt, fig, out / "fig15_pfeedback_surface.png"))
    for fig_no, x_key, group_key, xlabel, glabel in (
            (17, "omega_rad_s", "A_r_kgf", "ω, rad/s", "A_r = {:g} kgf"),
            (18, "A_r_kgf", "omega_rad_s", "A_r, kgf", "ω = {:.4g} rad/s")):
        fig, ax = plt.subplots(figsize=(6, 4))
        groups = defaultdict(list)
        for r in rows:
            groups[round(r[group_key], 6)].append(r)
        for key in sorted(groups):
            g = sorted(groups[key], key=lambda r: r[x_key])
            _errbar(ax, [r[x_key] for r in g], [r["g"] for r in g], [r["ci_low"] for r in g],
                    [r["ci_high"] for r in g], label=glabel.format(key))
        _truth_line(ax, g_true, "g of the model (truth)")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("g by eq. (3), kgf/(%·s)")
        ax.set_title(f"Fig. {fig_no}: g by eq. (3), view along {'ω' if fig_no == 17 else 'A_r'}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        name = f"fig{fig_no}_pfeedback_g_vs_{'omega' if fig_no == 17 else 'amplitude'}.png"
        files.append(_save(plt, fig, out / name))
    return files


def relay_figures(rows: list[dict], g_true: float | None, tau_true: float | None, out: Path) -> list[Path]:
    if not rows:
        return []
    plt = pyplot()
    files = []
    u0s = sorted({r["u0_pct"] for r in rows})
    refs = sorted({r["r_kgf"] for r in rows})
    if len(u0s) >= 2 and len(refs) >= 2:
        fig = plt.figure(figsize=(7, 5))
        ax = fig.add_subplot(projection="3d")
        ax.scatter([r["u0_pct"] for r in rows], [r["r_kgf"] for r in rows], [r["g"] for r in rows],
                   label="exact", color="C0")
        ax.scatter([r["u0_pct"] for r in rows], [r["r_kgf"] for r in rows], [r["g_eq4_peak"] for r in rows],
                   label="eq. (4), peak", color="C3", marker="^")
        ax.set_xlabel("u0, %")
        ax.set_ylabel("r, kgf")
        ax.set_zlabel("g, kgf/(%·s)")
        ax.set_title("Fig. 21: relay estimates of g over u0 and r")
        ax.legend()
        files.append(_save(plt, fig, out / "fig21_relay_g_surface.png"))
    for fig_no, keys, ylabel, truth, scale, name in (
            (22, (("g", "exact 4A/(u0·P)"), ("g_eq4_peak", "eq. (4), peak (biased ×π²/8)"),
                  ("g_eq4_harmonic", "eq. (4), first harmonic")), "g, kgf/(%·s)", g_true, 1.0, "g"),
            (23, (("tau_s", "exact P/4 − T/2"), ("tau_eq4_s", "eq. (4) P/4")), "τ, ms",
             tau_true * 1e3 if tau_true is not None else None, 1e3, "tau")):
        fig, ax = plt.subplots(figsize=(6, 4))
        for j, (key, label) in enumerate(keys):
            x = np.array([r["u0_pct"] for r in rows], float) + (j - 1) * 0.25
            ax.scatter(x, np.array([r[key] for r in rows], float) * scale, s=14, label=label)
        _truth_line(ax, truth, "model (truth)")
        ax.set_xlabel("u0, %  (the spread at each u0 is over r)")
        ax.set_ylabel(ylabel)
        ax.set_title(f"Fig. {fig_no}: relay estimates of {'g' if name == 'g' else 'τ'}, view along u0")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        files.append(_save(plt, fig, out / f"fig{fig_no}_relay_{name}_vs_u0.png"))
    return files


def trace_figures(items: list[ReportInput], out: Path) -> list[Path]:
    """One example run of each experiment: u and y against time (Figs. 4, 14, 20)."""
    plt = pyplot()
    files = []
    for exp, fig_no in (("meander", 4), ("pfeedback", 14), ("relay", 20)):
        item = next((i for i in items if i.estimate is not None and i.record is not None
                     and i.estimate.experiment == exp), None)
        if item is None:
            continue
        rec = item.record
        sel = slice(None)
        if exp == "relay":
            start = item.estimate.result.start_s
            sel = (rec.t >= start) & (rec.t <= start + 6 * item.estimate.result.period_s)
        fig, (a1, a2) = plt.subplots(2, 1, sharex=True, figsize=(7, 4.5))
        a1.plot(rec.t[sel], rec.y[sel], lw=0.8, label="y")
        if rec.has_reference():
            a1.plot(rec.t[sel], rec.r[sel], lw=0.8, ls="--", label="r")
        a1.set_ylabel("force, kgf")
        a1.legend(fontsize=8)
        a1.grid(alpha=0.3)
        a2.plot(rec.t[sel], rec.u[sel], lw=0.8, color="C2")
        a2.set_ylabel("command u, %")
        a2.set_xlabel("t, s")
        a2.grid(alpha=0.3)
        a1.set_title(f"Fig. {fig_no}: {exp}, {Path(item.source).name}")
        files.append(_save(plt, fig, out / f"fig{fig_no:02d}_{exp}_trace.png"))
    return files


# -- the report ----------------------------------------------------------------------------------
def format_summary(rows: list[SummaryRow], truth_model: str | None = None) -> str:
    head = ("experiment", "quantity", "method", "estimate", "95 % interval", "truth", "error")
    lines = []
    for r in rows:
        scale, unit = (1e3, "ms") if r.quantity == "tau" else (1.0, r.unit)
        q = {"tau": "τ", "delta": "Δ"}.get(r.quantity, r.quantity)
        ci = (f"[{r.ci_low * scale:.4g}, {r.ci_high * scale:.4g}]"
              if math.isfinite(r.ci_low) and math.isfinite(r.ci_high) else "")
        lines.append((r.experiment, q, r.method, f"{r.estimate * scale:.4g} {unit}", ci,
                      f"{r.truth * scale:.4g}" if r.truth is not None else "",
                      f"{r.error_pct:+.1f} %" if r.error_pct is not None else ""))
    widths = [max(len(str(x[i])) for x in [head] + lines) for i in range(len(head))]
    fmt = lambda row: "  ".join(str(c).ljust(w) for c, w in zip(row, widths)).rstrip()
    text = [fmt(head), fmt(["-" * w for w in widths])] + [fmt(l) for l in lines]
    if truth_model:
        text.append("")
        text.append(f"truth: the emulator's model {truth_model}"
                    + ("; its reversal effect raises the gain after each reversal above g, so "
                       "transitional, relay and high-ω estimates exceed the model's g by design"
                       if "reversal" in truth_model else ""))
    return "\n".join(text)


def write_report(items: list[ReportInput], out_dir: str | Path, figures: bool = True) -> CampaignReport:
    """Write tables, figures and the summary of ``items`` into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = summarize(items)
    truths = [i.truth for i in items if i.truth]
    truth = truths[0] if truths else None
    g_true, tau_true = _truth_value(items, "g"), _truth_value(items, "tau")
    report = CampaignReport(out, rows, truth=truth,
                            failures=[(i.source, i.error) for i in items if i.error])
    portions, contrast = meander_rows(items)
    pf, rl = pfeedback_rows(items), relay_rows(items)
    report.tables.append(_write_csv(out / "summary.csv", [asdict(r) for r in rows]))
    for name, data in (("meander_portions", portions), ("meander_contrast", contrast),
                       ("pfeedback_grid", pf), ("relay_grid", rl)):
        if data:
            report.tables.append(_write_csv(out / f"{name}.csv", data))
    docs = [result_json(i.estimate) | {"source": i.source} if i.estimate else error_json(i.source, i.error)
            for i in items]
    (out / "estimates.json").write_text(json.dumps(docs, indent=1, allow_nan=False) + "\n")
    report.tables.append(out / "estimates.json")
    if figures:
        report.figures += meander_figures(portions, g_true, out)
        report.figures += pfeedback_figures(pf, g_true, out)
        report.figures += relay_figures(rl, g_true, tau_true, out)
        report.figures += trace_figures(items, out)
    text = [format_summary(rows, truth["model"] if truth else None)]
    if contrast:
        text += ["", "meander: transitional vs main gain by u0 (the contrast the paper found shrinking as u0 grows)"]
        text += [f"  u0 {c['u0_pct']:5.1f} %   main {c['g_main']:7.1f}   transitional {c['g_transitional']:7.1f}"
                 f"   ratio {c['ratio']:.2f}" for c in contrast]
    if report.failures:
        text += ["", f"{len(report.failures)} input(s) gave no estimate:"]
        text += [f"  {s}: {e}" for s, e in report.failures]
    report.text = "\n".join(text)
    (out / "summary.txt").write_text(report.text + "\n")
    return report


def report_campaign(campaign_dir: str | Path, out_dir: str | Path | None = None,
                    options: EstimateOptions | None = None, figures: bool = True) -> CampaignReport:
    """Estimate every run of a campaign directory and write its report (default: into it)."""
    campaign_dir = Path(campaign_dir)
    items = estimate_inputs([campaign_dir], options, keep_records=figures)
    return write_report(items, out_dir or campaign_dir, figures=figures)
