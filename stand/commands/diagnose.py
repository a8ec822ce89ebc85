"""``stand diagnose DATA...``: which catalogue effect does the model miss?"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tqdm import tqdm

from analysis import plots
from analysis.compare import resolve_model
from analysis.data import load_all
from analysis.diagnose import diagnosable_effects, diagnose

from .compare import default_out
from .fit import add_data_args, check_window, print_json


def register(sub) -> None:
    p = sub.add_parser("diagnose", help="find the effect the model is missing (or say it is adequate)",
                       description="Fit the model (default: the paper's base model), then add every "
                                   "diagnosable catalogue effect in turn, refit, and rank them by how "
                                   "much they lower the windowed error. Verdict: adequate, "
                                   "missing_effect (the best one) or unexplained (structure no effect "
                                   "removes, described), with the residual pattern in plain words and "
                                   "warnings when the data cannot separate two explanations.")
    add_data_args(p, model_required=False)
    p.add_argument("--effects", metavar="A,B,...",
                   help="only try these effects (default: every diagnosable one not in the model)")
    p.add_argument("--plots", metavar="DIR", nargs="?", const="",
                   help="also write plots (default directory diagnose-<data>)")
    p.add_argument("--json", action="store_true",
                   help='print {"verdict", "base": {"rmse", ...}, "candidates": [{"effect", "rmse", '
                        '"improvement", ...}], "unexplained": {...} or null, ...} as JSON')
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    check_window(args)
    records = load_all(args.data)
    model, _ = resolve_model(args.model)
    effects = [e.strip() for e in args.effects.split(",") if e.strip()] if args.effects else None
    total = 1 + len(effects if effects is not None else diagnosable_effects(model))
    bar = None if args.no_progress else tqdm(total=total, desc="diagnose", unit="model",
                                             file=sys.stderr, leave=False)

    def progress(msg: str) -> None:
        if bar is not None and not msg.startswith("refitting"):
            bar.set_postfix_str(msg)
            bar.update(1)

    try:
        d = diagnose(records, model, window_s=args.window_s, effects=effects, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    files = []
    if args.plots is not None:
        out = Path(args.plots) if args.plots else default_out(args.data, "diagnose")
        out.mkdir(parents=True, exist_ok=True)
        files.append(plots.plot_candidates(d, out / "candidates.png"))
        files.append(plots.plot_overlay(d.base_eval, out / "overlay_start_model.png"))
        files.append(plots.plot_regimes(d.base_eval, out / "regimes_start_model.png"))
    if args.json:
        out = d.to_dict()
        out["plots"] = [str(f) for f in files]
        print_json(out)
        return 0
    print(f"verdict: {d.verdict.upper()}")
    print(f"  {d.summary}")
    print()
    print(f"{'model':32s} {'RMSE kgf':>9s} {'change':>8s} {'of excess':>9s}  earns")
    print(f"{d.base_fit.model.spec:32s} {d.base_eval.rmse:9.4g} {'':>8s} {'':>9s}")
    for c in d.candidates:
        mark = "yes" if c.earns else "no"
        print(f"{'+' + c.effect:32s} {c.rmse:9.4g} {-100 * c.rmse_reduction:+7.1f}% "
              f"{100 * max(-9.99, c.excess_share):8.0f}%  {mark}{'  <- best' if c.effect == d.best else ''}")
    print(f"(noise floor {d.base_eval.noise_floor:.3g} kgf, σ = {d.noise_sigma:.3g} kgf; candidates "
          f"judged on the error with re-estimated window starts)")
    if d.screening["subset"]:
        print(f"(screened on {d.screening['windows_screened']} of {d.screening['windows_total']} windows; "
              f"refitted on all: {', '.join(d.screening['refit_on_all'])}; the others keep their "
              f"screening fit and are compared with the starting model fitted on the same windows)")
    best = d.best_candidate
    if best is not None:
        print()
        print(f"fitted {best.spec}: " + ", ".join(f"{k} = {v:.4g}" for k, v in best.params.items()))
    print()
    print("what the residual of " + d.base_fit.model.spec + " shows:")
    for o in d.observations:
        print(f"  - {o}")
    if d.unexplained:
        print(f"  - unexplained: {d.unexplained.description}")
    if d.ambiguities:
        print()
        print("what these data cannot tell:")
        for a in d.ambiguities:
            print(f"  - {a.text()}")
    for w in d.warnings:
        print(f"note: {w}")
    if files:
        print("\nplots: " + ", ".join(str(f) for f in files))
    return 0
