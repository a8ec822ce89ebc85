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
                                   "controller file for stand load. From a rig model file (stand "
                                   "estimate RIG_RUNS --save, stand diagnose --rig-model ... --save) or a "
                                   "rig file with a plant per channel: the rig's controller, feedforward "
                                   "through G^-1, a PI per channel decoupled through G^-1 diag(g), the "
                                   "margins of the loops together (characteristic loci) at the nominal and "
                                   "the boosted gains; a coupling too strong is refused with the figure.")
    p.add_argument("model", metavar="MODEL.toml", help="a model file (or a spec such as base+reversal), a "
                                                       "rig model file or a rig file")
    p.add_argument("-o", "--out", metavar="CONTROLLER.toml", help="write the controller file here")
    p.add_argument("--period-ms", type=float, default=2.0, metavar="MS",
                   help="control period the controller is for, ms (default %(default)s)")
    p.add_argument("--command-limit", type=float, default=100.0, metavar="PCT",
                   help="the controller's command limit, %% (default %(default)s)")
    g = p.add_argument_group("a rig (docs/loading.md, \"A rig\")")
    g.add_argument("--independent", action="store_true",
                   help="today's one-channel controller on every channel (each from its own g, no "
                        "decoupling): the baseline to compare with")
    g.add_argument("--coupling-error", type=float, default=20.0, metavar="PCT",
                   help="the margins hold with the rig's coupling this much off the model's "
                        "(each off-diagonal entry of G, %%; default %(default)s)")
    p.add_argument("--json", action="store_true", help="print the design as JSON")
    add_effects(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from loading.controller_files import is_rig_file, read_rig_model
    from loading.design import design
    rig = is_rig_file(args.model)
    if rig:
        model, source = read_rig_model(args.model)
    else:
        if args.independent or args.coupling_error != 20.0:
            from core.errors import ParameterError
            raise ParameterError("--independent and --coupling-error are for a rig: give a rig model file "
                                 "(stand estimate RIG_RUNS --save) or a rig file")
        from analysis import resolve_model
        model, source = resolve_model(args.model, complete=True)[0], None
    c = design(model, args.period_ms / 1e3, args.command_limit,
               feedback="independent" if args.independent else "decoupled",
               coupling_error=args.coupling_error / 100)
    if args.out:
        Path(args.out).write_text(c.to_toml(args.out))
    if args.json:
        json.dump({**c.to_dict(), **({"model": source} if rig else {})}, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    if rig:
        print(f"from {source}")
    print(c.text())
    if args.out:
        print(f"{'rig controller' if rig else 'controller'} file written: {args.out}")
    return 0
