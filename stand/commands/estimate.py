"""``stand estimate DATA...``: the paper's estimates of g and τ from recorded runs or CSV files;
on rig runs G, each channel's τ and Δ (a thin wrapper over :mod:`analysis.rig`)."""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from .common import load_rig_records, rig_inputs
from .fit import data_help

if TYPE_CHECKING:
    from analysis.reports.campaign import ReportInput
    from analysis.rig.result import RigEstimate


def register(sub) -> None:
    from analysis.defaults import EXPERIMENT_NAMES
    p = sub.add_parser(
        "estimate", help="estimate g and τ from meander, P-feedback or relay runs / CSV files",
        description="Estimate the paper's model parameters from recorded runs, campaign directories "
                    "or tables of samples (t,u,y[,r]; s, %, kgf). The experiment is read from the run's "
                    "metadata or recognised from the signals. --json prints one object per input "
                    "(schema hydrostand-estimate/1, see docs/experiments.md); --out writes the "
                    "tables, figures and summary a campaign gets.")
    p.add_argument("data", nargs="+", metavar="DATA",
                   help=f"campaign directories (their runs/*), {data_help()}; each is estimated on its own")
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
        "with t, u.NAME, y.NAME columns), all of them are one data set: G (kgf/(%·s)) with a "
        "95 % interval per entry, each channel's τ and Δ, the physical check. --json: "
        "{\"G\": rows, \"G_ci\": rows of [low, high], \"channels\", \"tau_s\", "
        "\"delta_kgf_s\", \"physical\", ...} (schema hydrostand-rig-estimate/1).")
    g.add_argument("--save", metavar="RIG_MODEL.toml",
                   help="write the rig model: G, and per channel the base model with τ, Δ and the "
                        "reversal boost found (what stand diagnose --rig-model starts from)")
    g.add_argument("--channel", metavar="NAME",
                   help="one channel of a rig run, read as a one-channel run: the paper's "
                        "estimates of that channel (instead of G)")
    g.add_argument("--guard-ms", type=float, metavar="MS",
                   help="time left out after every reversal (default: 4 times each channel's "
                        "transitional window, where its reversal boost has died out)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    if args.channel is None and rig_inputs(args.data):
        return main_rig(args)
    if args.save or args.guard_ms is not None:
        from core.errors import ParameterError
        raise ParameterError("--save and --guard-ms are for G from rig runs (a run directory with "
                             "a rig section, or t, u.NAME, y.NAME tables), not with --channel"
                             if args.channel else
                             "--save and --guard-ms are for rig runs (a run directory with a rig "
                             "section, or t, u.NAME, y.NAME tables); none was given")
    from analysis import EstimateOptions, error_json, result_json
    from analysis.reports.campaign import estimate_inputs, write_report
    options = EstimateOptions(
        experiment=args.experiment, hysteresis_kgf=args.hysteresis_kgf,
        control_period_s=args.period_ms / 1000.0 if args.period_ms else None,
        omega_rad_s=args.omega, gain=args.gain,
        transitional_s=args.transitional_ms / 1000.0 if args.transitional_ms else None)
    items = estimate_inputs(args.data, options, keep_records=bool(args.out), channel=args.channel)
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


# -- rig runs -----------------------------------------------------------------------------------
def main_rig(args: argparse.Namespace) -> int:
    """Rig runs, all of them one data set: G, each channel's τ and Δ, the physical check."""
    from analysis.rig.estimate import estimate_rig
    from core.errors import ParameterError
    if args.out or args.experiment not in (None, "meander"):
        raise ParameterError("rig runs are estimated from meanders, as one data set: --out and "
                             "--experiment other than meander are for one-channel inputs")
    guard = None
    if args.guard_ms is not None:
        if not 0 <= args.guard_ms <= 10_000:
            raise ParameterError(f"--guard-ms {args.guard_ms:g} is out of range: give 0 to 10000")
        guard = args.guard_ms / 1000.0
    records = load_rig_records(args.data)
    est = estimate_rig(records, guard_s=guard)
    saved = save_estimate(args, est) if args.save else None
    if args.json:
        doc = est.to_dict()
        doc["saved"] = str(saved) if saved else None
        print(json.dumps(doc, indent=2, allow_nan=False))
    else:
        print(describe_estimate(est, _truth(args.data)))
        if saved:
            print(f"rig model saved: {saved} (G, and per channel the base model with τ, Δ and "
                  "the reversal boost found; refine with stand diagnose --rig-model)")
    return 0


def save_estimate(args: argparse.Namespace, est: "RigEstimate") -> Path:
    from analysis.rig.result import starting_models
    from core.errors import DataError
    from plant.config import rig_model_to_toml
    unknown = [n for n, col in zip(est.names, est.G.T) if not all(map(math.isfinite, col))]
    if unknown:
        raise DataError(f"--save: the columns of {', '.join(unknown)} are unknown (no run moved "
                        "them): a rig model needs all of G; run a meander on each first")
    path = Path(args.save)
    header = (f"from {', '.join(Path(d).name for d in args.data)}: stand estimate ({est.design} "
              f"meanders)\nG's 95 % intervals: ±{_largest_half(est):.3g} kgf/(%·s) at most; "
              f"physical check: {est.physical.text}")
    path.write_text(rig_model_to_toml(starting_models(est), header, path))
    return path


def _largest_half(est: "RigEstimate") -> float:
    import numpy as np
    half = 0.5 * np.abs(est.G_ci[..., 1] - est.G_ci[..., 0])
    return float(np.nanmax(half)) if np.isfinite(half).any() else math.nan


def _truth(paths: list[str]) -> dict | None:
    """An emulated or synthetic run's truth.json (printed beside, never used)."""
    for p in paths:
        for f in [Path(p) / "truth.json", *sorted(Path(p).glob("*/truth.json"))] \
                if Path(p).is_dir() else []:
            try:
                doc = json.loads(f.read_text())
            except (OSError, ValueError):
                continue
            if isinstance(doc, dict) and "G" in doc:
                return doc
    return None


def _pm(value: float, ci) -> str:
    """``value ±half`` to the half-width's second significant digit."""
    lo, hi = ci
    if not math.isfinite(value):
        return "unknown"
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return f"{value:.4g}"
    half = 0.5 * (hi - lo)
    decimals = max(0, 1 - math.floor(math.log10(half)))
    return f"{value:.{decimals}f} ±{half:.{decimals}f}"


def describe_estimate(est: "RigEstimate", truth: dict | None = None) -> str:
    import numpy as np
    names = est.names
    width = max(18, max(len(n) for n in names) + 2)
    moving = ", ".join(f"{Path(src).name}: {', '.join(m) or 'none'}" for src, m in est.moving.items())
    lines = [f"rig estimate: {est.n} channels, {est.design} meanders ({moving})",
             f"G, kgf/(%·s), ±{100 * est.level:.0f} % intervals (row: the force's channel, "
             "column: the moving valve's; the diagonal is each channel's g):",
             " " * 12 + "".join(f"{n:>{width}s}" for n in names)]
    for i, n in enumerate(names):
        lines.append(f"  {n:10s}" + "".join(f"{_pm(est.G[i, j], est.G_ci[i, j]):>{width}s}"
                                            for j in range(est.n)))
    lines.append("")
    lines.append(f"  {'channel':10s} {'τ ms':>8s} {'[95 %]':>16s} {'Δ kgf/s':>18s} "
                 f"{'transitional':>13s} {'reversals':>9s} {'stretches':>9s} {'resid kgf':>9s}")
    for j, n in enumerate(names):
        tau = est.tau_s[j] * 1e3
        lo, hi = est.tau_ci_s[j] * 1e3
        tau_s = f"{tau:8.4g}" if math.isfinite(tau) else f"{'-':>8s}"
        ci = f"[{lo:.4g}, {hi:.4g}]" if math.isfinite(lo) else ""
        trans = (f"{est.transitional_s[j] * 1e3:.0f} ms" if est.transitional_detected[j]
                 else "none found" if math.isfinite(est.tau_s[j]) else "-")
        lines.append(f"  {n:10s} {tau_s} {ci:>16s} {_pm(est.delta_kgf_s[j], est.delta_ci[j]):>18s} "
                     f"{trans:>13s} {est.reversals[j]:9d} {est.stretches[j]:9d} "
                     f"{est.residual_kgf[j]:9.3g}")
    lines.append("")
    lines.append(f"physical check: {est.physical.text}")
    if truth is not None:
        try:
            order = [truth["channels"].index(n) for n in names]
            Gt = np.array(truth["G"], float)[np.ix_(order, order)]
            diag = np.minimum.outer(np.diag(Gt), np.diag(Gt))
            rel = np.abs(est.G - Gt) / diag
            worst = np.unravel_index(int(np.nanargmax(rel)), rel.shape)
            lines.append(f"truth (truth.json, not used): largest |G − G_true| is "
                         f"{100 * rel[worst]:.2g} % of the diagonal (G[{names[worst[0]]},"
                         f"{names[worst[1]]}] {est.G[worst]:.4g} for {Gt[worst]:.4g})")
        except (KeyError, ValueError, TypeError, IndexError):
            pass
    lines += [f"note: {n}" for n in est.notes]
    return "\n".join(lines)
