"""``stand load PROGRAM --controller C --out RUN``: a loading programme on the stand, tracked by
the designed controller, with peak/valley compensation learning over passes (gateway.load)."""
from __future__ import annotations

import argparse
import json
import signal
import sys

from core.errors import ParameterError

from .common import add_effects, add_gateway, gateway_config

#: loading.pacing.PACING_MODES, written out: `stand --help` imports no numerics
PACING_MODES = ("off", "static", "dynamic")


def register(sub) -> None:
    p = sub.add_parser("load", help="run a loading programme with the designed controller",
                       description="Apply a loading programme through the gateway (same supervisor, "
                                   "limits, recorder and run directories as stand run): the force is "
                                   "brought to the first level, the programme is tracked by the "
                                   "controller (feedforward through the model's inverse + PI), then "
                                   "unloaded. PROGRAM: a turning-point CSV (column 'level', kgf), a time "
                                   "history CSV ('t,r'), a block programme (.toml with [[block]] mean, "
                                   "amplitude, frequency, cycles) or "
                                   "sine:mean=KGF,amplitude=KGF,frequency=HZ,cycles=N.")
    p.add_argument("program", metavar="PROGRAM", help="the loading programme")
    p.add_argument("--controller", required=True, metavar="CONTROLLER.toml",
                   help="a controller file written by stand design")
    p.add_argument("--out", metavar="DIR", help="directory for the passes and the report (required "
                                                 "unless --plan)")
    p.add_argument("--plan", action="store_true",
                   help="print the programme's time beside its valve-limited minimum (every "
                        "segment at the largest rate the controller's model says the valve can "
                        "deliver) and exit; the stand is not touched")
    p.add_argument("--repeat", type=int, default=None, metavar="N",
                   help="run the programme N times in a row, learning the peak/valley corrections "
                        "between passes (default 1)")
    p.add_argument("--rate", type=float, metavar="KGF_PER_S",
                   help="turning-point sequence: peak rate of the haversines between points, kgf/s")
    p.add_argument("--frequency", type=float, metavar="HZ",
                   help="turning-point sequence: one half cycle per 1/(2 HZ) instead of --rate")
    p.add_argument("--compensation", metavar="FILE.toml",
                   help="start from peak/valley corrections learned before (compensation.toml of "
                        "an earlier stand load)")
    p.add_argument("--no-learn", action="store_true", help="keep the corrections as they are")
    g = p.add_argument_group("null pacing (docs/loading.md)")
    g.add_argument("--pacing", choices=PACING_MODES, default="off",
                   help="null pacing: static waits at a turning point the force has not reached; "
                        "dynamic also slows the programme while the force lags (default %(default)s)")
    g.add_argument("--pacing-tolerance", type=float, metavar="KGF",
                   help="how far the force may be from the reference or a turning point before the "
                        "programme paces (default 0.5 %% of the programme's range)")
    g.add_argument("--pacing-min-speed", type=float, default=0.2, metavar="SHARE",
                   help="dynamic pacing: the slowest share of the programme's speed (default %(default)s)")
    g.add_argument("--pacing-timeout", type=float, default=10.0, metavar="S",
                   help="stop the pass when the programme waits longer than S at one turning point "
                        "(default %(default)s)")
    p.add_argument("--unload-to", type=float, default=0.0, metavar="KGF",
                   help="force to unload to at the end, kgf (default %(default)s)")
    p.add_argument("--json", action="store_true",
                   help="print the tracking summary as JSON (schema hydrostand-load/1)")
    add_gateway(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_effects(p)
    p.set_defaults(func=main)


def _terminate(signum, frame) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def _plan(args, programme, controller, config) -> int:
    """``--plan``: the programme's time beside its valve-limited minimum."""
    from loading.minimum_time import programme_timing
    limit = min(controller.command_limit_pct, config.limits.command_limit_pct)
    timing = programme_timing(programme, controller.model, limit)
    if args.json:
        json.dump({"programme": programme.source, "turning_points": int(len(programme.turning_idx)),
                   "range_kgf": programme.range_kgf, "command_limit_pct": limit, **timing.to_dict()},
                  sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    print(f"{programme.source}: {len(programme.turning_idx)} turning points, range "
          f"{programme.range_kgf:.0f} kgf, command limit ±{limit:g} %")
    print(timing.text("at the requested rate"))
    return 0


def main(args: argparse.Namespace) -> int:
    from gateway import Gateway
    from gateway.load import LoadProgramme, run_load, timing_text
    from loading.compensation import Compensation
    from loading.design import load_controller
    from loading.pacing import PacingOptions
    from loading.programme import load_programme
    config = gateway_config(args)
    controller = load_controller(args.controller, config.period_s)
    programme = load_programme(args.program, config.period_s, args.rate, args.frequency)
    if args.plan:
        return _plan(args, programme, controller, config)
    if not args.out:
        raise ParameterError("give --out DIR for the passes and the report (or --plan to see the "
                             "programme's time and its valve-limited minimum without loading)")
    repeat = args.repeat if args.repeat is not None else 1
    pacing = PacingOptions(args.pacing, args.pacing_tolerance, args.pacing_min_speed, args.pacing_timeout)
    pacing.check()
    comp = Compensation.load(args.compensation) if args.compensation else None
    # everything that can be refused is refused before the stand is touched
    LoadProgramme(programme, controller, comp, args.unload_to, pacing=pacing).check(
        config.period_s, config.limits.force_limit_kgf, config.limits.command_limit_pct)
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        with Gateway(config) as gw:
            result = run_load(gw, programme, controller, args.out, repeat, comp,
                              learn=not args.no_learn, unload_kgf=args.unload_to,
                              progress=False if args.no_progress else None, pacing=pacing)
    finally:
        signal.signal(signal.SIGTERM, previous)
    if args.json:
        json.dump(result.summary(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        for i, (p, timing) in enumerate(zip(result.passes, result.timings), start=1):
            print(f"pass {i}: peak/valley error p95 {p.peak_valley_error_pct['p95']:.2f} %, max "
                  f"{p.peak_valley_error_pct['max']:.2f} %, RMS {p.rms_error_pct:.2f} %, extra cycles "
                  f"{p.extra_cycles:g}; {timing_text(timing)}")
        if result.passes:
            print(result.passes[-1].text())
        print(f"-> {result.out} (report.txt, report.json, tracking.png, pass-N/)")
    if result.end_reason not in (None, "complete"):
        print(f"stand load: stopped ({result.end_reason}): {result.end_message}", file=sys.stderr)
        return 1
    return 0
