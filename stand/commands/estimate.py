"""``stand estimate DATA...``: the paper's estimates of g and τ from recorded runs or CSV files;
on rig runs G, each channel's τ and Δ (:mod:`stand.commands.rig_analysis`)."""
from __future__ import annotations

import argparse
import json
import math
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from analysis.reports.campaign import ReportInput



def register(sub) -> None:
    from analysis.defaults import EXPERIMENT_NAMES
    p = sub.add_parser(
        "estimate", help="estimate g and τ from meander, P-feedback or relay runs / CSV files",
        description="Estimate the paper's model parameters from recorded runs, campaign directories "
                    "or tables of samples (t,u,y[,r]; s, %, kgf). The experiment is read from the run's "
                    "metadata or recognised from the signals. --json prints one object per input "
                    "(schema hydrostand-estimate/1, see docs/experiments.md); --out writes the "
                    "tables, figures and summary a campaign gets.")
    p.add_argument("data", nargs="+", metavar="DATA", help="run directory, campaign directory or CSV file")
    p.add_argument("--json", action="store_true", help="print a JSON array, one object per input")
    p.add_argument("--out", metavar="DIR", help="also write the report (tables, figures, summary) here")
    p.add_argument("--experiment", choices=EXPERIMENT_NAMES, help="do not detect: treat every input as this")
    p.add_argument("--hysteresis-kgf", type=float, metavar="EPS", help="relay hysteresis ε (default: from the run, else 0)")
    p.add_argument("--period-ms", type=float, metavar="T",
                   help="control period (default: from the run, else the CSV's sampling interval)")
    p.add_argument("--omega", type=float, metavar="RAD_S", help="P feedback: ω (default: from the run, else fitted on r)")
    p.add_argument("--gain", type=float, metavar="K", help="P feedback: k, %%/kgf (default: from the run, else fitted)")
    p.add_argument("--transitional-ms", type=float, metavar="MS",
                   help="meander: transitional window after each reversal (default: detected)")
    g = p.add_argument_group(
        "rig runs (many channels on one structure: per-column meanders, or one simultaneous "
        "meander with a period per channel; see docs/rig.md)",
        "Given rig runs (a run directory with a rig section, a directory of them, or a table "
        "with t, u.NAME, y.NAME columns), all of them are one data set: G (kgf/(%%·s)) with a "
        "95 %% interval per entry, each channel's τ and Δ, the physical check. --json: "
        "{\"G\": rows, \"G_ci\": rows of [low, high], \"channels\", \"tau_s\", "
        "\"delta_kgf_s\", \"physical\", ...} (schema hydrostand-rig-estimate/1).")
    g.add_argument("--save", metavar="RIG_MODEL.toml",
                   help="write the rig model: G, and per channel the base model with τ, Δ and the "
                        "reversal boost found (what stand diagnose --rig-model starts from)")
    g.add_argument("--guard-ms", type=float, metavar="MS",
                   help="time left out after every reversal (default: 4 times each channel's "
                        "transitional window, where its reversal boost has died out)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from .rig_analysis import main_estimate, rig_inputs
    if rig_inputs(args.data):
        return main_estimate(args)
    if args.save or args.guard_ms is not None:
        from core.errors import ParameterError
        raise ParameterError("--save and --guard-ms are for rig runs (a run directory with a rig "
                             "section, or t, u.NAME, y.NAME tables); none was given")
    from analysis import EstimateOptions, error_json, result_json
    from analysis.reports.campaign import estimate_inputs, write_report
    options = EstimateOptions(
        experiment=args.experiment, hysteresis_kgf=args.hysteresis_kgf,
        control_period_s=args.period_ms / 1000.0 if args.period_ms else None,
        omega_rad_s=args.omega, gain=args.gain,
        transitional_s=args.transitional_ms / 1000.0 if args.transitional_ms else None)
    items = estimate_inputs(args.data, options, keep_records=bool(args.out))
    if args.json:
        docs = [result_json(i.estimate) | {"source": i.source} if i.estimate else error_json(i.source, i.error)
                for i in items]
        print(json.dumps(docs, indent=2, allow_nan=False))
    else:
        for i in items:
            print(describe(i))
    if args.out:
        report = write_report(items, args.out)
        print(f"report: {args.out}/ ({len(report.tables)} tables, {len(report.figures)} figures)",
              file=sys.stderr if args.json else sys.stdout)
    failed = [i for i in items if i.error]
    for i in failed:
        print(f"stand estimate: error: {i.error}", file=sys.stderr)
    return 2 if failed else 0


def _ci(ci, scale: float = 1.0) -> str:
    lo, hi = ci
    return f"[{lo * scale:.4g}, {hi * scale:.4g}]" if math.isfinite(lo) and math.isfinite(hi) else ""


def describe(item: "ReportInput") -> str:
    """A few lines per input: the recommended estimates, the paper's formulas, warnings."""
    from analysis import MeanderEstimate, PFeedbackEstimate, RelayEstimate
    if item.estimate is None:
        return f"{item.source}: no estimate"
    est = item.estimate
    r = est.result
    truth = (item.truth or {}).get("params") or {}
    beside = lambda key, scale=1.0: f"   truth {truth[key] * scale:.4g}" if key in truth else ""
    lines = [f"{item.source}: {est.experiment} ({est.detection.reason})"]
    if isinstance(r, RelayEstimate):
        lines += [
            f"  g = {r.g:.4g} kgf/(%·s) {_ci(r.g_ci)}  exact limit cycle 4A/(u0·P), recommended{beside('g')}",
            f"  τ = {r.tau * 1e3:.4g} ms {_ci(r.tau_ci, 1e3)}  exact P/4 − T/2 (T/2 = {r.sampling_correction_s * 1e3:g} ms "
            f"for the sampling){beside('tau', 1e3)}",
            f"  eq. (4): g = {r.g_df_peak:.4g} with the peak A (biased: ×{r.df_bias:.3f} of the exact), "
            f"g = {r.g_df_harmonic:.4g} with the first harmonic, τ = {r.tau_df * 1e3:.4g} ms",
            f"  u0 = {r.amplitude_pct:.4g} %, r = {r.reference_kgf:.4g} kgf, P = {r.period_s * 1e3:.4g} ms, "
            f"A = {r.peak_kgf:.4g} kgf, {r.cycles} cycles"]
    elif isinstance(r, PFeedbackEstimate):
        tau = f"{r.tau * 1e3:.4g} ms" if r.tau is not None else "none"
        lines += [
            f"  g = {r.g:.4g} kgf/(%·s) {_ci(r.g_ci)}  eq. (3) A_y·ω/A_u{beside('g')}",
            f"  τ (phase) = {tau}{beside('tau', 1e3)}",
            f"  ω = {r.omega_rad_s:.4g} rad/s, A_r = {r.reference_kgf:.4g} kgf, k = {r.gain:.4g} %/kgf, "
            f"A_u = {r.amplitude_u_pct:.4g} %, A_y = {r.amplitude_y_kgf:.4g} kgf, {r.periods} stationary "
            f"period(s) from {r.stationary_from_s:.1f} s"]
    elif isinstance(r, MeanderEstimate):
        lines += [f"  g = {r.g:.4g} kgf/(%·s) {_ci(r.g_ci)}  eq. (2), main portions{beside('g')}",
                  f"  Δ = {r.delta:.4g} kgf/s{beside('delta')}"
                  + (f", τ (rough) = {r.tau * 1e3:.4g} ms" if r.tau else ""),
                  f"  transitional window {r.transitional_s * 1e3:.0f} ms "
                  f"({'detected' if r.transitional_detected else 'nominal: no excess slope found'})"]
        for p in r.portions:
            lines.append(f"    u0 {p.amplitude_pct:5.3g} %  {p.portion:18s} g = {p.g:7.4g} {_ci((p.ci_low, p.ci_high))}")
    lines += [f"  warning: {w}" for w in r.warnings]
    lines += [f"  note: {n}" for n in est.notes]
    return "\n".join(lines)
