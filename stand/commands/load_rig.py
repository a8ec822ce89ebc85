"""The rig's side of ``stand load`` (``--rig RIG.toml``): every channel of a rig loaded at once by
the rig's controller, pass by pass (a thin wrapper over :func:`gateway.rig_load.run_rig_load`).
Not a sub-command of its own (no ``register``)."""
from __future__ import annotations

import argparse
import json
import sys

from core.errors import ParameterError

#: one-channel options that have no rig form yet, and what each is
NOT_FOR_A_RIG = (("plan", "--plan"), ("accuracy", "--accuracy"), ("fastest", "--fastest"),
                 ("schedule", "--schedule"))


def _refuse_one_channel_options(args: argparse.Namespace) -> None:
    given = [flag for attr, flag in NOT_FOR_A_RIG if getattr(args, attr, None)]
    if getattr(args, "pacing", "off") != "off":
        given.append("--pacing")
    if getattr(args, "gain", "off") != "off":
        given.append("--gain")
    if given:
        raise ParameterError(f"{', '.join(given)}: not available with --rig yet (a rig's programme "
                             "runs at its --rate or --frequency, with peak/valley compensation per "
                             "channel); leave them out")


def main(args: argparse.Namespace) -> int:
    from gateway import Gateway
    from gateway.rig_load import check_rig_load, run_rig_load
    from loading.rig_compensation import RigCompensation
    from loading.rig_design import load_rig_controller
    from loading.rig_programme import load_rig_programme

    from .common import gateway_config, sigterm_as_interrupt
    _refuse_one_channel_options(args)
    if not args.out:
        raise ParameterError("give --out DIR for the passes and the report")
    config = gateway_config(args)
    rig = config.rig
    controller = load_rig_controller(args.controller, config.period_s, rig.names)
    programme = load_rig_programme(args.program, rig.names, config.period_s, args.rate, args.frequency)
    repeat = args.repeat if args.repeat is not None else 1
    comp = RigCompensation.load(args.compensation, rig.names) if args.compensation else None
    # everything that can be refused is refused before the rig is touched
    check_rig_load(config, programme, controller, comp, args.unload_to)
    if not (1 <= repeat <= 1000):
        raise ParameterError(f"--repeat {repeat}: it must be from 1 to 1000")
    with sigterm_as_interrupt():
        with Gateway(config) as gw:
            result = run_rig_load(gw, programme, controller, args.out, repeat, comp,
                                  learn=not args.no_learn, unload_kgf=args.unload_to,
                                  progress=False if args.no_progress else None)
    if args.json:
        json.dump(result.summary(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        for i, p in enumerate(result.passes, start=1):
            f = p.figures()
            pv = f["peak_valley_error_pct"]
            ratio = p.ratio_error_pct
            print(f"pass {i}: worst channel {p.worst_channel}: peak/valley error p95 {pv['p95']:.2f} %, "
                  f"max {pv['max']:.2f} %; extra cycles (all channels) "
                  f"{sum(r.extra_cycles for r in p.channels):g}"
                  + (f"; ratio error {ratio:.2f} %" if ratio is not None else ""))
        if result.passes:
            print(result.passes[-1].text())
        print(f"-> {result.out} (report.txt, report.json, tracking.png, compensation.toml, pass-N/)")
    if result.end_reason not in (None, "complete"):
        print(f"stand load: stopped ({result.end_reason}): {result.end_message}", file=sys.stderr)
        return 1
    return 0
