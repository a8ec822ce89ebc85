"""``stand report DATA... --model M``: add a model version to the data set's history, write the HTML page."""
from __future__ import annotations

import argparse

from core.errors import ParameterError

from .compare import default_out
from .common import load_records
from .fit import add_data_args, check_window


def register(sub) -> None:
    p = sub.add_parser("report", help="keep a data set's model history; HTML report of the error falling "
                                      "(or of a loading test)",
                       description="Fit the model (a spec, or a model file you edit; --as-given keeps "
                                   "the file's values), add it as the next version to OUT/history.json "
                                   "and rewrite OUT/report.html: the error of every version so far, "
                                   "and the plots, parameters and regimes of the latest. The page is "
                                   "self-contained (images embedded, no network). Given the directory "
                                   "of a `stand load` (no --model), its page instead: the passes' "
                                   "figures, the tracking and the stand's g through the test "
                                   "(LOAD_DIR/report.html, gain.png).")
    add_data_args(p)
    model = next(a for a in p._actions if "--model" in a.option_strings)
    model.required = False
    p.add_argument("--out", metavar="DIR", help="report directory (default report-<data>)")
    p.add_argument("--as-given", action="store_true", help="use the model's values as they are (no fit)")
    p.add_argument("--diagnose", action="store_true",
                   help="also diagnose what the latest model still misses (slower)")
    p.add_argument("--new-history", action="store_true",
                   help="start the history in OUT over (e.g. for a different data set)")
    p.add_argument("--title", help="title of the page (default: the data files)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from loading.load_page import is_load_dir, write_load_page
    if len(args.data) == 1 and is_load_dir(args.data[0]) and args.model is None:
        page = write_load_page(args.data[0], args.title)
        print(f"report: {page}")
        return 0
    if args.model is None:
        raise ParameterError("give --model SPEC|FILE.toml (the model to fit and add to the history), "
                             "or one directory written by stand load for its page")
    from analysis import diagnose, write_report
    check_window(args)
    records = load_records(args.data, getattr(args, "channel", None))
    out = args.out or default_out(args.data, "report")
    d = None
    res = write_report(records, args.model, out, fit=not args.as_given, window_s=args.window_s,
                       new_history=args.new_history, title=args.title)
    if args.diagnose:
        d = diagnose(records, res.comparison.model, window_s=args.window_s)
        res = write_report(records, res.comparison.model, out, fit=False, window_s=args.window_s,
                           diagnosis=d, title=args.title)
    versions = res.history["versions"]
    print(f"{'version':8s} {'model':36s} {'RMSE kgf':>9s} {'fit %':>7s}")
    for v in versions:
        print(f"v{v['version']:<7d} {v['model']:36s} {v['metrics']['rmse']:9.4g} {v['metrics']['fit_percent']:7.2f}")
    if d is not None:
        print(f"\ndiagnosis of v{versions[-1]['version']}: {d.summary}")
    print(f"\nreport: {res.path}  (history: {res.history_path})")
    return 0
