"""``stand effects``: the catalogue of plant effects and the plug-ins loaded, with their
parameters; ``--new NAME --stage STAGE`` prints a plug-in to start from."""
from __future__ import annotations

import argparse
import inspect

from .common import add_effects
from .fit import print_json

STAGES = ("valve", "flow", "disturbance", "force", "sensor")


def register(sub) -> None:
    p = sub.add_parser("effects", help="list the plant effects (catalogue and plug-ins), or start a new one",
                       description="The base model and every effect of the catalogue and of the "
                                   "plug-ins loaded (--effects, installed packages): what it "
                                   "models, its equation, its parameters with units and bounds, "
                                   "where it came from. With --new, print a commented plug-in "
                                   "to start an effect of your own from.")
    p.add_argument("--json", action="store_true", help="machine-readable listing")
    p.add_argument("--doc", action="store_true", help="print each effect's full documentation")
    p.add_argument("--new", metavar="NAME",
                   help="print the skeleton of a plug-in effect NAME (redirect it to NAME.py)")
    p.add_argument("--stage", choices=STAGES, default="flow",
                   help="with --new: where it acts: valve (maps the command to the flow "
                        "command), flow (a factor on the gain), disturbance (a force rate in "
                        "time), force (a force rate depending on the force), sensor (filters "
                        "the reading) (default %(default)s)")
    add_effects(p)
    p.set_defaults(func=main)


def _param(p) -> dict:
    return {"name": p.name, "default": p.default, "lower": p.lower, "upper": p.upper,
            "unit": p.unit, "doc": p.doc, "log": p.log}


def main(args: argparse.Namespace) -> int:
    if args.new is not None:
        from plant.skeleton import skeleton
        print(skeleton(args.new, args.stage), end="")
        return 0
    from plant import BASE_PARAMS, CATALOGUE
    from plant.catalogue import order
    from plant.plugins import origin
    rows = [{"effect": "base", "summary": "dy/dt = g·u(t − τ) + Δ (paper eq. 1 with the trend of eq. 2)",
             "stage": "-", "diagnosable": True, "origin": "catalogue",
             "params": [_param(p) for p in BASE_PARAMS], "look_alikes": {}, "doc": ""}]
    for name, cls in sorted(CATALOGUE.items(), key=lambda kv: order(kv[0])):
        rows.append({"effect": name, "summary": cls.summary, "stage": cls.stage.name.lower(),
                     "diagnosable": cls.diagnosable, "origin": origin(name),
                     "params": [_param(p) for p in cls.params],
                     "look_alikes": dict(cls.look_alikes),
                     "doc": inspect.cleandoc(cls.__doc__ or "")})
    if args.json:
        print_json(rows)
        return 0
    for row in rows:
        flag = "" if row["diagnosable"] else "   (not offered by `stand diagnose`)"
        source = "" if row["origin"] == "catalogue" else f"   [plug-in: {row['origin']}]"
        print(f"{row['effect']}: {row['summary']}{flag}{source}")
        for p in row["params"]:
            name = p["name"] if row["effect"] == "base" else f"{row['effect']}.{p['name']}"
            print(f"    {name:28s} {p['doc']}, {p['unit']}; default {p['default']:g}, "
                  f"bounds [{p['lower']:g}, {p['upper']:g}]" + (", fitted in log scale" if p["log"] else ""))
        if args.doc and row["doc"]:
            print("\n".join("      " + line for line in row["doc"].splitlines()))
        if args.doc and row["look_alikes"]:
            print("      told apart from:")
            for other, how in row["look_alikes"].items():
                print(f"        {other}: {how}")
        print()
    print("Models are written base+effect+effect (e.g. --model base+reversal+lag) or as a TOML model "
          "file; parameters as NAME or EFFECT.NAME. An effect of your own: `stand effects --new "
          "NAME --stage STAGE > NAME.py`, then --effects NAME.py (docs/your-own-effect.md).")
    return 0
