"""``stand compare DATA... --model M``: the model against the measurements, in numbers and plots."""
from __future__ import annotations

import argparse
from pathlib import Path


from .common import load_records
from .fit import add_data_args, check_window, print_json


def register(sub) -> None:
    p = sub.add_parser("compare", help="compare a model with measurements: error table and plots",
                       description="Fit the model (a spec, or a model file as the start; --as-given "
                                   "keeps the file's values), simulate it free-running over windows "
                                   "started from the measured force, print RMSE and fit % overall, "
                                   "per regime and per window, the residual tests, and write plots: "
                                   "measurement and model overlaid, residual below, worst windows "
                                   "and regimes marked.")
    add_data_args(p)
    p.add_argument("--as-given", action="store_true",
                   help="use the model's parameter values as they are (no fit)")
    p.add_argument("--out", metavar="DIR", help="directory for the plots (default compare-<data>)")
    p.add_argument("--no-plots", action="store_true", help="numbers only")
    p.add_argument("--json", action="store_true",
                   help='print {"model", "params", "metrics": {...}, "regimes", "windows", ...} as JSON')
    p.set_defaults(func=main)


def default_out(data: list[str], prefix: str) -> Path:
    stem = Path(str(data[0]).rstrip("/")).name.replace(".csv", "") or "data"
    return Path(f"{prefix}-{stem}")


def main(args: argparse.Namespace) -> int:
    from analysis import compare
    from analysis.identification.compare import metrics_table, params_table
    from analysis.reports import plots
    check_window(args)
    records = load_records(args.data, getattr(args, "channel", None))
    c = compare(records, args.model, window_s=args.window_s, fit=not args.as_given)
    files = []
    if not args.no_plots:
        out = Path(args.out) if args.out else default_out(args.data, "compare")
        out.mkdir(parents=True, exist_ok=True)
        files = [plots.plot_overlay(c.evaluation, out / "overlay.png"),
                 plots.plot_regimes(c.evaluation, out / "regimes.png"),
                 plots.plot_correlations(c.evaluation, out / "correlations.png")]
    if args.json:
        d = c.to_dict(full=True)
        d["plots"] = [str(f) for f in files]
        print_json(d)
        return 0
    print(f"model {c.model.spec} ({'fitted' if c.fit else 'as given'}) on {len(records)} record(s)")
    print(params_table(c))
    print()
    print(metrics_table(c))
    if files:
        print("\nplots: " + ", ".join(str(f) for f in files))
    return 0
