"""``stand fit DATA... --model M``: least-squares fit of a model on the windowed free-run error."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


from .common import add_effects, add_rig_channel, load_records


def add_data_args(p: argparse.ArgumentParser, model_required: bool = True,
                  channel: bool = True) -> None:
    """DATA, --model, --window-s, --effects: shared by fit, compare, diagnose and report;
    ``channel``: --channel NAME, the channel of a rig run to read (diagnose has its own)."""
    from analysis.defaults import WINDOW_S
    p.add_argument("data", nargs="+", metavar="DATA",
                   help=f"{data_help()}; several together are one data set")
    p.add_argument("--model", required=model_required, default=None if model_required else "base",
                   metavar="SPEC|FILE.toml",
                   help="a model spec like base+reversal+deadzone, or a TOML model file"
                        + ("" if model_required else " (default: %(default)s)"))
    p.add_argument("--window-s", type=float, default=WINDOW_S, metavar="S",
                   help="length of the free-run windows, s (default %(default)s)")
    if channel:
        add_rig_channel(p)
    add_effects(p)


def data_help() -> str:
    """What a DATA argument may be, as the help says it: the suffixes the readers take."""
    from analysis.defaults import TABLE_SUFFIXES
    from captures.formats import SUFFIXES
    return (f"tables of samples ({', '.join(TABLE_SUFFIXES)}: t,u,y[,r] in s, %%, kgf, or other names "
            "and units in the header, e.g. 'time [ms]', 'Усилие, кН'; docs/reference/tables.md), run "
            f"directories or bus captures ({', '.join(s for s in SUFFIXES if s != '.csv')}); any "
            "file may be gzipped (.gz)")


def check_window(args: argparse.Namespace) -> None:
    from gateway.errors import ParameterError
    if not (0.05 <= args.window_s <= 600):
        raise ParameterError(f"--window-s {args.window_s:g} is out of range: give 0.05 to 600 s")


def print_json(obj) -> None:
    from analysis.identification.compare import jsonable
    json.dump(jsonable(obj), sys.stdout, indent=2, allow_nan=False)
    sys.stdout.write("\n")


def register(sub) -> None:
    p = sub.add_parser("fit", help="fit a model to measurements (least squares, with intervals)",
                       description="Fit every parameter of a model (delay included) by least squares "
                                   "on the windowed free-run simulation error, with 95 % confidence "
                                   "intervals. A spec starts from grids of sensible values; a model "
                                   "file starts from its values.")
    add_data_args(p)
    p.add_argument("--fix", action="append", metavar="NAME", default=[],
                   help="hold a parameter at its given value (repeatable), e.g. --fix tau")
    p.add_argument("--save", metavar="FILE.toml", help="write the fitted model as a model file")
    p.add_argument("--json", action="store_true",
                   help='print {"model", "params", "metrics": {"rmse", "fit_percent", ...}, '
                        '"intervals"} as JSON')
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from analysis import Comparison, evaluate, fit_model, resolve_model
    from analysis.identification.compare import metrics_table, params_table
    from plant import model_to_toml
    check_window(args)
    records = load_records(args.data, args.channel)
    model, path = resolve_model(args.model)
    result = fit_model(records, model, window_s=args.window_s, fixed=args.fix)
    ev = evaluate(result.model, records, args.window_s)
    c = Comparison(result.model, ev, result, path or model.spec)
    if args.save:
        header = (f"fitted by `stand fit` to {', '.join(str(Path(d).name) for d in args.data)}\n"
                  f"windowed RMSE {ev.rmse:.4g} kgf, fit {ev.fit_percent:.2f} %")
        Path(args.save).write_text(model_to_toml(result.model, header, args.save))
    if args.json:
        print_json(c.to_dict())
        return 0
    print(f"model {result.model.spec} fitted to {len(records)} record(s), "
          f"{sum(len(r) for r in records):,} samples")
    print(params_table(c))
    for w in result.warnings:
        print(f"  note: {w}")
    print()
    print(metrics_table(c))
    if args.save:
        print(f"\nmodel file written: {args.save}")
    return 0
