"""``stand campaign``: a station's identification: on a stand the paper's three experiments as
one campaign, then the report; on a rig (``--rig``) the meanders that identify G (a thin wrapper
over :func:`gateway.campaign.run_campaign`)."""
from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import os
import sys
import time
import uuid
from pathlib import Path

from gateway.errors import ParameterError

from .common import add_effects, add_node_ids, device_set, id_args, parse_assignments

#: one-channel options that mean nothing on a rig
ONE_CHANNEL_ONLY = (("bus", "--bus"), ("config", "--config"), ("model", "--model"), ("set", "--set"),
                    ("only", "--only"), ("quick", "--quick"), ("force_limit", "--force-limit"))

#: the one-channel campaign's force limit unless --force-limit says
FORCE_LIMIT_KGF = 9500.0
#: --one-run's defaults: the accuracy asked, the longest transitional window and the noise the
#: plan assumes
ACCURACY_PCT, TRANSITIONAL_MS, NOISE_KGF = 1.0, 350.0, 2.0
#: the one-run excitations (rig/excitation.py; kept here so that --help needs no numerics)
EXCITATIONS = ("hadamard",)
#: options of --one-run only, and of the simultaneous run only
ONE_RUN_ONLY = (("excitation", "--excitation"), ("accuracy_pct", "--accuracy-pct"),
                ("transitional_ms", "--transitional-ms"), ("noise_kgf", "--noise-kgf"))


def register(sub) -> None:
    p = sub.add_parser(
        "campaign", help="run the paper's meander, P-feedback and relay experiments and report g and τ",
        description="Run the paper's whole experimental program (open-loop meander, proportional "
                    "feedback with a harmonic reference, relay feedback) in one gateway session, one "
                    "run directory per experiment, then write the report: tables (CSV), figures (PNG) "
                    "and a summary of g and τ with 95 % intervals. By default the campaign starts its "
                    "own emulator (lockstep, private loopback bus) and puts its truth beside the "
                    "estimates; with --bus it drives whatever stand is on that bus.")
    p.add_argument("--out", metavar="DIR", help="report directory (default campaigns/campaign-TIMESTAMP)")
    p.add_argument("--quick", action="store_true", help="a short campaign (two points per grid, ~1 min of stand time)")
    p.add_argument("--only", metavar="NAMES", help="comma-separated subset: meander,pfeedback,relay")
    p.add_argument("--bus", default=None, metavar="SPEC",
                   help="run against the stand on this bus instead of starting an emulator "
                        "(e.g. socketcan:can0; add --lockstep for an emulator started with --lockstep)")
    p.add_argument("--lockstep", action="store_true", help="with --bus: the stand is a lockstep emulator")
    add_node_ids(p)
    p.add_argument("--period-ms", type=float, default=2.0, help="control period, ms (default %(default)s)")
    p.add_argument("--force-limit", type=float, default=None, metavar="KGF",
                   help="supervisor force limit, kgf; experiments stop themselves at 90 %% of it "
                        f"(default {FORCE_LIMIT_KGF:g}; a rig: each channel's force_limit_kgf)")
    p.add_argument("--config", metavar="PLANT.toml", help="emulator plant configuration (own emulator only)")
    p.add_argument("--model", metavar="SPEC", help="emulator model, e.g. base or base+reversal (own emulator only)")
    p.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="override an emulator parameter, e.g. --set g=130 --set reversal.boost=0 (repeatable)")
    p.add_argument("--seed", type=int, default=1, help="emulator noise seed (default %(default)s)")
    add_effects(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-figures", action="store_true", help="tables and summary only")
    g = p.add_argument_group("a rig of many channels: identify G (docs/rig.md, \"Identifying G\")")
    g.add_argument("--rig", metavar="RIG.toml",
                   help="run the rig's identification through the rig gateway against the rig "
                        "on the file's buses (e.g. stand emulate --rig RIG.toml --lockstep): one "
                        "meander run per channel, the others at a zero command (a column of G "
                        "each), with --simultaneous one run, every channel a meander of its "
                        "own period, or with --one-run one short run of Hadamard meanders; the "
                        "runs go to OUT/NN-LABEL for stand estimate OUT --save")
    g.add_argument("--simultaneous", action="store_true",
                   help="with --rig: every channel at once, the periods from --meander-period-s "
                        "up (analysis.rig.periods.separating_periods)")
    g.add_argument("--one-run", action="store_true",
                   help="with --rig: all of G from one short run: every channel a ±u0 meander "
                        "whose signs follow its row of a Hadamard matrix, all switching on one "
                        "grid; the plan says how long it must be for --accuracy-pct before "
                        "anything moves (docs/rig.md, \"G from one short run\")")
    g.add_argument("--excitation", choices=EXCITATIONS, default=None,
                   help="with --one-run: the excitation (default hadamard)")
    g.add_argument("--accuracy-pct", type=float, default=None, metavar="PCT",
                   help="with --one-run: every entry of G within ±PCT %% of the smallest "
                        f"diagonal, all at once at 95 %% (default {ACCURACY_PCT:g})")
    g.add_argument("--transitional-ms", type=float, default=None, metavar="MS",
                   help="with --one-run: the longest reversal boost (transitional window) the "
                        "plan allows for; the estimate leaves 4 such windows out after each "
                        f"reversal (default {TRANSITIONAL_MS:g}, the paper's)")
    g.add_argument("--noise-kgf", type=float, default=None, metavar="KGF",
                   help="with --one-run: the dynamometers' noise the plan assumes (default "
                        f"{NOISE_KGF:g})")
    g.add_argument("--amplitude-pct", type=float, default=5.0, metavar="PCT",
                   help="with --rig: every meander's command ±PCT (default %(default)s)")
    g.add_argument("--meander-period-s", type=float, default=None, metavar="S",
                   help="with --rig: the meander period (per column, default 8) or the shortest "
                        "of the separating periods (simultaneous, default 12)")
    g.add_argument("--cycles", type=int, default=4, metavar="N",
                   help="with --rig, per column: periods per run (default %(default)s)")
    g.add_argument("--duration-s", type=float, default=None, metavar="S",
                   help="with --rig --simultaneous: the run's length (default 120); with "
                        "--one-run: instead of the planned length (refused if it cannot give "
                        "--accuracy-pct)")
    g.add_argument("--fault-action", choices=("hold", "unload"), default="hold",
                   help="with --rig: what a channel's communication or valve fault does to the "
                        "others (default %(default)s)")
    g.add_argument("--emulated", action="store_true",
                   help="with --rig: the rig is `stand emulate --rig` of this very file: write "
                        "its truth (truth.json) beside each run")
    g.add_argument("--with-emulator", action="store_true",
                   help="with --rig: start `stand emulate --rig` of the file for the campaign "
                        "(lockstep, on private loopback buses; OUT/rig.toml is the file as run) "
                        "and write its truth beside each run, as the one-channel campaign does")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    if args.rig:
        return _rig(args)
    if (args.simultaneous or args.one_run or args.emulated or args.with_emulator
            or args.meander_period_s is not None or args.duration_s is not None
            or any(getattr(args, a) is not None for a, _ in ONE_RUN_ONLY)):
        raise ParameterError("--simultaneous, --one-run, --emulated, --with-emulator, "
                             "--meander-period-s, --duration-s and the --one-run options plan a "
                             "rig's identification: give --rig RIG.toml too")
    from analysis import report_campaign
    from gateway import Gateway, GatewayConfig, SafetyLimits
    from gateway.campaign import CampaignPlan, run_campaign
    from plant.config import load_plant_config
    from plant_emulator.process import EmulatorProcess
    plan = CampaignPlan.quick() if args.quick else CampaignPlan.default()
    if args.only:
        plan = plan.only([n.strip() for n in args.only.split(",") if n.strip()])
    planned = plan.runs()
    out = Path(args.out or f"campaigns/campaign-{dt.datetime.now():%Y%m%d-%H%M%S}")
    progress = False if args.no_progress else None
    period_s = args.period_ms / 1000.0
    limits = SafetyLimits(force_limit_kgf=FORCE_LIMIT_KGF if args.force_limit is None else args.force_limit)
    t0 = time.monotonic()
    devices = device_set(args)
    if args.bus is None:
        config = load_plant_config(args.config, args.model, parse_assignments(args.set))
        bus = f"udp_loopback:campaign-{os.getpid()}-{uuid.uuid4().hex[:6]}"   # private channel
        print(f"emulator: {config.model.spec} on {bus} (lockstep, separate process, seed {args.seed})")
        print(f"campaign: {len(planned)} runs, about {plan.nominal_stand_s():.0f} s of stand time -> {out}/")
        with EmulatorProcess(bus, config, lockstep=True, seed=args.seed, devices=devices,
                             extra_args=id_args(args)):
            with Gateway(GatewayConfig(bus=bus, lockstep=True, period_s=period_s, valve_id=args.valve_id,
                                       dynamometer_id=args.dynamometer_id, limits=limits,
                                       devices=devices)) as gw:
                result = run_campaign(gw, plan, out, progress=progress, truth=config.to_dict())
    else:
        if args.config or args.model or args.set:
            raise ParameterError("--config, --model and --set describe the emulator the campaign starts "
                                 "itself; with --bus the stand is whatever is on that bus")
        print(f"stand on {args.bus} ({'lockstep' if args.lockstep else 'real time'})")
        print(f"campaign: {len(planned)} runs, about {plan.nominal_stand_s():.0f} s of stand time -> {out}/")
        with Gateway(GatewayConfig(bus=args.bus, lockstep=args.lockstep, period_s=period_s,
                                   valve_id=args.valve_id, dynamometer_id=args.dynamometer_id,
                                   limits=limits, devices=devices)) as gw:
            result = run_campaign(gw, plan, out, progress=progress)
    wall = time.monotonic() - t0
    stopped = [r for r in result.runs if r.status != "complete"]
    print(f"campaign {result.status}: {len(result.runs)}/{len(planned)} runs, {result.stand_s:.0f} s of "
          f"stand time in {result.wall_s:.0f} s wall ({result.speedup:.1f}x real time; "
          f"{wall:.0f} s with start-up)")
    for r in stopped:
        print(f"  {r.label} stopped ({r.reason}): {r.message}")
    if result.stopped_by:
        print(f"  the campaign ended early: {result.stopped_by}", file=sys.stderr)
    report = report_campaign(out, figures=not args.no_figures)
    print()
    print(report.text)
    print()
    print(f"report: {out}/  (summary.txt, summary.csv, estimates.json, {len(report.tables) - 2} tables, "
          f"{len(report.figures)} figures; runs/ holds {len(result.runs)} run directories)")
    return 0 if result.status == "complete" and not report.failures else 1


def _rig(args: argparse.Namespace) -> int:
    """``--rig``: the meanders that identify the rig's G."""
    from analysis.rig.periods import planned_inflation, separating_periods
    from gateway import Gateway, GatewayConfig, SafetyLimits
    from gateway.campaign import G_CAMPAIGN_FILE, GPlan, run_campaign
    from rig.config import load_rig_file
    given = [flag for attr, flag in ONE_CHANNEL_ONLY if getattr(args, attr, None)]
    if given:
        raise ParameterError(f"{', '.join(given)}: not with --rig (the rig file gives the buses, node "
                             "ids and each channel's force limit; the emulator is `stand emulate "
                             "--rig RIG.toml --lockstep`, or --with-emulator); leave them out")
    rig = load_rig_file(args.rig)
    if abs(args.period_ms / 1e3 - rig.period_s) > 1e-9 and args.period_ms != 2.0:
        raise ParameterError(f"--period-ms {args.period_ms:g}: the rig {args.rig} runs at "
                             f"{rig.period_s * 1e3:g} ms (period_ms in the file); leave --period-ms out")
    given = [flag for attr, flag in ONE_RUN_ONLY if getattr(args, attr) is not None]
    if given and not args.one_run:
        raise ParameterError(f"{', '.join(given)}: only with --one-run")
    if args.one_run and (args.simultaneous or args.meander_period_s is not None):
        raise ParameterError("--one-run plans its own excitation: leave --simultaneous and "
                             "--meander-period-s out")
    if args.one_run:
        from analysis.rig.onerun import describe_design, plan_for_rig
        transitional = (TRANSITIONAL_MS if args.transitional_ms is None else args.transitional_ms) / 1e3
        design = plan_for_rig(rig, args.amplitude_pct,
                              ACCURACY_PCT if args.accuracy_pct is None else args.accuracy_pct,
                              transitional, NOISE_KGF if args.noise_kgf is None else args.noise_kgf,
                              args.duration_s)
        plan = GPlan.one(design)
        what = describe_design(design, transitional)
    elif args.simultaneous:
        duration = 120.0 if args.duration_s is None else args.duration_s
        shortest = 12.0 if args.meander_period_s is None else args.meander_period_s
        periods = separating_periods(len(rig.names), shortest, rig.period_s)
        plan = GPlan(True, args.amplitude_pct, periods, duration_s=duration)
        vif = max(planned_inflation(periods, duration, rig.period_s))
        what = (f"one simultaneous run, periods {', '.join(f'{p:g}' for p in periods)} s over "
                f"{duration:g} s (planned variance inflation ≤ {vif:.2f})")
    else:
        if args.duration_s is not None:
            raise ParameterError("--duration-s: only with --simultaneous or --one-run (per column "
                                 "the runs are --cycles periods of --meander-period-s)")
        period = 8.0 if args.meander_period_s is None else args.meander_period_s
        if not (2 <= args.cycles <= 1000):
            raise ParameterError(f"--cycles {args.cycles}: it must be from 2 to 1000 (the estimate "
                                 "needs two reversals of each channel's command)")
        plan = GPlan(False, args.amplitude_pct, [period], args.cycles)
        what = f"{len(rig.names)} runs, one per column of G: ±{args.amplitude_pct:g} %, {args.cycles} × {period:g} s"
    out = Path(args.out or f"campaigns/rig-campaign-{dt.datetime.now():%Y%m%d-%H%M%S}")
    print(f"rig campaign on {rig.name}: {what} -> {out}/", flush=True)
    plan.check_rig(rig)          # before anything is opened
    lockstep = args.lockstep or args.with_emulator
    with contextlib.ExitStack() as stack:
        if args.with_emulator:
            rig = _own_emulator(stack, rig, out, args.seed)
        truth = None
        if args.emulated or args.with_emulator:
            from rig.emulated import rig_truth
            truth = rig_truth(rig)
        config = GatewayConfig(rig=rig, lockstep=lockstep, period_s=rig.period_s,
                               limits=SafetyLimits(), fault_action=args.fault_action)
        with Gateway(config) as gw:
            result = run_campaign(gw, plan, out, progress=False if args.no_progress else None, truth=truth)
    for r in result.runs:
        line = f"  {r.label}: {r.status}, {r.stand_s:.0f} s of stand time in {r.wall_s:.0f} s"
        if r.status != "complete":
            line += f" ({r.reason}: {r.message})"
        print(line)
    print(f"rig campaign {result.status}: {result.stand_s:.0f} s of stand time in {result.wall_s:.0f} s; "
          f"{out / G_CAMPAIGN_FILE}; next: stand estimate {out} --save rig-model.toml")
    if result.status != "complete":
        print("stand campaign: a run stopped early; the campaign ended there", file=sys.stderr)
        return 1
    return 0


def _own_emulator(stack: contextlib.ExitStack, rig, out: Path, seed: int):
    """``--with-emulator``: the rig on private loopback buses, written to OUT/rig.toml and
    served by ``stand emulate --rig`` in lockstep until the campaign ends; the rig as run.
    A rig that cannot be emulated (a channel without a plant, a structure no stiffness gives)
    is refused before anything starts."""
    from plant_emulator.process import RigEmulatorProcess
    from rig.emulated import emulated_plant
    from rig.files import on_private_loopback, write_as_run
    source = rig.path
    private = on_private_loopback(rig, f"campaign-{os.getpid()}")
    emulated_plant(private)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "rig.toml"
    write_as_run(private, path, source, "stand campaign --with-emulator")
    print(f"emulator: rig {private.name!r} from {source}, {len(private.channels)} channels on "
          f"{len(private.buses)} private loopback buses, lockstep, one separate process")
    stack.enter_context(RigEmulatorProcess(path, lockstep=True, seed=seed))
    return private
