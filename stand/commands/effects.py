"""``stand effects``: the catalogue of plant effects with their parameters."""
from __future__ import annotations

import argparse
import inspect


from .fit import print_json


def register(sub) -> None:
    p = sub.add_parser("effects", help="list the catalogue of plant effects and their parameters",
                       description="The base model and every effect of the catalogue: what it "
                                   "models, its equation, its parameters with units and bounds.")
    p.add_argument("--json", action="store_true", help="machine-readable listing")
    p.add_argument("--doc", action="store_true", help="print each effect's full documentation")
    p.set_defaults(func=main)


def _param(p) -> dict:
    return {"name": p.name, "default": p.default, "lower": p.lower, "upper": p.upper,
            "unit": p.unit, "doc": p.doc, "log": p.log}


def main(args: argparse.Namespace) -> int:
    from plant import BASE_PARAMS, CATALOGUE
    rows = [{"effect": "base", "summary": "dy/dt = g·u(t − τ) + Δ (paper eq. 1 with the trend of eq. 2)",
             "stage": "-", "diagnosable": True, "params": [_param(p) for p in BASE_PARAMS],
             "doc": ""}]
    for name, cls in CATALOGUE.items():
        rows.append({"effect": name, "summary": cls.summary, "stage": cls.stage.name.lower(),
                     "diagnosable": cls.diagnosable, "params": [_param(p) for p in cls.params],
                     "doc": inspect.cleandoc(cls.__doc__ or "")})
    if args.json:
        print_json(rows)
        return 0
    for row in rows:
        flag = "" if row["diagnosable"] else "   (not offered by `stand diagnose`)"
        print(f"{row['effect']}: {row['summary']}{flag}")
        for p in row["params"]:
            name = p["name"] if row["effect"] == "base" else f"{row['effect']}.{p['name']}"
            print(f"    {name:28s} {p['doc']}, {p['unit']}; default {p['default']:g}, "
                  f"bounds [{p['lower']:g}, {p['upper']:g}]" + (", fitted in log scale" if p["log"] else ""))
        if args.doc and row["doc"]:
            print("\n".join("      " + line for line in row["doc"].splitlines()))
        print()
    print("Models are written base+effect+effect (e.g. --model base+reversal+lag) or as a TOML model "
          "file; parameters as NAME or EFFECT.NAME.")
    return 0
