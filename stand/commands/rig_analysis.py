"""The rig's side of ``stand estimate`` and ``stand diagnose`` (many channels on one structure):
thin wrappers over :mod:`analysis.rig` and :mod:`analysis.diagnosis.rig`. Not a sub-command of
its own (no ``register``)."""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from analysis.diagnosis.rig import RigDiagnosis
    from analysis.rig.result import RigEstimate


def rig_inputs(paths: list[str]) -> bool:
    """True if the inputs are rig runs (all of them); a mix with one-channel inputs is refused."""
    from analysis.rig.load import is_rig_input
    from core.errors import ParameterError
    flags = [is_rig_input(p) for p in paths]
    if any(flags) and not all(flags):
        rig = [p for p, f in zip(paths, flags) if f]
        one = [p for p, f in zip(paths, flags) if not f]
        raise ParameterError(f"{', '.join(rig)} {'is a rig run' if len(rig) == 1 else 'are rig runs'}"
                             f" but {', '.join(one)} {'is' if len(one) == 1 else 'are'} not: give "
                             "the runs of one rig together, one-channel data apart")
    return bool(flags) and all(flags)


def load_rig_records(paths: list[str]) -> list:
    """The rig records of ``paths``, what loading changed said on stderr."""
    from analysis.rig.load import load_rig_inputs
    records = load_rig_inputs(paths)
    for rec in records:
        for note in rec.notes:
            print(f"note: {rec.source}: {note}", file=sys.stderr)
        for name, ch in zip(rec.names, rec.channels):
            for note in ch.notes:
                print(f"note: {rec.source} [{name}]: {note}", file=sys.stderr)
    return records


# ------------------------------------------------------------------------------------------
# stand estimate on rig runs
# ------------------------------------------------------------------------------------------
def main_estimate(args: argparse.Namespace) -> int:
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


# ------------------------------------------------------------------------------------------
# stand diagnose --rig-model
# ------------------------------------------------------------------------------------------
def main_diagnose(args: argparse.Namespace) -> int:
    from analysis.diagnosis.rig import diagnose_rig
    from analysis.executors import rig_executor
    from core.errors import ParameterError
    from plant.config import load_rig_model, rig_model_to_toml
    for opt in ("plots", "report"):
        if getattr(args, opt, None) is not None:
            raise ParameterError(f"--{opt} is for one channel's data; with --rig-model use --json "
                                 "or diagnose a channel's one-channel view")
    if args.rounds < 1 or args.rounds > 10:
        raise ParameterError(f"--rounds {args.rounds} is out of range: give 1 to 10")
    rig = load_rig_model(args.rig_model)
    records = load_rig_records(args.data)
    channels = None
    if args.channel:
        channels = [c.strip() for item in args.channel for c in item.split(",") if c.strip()]
        missing = [c for c in channels if c not in rig.names]
        if missing:
            raise ParameterError(f"--channel {', '.join(missing)}: the rig model {args.rig_model} "
                                 f"has channels {', '.join(rig.names)}")
    effects = ([e.strip() for e in args.candidates.split(",") if e.strip()]
               if args.candidates else None)
    names = channels or rig.names
    start = None
    if args.model != "rig":
        from analysis import resolve_model
        start, _ = resolve_model(args.model)

    def progress(msg: str) -> None:
        if not args.no_progress:
            print(f"diagnose: {msg}", file=sys.stderr, flush=True)

    with rig_executor(args.jobs, args.scheduler, tasks=len(names)) as ex:
        d = diagnose_rig(records, rig, channels, build_up=args.stepwise, start=start,
                         window_s=args.window_s, max_effects=args.max_effects, effects=effects,
                         executor=ex, rounds=args.rounds, progress=progress)
    saved = None
    if args.save:
        path = Path(args.save)
        verdicts = "; ".join(f"{c.name}: {c.verdict} ({c.spec})" for c in d.channels)
        header = (f"from {', '.join(Path(x).name for x in args.data)}: stand diagnose --rig-model "
                  f"{Path(args.rig_model).name}{' --stepwise' if args.stepwise else ''}, "
                  f"{d.rounds} round(s)\n{verdicts}")
        path.write_text(rig_model_to_toml(d.rig, header, path))
        saved = path
    if args.json:
        doc = d.to_dict()
        doc["saved"] = str(saved) if saved else None
        from .fit import print_json
        print_json(doc)
        return 0
    print(describe_diagnosis(d))
    if saved:
        print(f"rig model saved: {saved}")
    return 0


def describe_diagnosis(d: "RigDiagnosis") -> str:
    lines = [f"{len(d.channels)} channel(s) diagnosed with the coupling from the others in the "
             f"model, {d.rounds} round(s), {d.seconds:.1f} s"]
    lines.append(f"  {'channel':10s} {'verdict':24s} {'model':34s} {'g':>8s} {'τ ms':>7s} "
                 f"{'Δ kgf/s':>8s}  task s")
    for c in d.channels:
        p = c.params
        lines.append(f"  {c.name:10s} {c.verdict:24s} {c.spec:34s} {p['g']:8.4g} "
                     f"{p['tau'] * 1e3:7.3g} {p['delta']:8.3g}  {c.seconds:6.1f}")
    for c in d.channels:
        own = {k: v for k, v in c.params.items() if "." in k}
        lines.append("")
        lines.append(f"{c.name}: {c.summary}")
        if own:
            lines.append("  " + ", ".join(f"{k} = {v:.4g}" for k, v in own.items()))
        steps = c.detail.get("steps") if isinstance(c.detail, dict) else None
        for i, s in enumerate(steps or []):
            nxt = f"+{s['added']}: {s['why']}" if s.get("added") else s.get("why", "")
            lines.append(f"  {i:2d}  {s['model']:36s} RMSE {s['rmse']:8.4g} kgf  "
                         f"×floor {s['over_floor']:5.2f}  {nxt}")
    lines += [f"note: {n}" for n in d.notes]
    return "\n".join(lines)
