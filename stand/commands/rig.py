"""``stand rig ACTION RIG.toml``: a rig of many loading channels (docs/rig.md).

``stand rig check RIG.toml [--json]``: the rig (buses, channels, structure), each bus's load,
and every problem found before anything moves (:func:`rig.check.check_rig`); exit 1 when
there is one.
"""
from __future__ import annotations

import argparse


def register(sub) -> None:
    p = sub.add_parser("rig", help="a rig of many loading channels: check its file",
                       description="A rig: loading channels (a valve and a dynamometer each) on "
                                   "one or more CAN buses, coupled by the structure they load "
                                   "(docs/rig.md).")
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    check = actions.add_parser(
        "check", help="check a rig file: buses, channels, structure, bus load, problems",
        description="Print the rig (buses with spec, bit rate and CAN FD; channels with their "
                    "bus, node ids, range, force limit and emulated plant), the structure G "
                    "with whether a symmetric positive definite stiffness can give it, each "
                    "bus's worst-case load against the rig's limit, and every problem found. "
                    "Exit status 1 when there is a problem, 0 when none, 2 when the file "
                    "cannot be read.")
    check.add_argument("rig", metavar="RIG.toml", help="the rig file (format: docs/rig.md)")
    check.add_argument("--json", action="store_true",
                       help="machine-readable: rig, buses (name, load_pct, bitrate, channels, "
                            "...), channels, structure, problems, notes")
    check.set_defaults(func=check_main)


def check_main(args: argparse.Namespace) -> int:
    from rig.check import check_rig
    from rig.config import load_rig_file
    result = check_rig(load_rig_file(args.rig))
    if args.json:
        from .fit import print_json
        print_json(result.to_dict())
    else:
        print(result.text())
    return 0 if result.ok else 1
