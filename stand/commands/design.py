"""``stand design MODEL``: a force controller from an identified model (loading.design)."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .common import add_effects


def register(sub) -> None:
    p = sub.add_parser("design", help="design a force controller from a fitted model",
                       description="From a fitted model file (stand fit --save, stand diagnose "
                                   "--stepwise --save): feedforward through the model's inverse and a "
                                   "PI feedback with gain margin >= 2 at the largest gain the model "
                                   "predicts (right after a reversal) and phase margin >= 45 degrees. "
                                   "Prints the margins at the nominal and the boosted gain; writes a "
                                   "controller file for stand load.")
    p.add_argument("model", metavar="MODEL.toml", help="a model file (or a spec such as base+reversal)")
    p.add_argument("-o", "--out", metavar="CONTROLLER.toml", help="write the controller file here")
    p.add_argument("--period-ms", type=float, default=2.0, metavar="MS",
                   help="control period the controller is for, ms (default %(default)s)")
    p.add_argument("--command-limit", type=float, default=100.0, metavar="PCT",
                   help="the controller's command limit, %% (default %(default)s)")
    p.add_argument("--json", action="store_true", help="print the design as JSON")
    add_effects(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from analysis import resolve_model
    from loading.design import design
    model, _path = resolve_model(args.model, complete=True)
    c = design(model, args.period_ms / 1e3, args.command_limit)
    if args.out:
        Path(args.out).write_text(c.to_toml(args.out))
    if args.json:
        json.dump(c.to_dict(), sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    print(c.text())
    if args.out:
        print(f"controller file written: {args.out}")
    return 0
