"""``stand load PROGRAM --controller C --out RUN``: a loading programme on the stand, tracked by
the designed controller, with peak/valley compensation learning over passes (gateway.load)."""
from __future__ import annotations

import argparse
import json
import sys

from core.errors import ParameterError

#: loading.pacing.PACING_MODES and loading.gain_monitor.ALARM_ACTIONS, written out: `stand
#: --help` imports no numerics
PACING_MODES = ("off", "static", "dynamic")
ALARM_ACTIONS = ("note", "hold", "unload")
GAIN_MODES = ("off", "watch", "adapt")

#: time scaling's passes unless --repeat says
SCALING_PASSES = 10
DEFAULT_ACCURACY_PCT = 0.5
#: a turning-point sequence without --rate under --fastest or --schedule is read at this rate,
#: then given its durations
PLACEHOLDER_RATE_KGF_S = 1000.0

from .common import add_effects, add_gateway, gateway_config, programme_error_limit, sigterm_as_interrupt


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
                        "between passes (default 1; with --accuracy/--fastest: at most N passes, "
                        f"default {SCALING_PASSES})")
    p.add_argument("--rate", type=float, metavar="KGF_PER_S",
                   help="turning-point sequence: peak rate of the haversines between points, kgf/s")
    p.add_argument("--frequency", type=float, metavar="HZ",
                   help="turning-point sequence: one half cycle per 1/(2 HZ) instead of --rate")
    p.add_argument("--compensation", metavar="FILE.toml",
                   help="start from peak/valley corrections learned before (compensation.toml of "
                        "an earlier stand load)")
    p.add_argument("--no-learn", action="store_true", help="keep the corrections as they are")
    g = p.add_argument_group("time scaling and null pacing (docs/loading.md)")
    g.add_argument("--accuracy", type=float, metavar="PCT",
                   help="time scaling: shorten each segment pass by pass while its turning point "
                        "holds PCT %% of the range (p95 <= PCT, max <= 2 PCT, no extra cycle), "
                        "lengthen those that miss; the fastest schedule that met it is saved as "
                        "OUT/schedule.toml")
    g.add_argument("--fastest", action="store_true",
                   help=f"time scaling at --accuracy (default {DEFAULT_ACCURACY_PCT} %%), starting "
                        "from --rate, or from twice the valve-limited minimum without one")
    g.add_argument("--schedule", metavar="SCHEDULE.toml",
                   help="run the segment durations of a schedule made by --fastest/--accuracy "
                        "(a production run)")
    g.add_argument("--pacing", choices=PACING_MODES, default="off",
                   help="null pacing: static waits at a turning point the force has not reached; "
                        "dynamic also slows the programme while the force lags; with --rig one "
                        "clock for every channel, waiting at load cases (default %(default)s)")
    g.add_argument("--pacing-tolerance", type=float, metavar="KGF",
                   help="how far the force may be from the reference or a turning point before the "
                        "programme paces (default 0.5 %% of the programme's range)")
    g.add_argument("--pacing-min-speed", type=float, default=0.2, metavar="SHARE",
                   help="dynamic pacing: the slowest share of the programme's speed (default %(default)s)")
    g.add_argument("--pacing-timeout", type=float, default=10.0, metavar="S",
                   help="stop the pass when the programme waits longer than S at one turning point "
                        "(default %(default)s)")
    g = p.add_argument_group("the stand's gain, estimated and watched (docs/loading.md)")
    g.add_argument("--gain", choices=GAIN_MODES, default="off",
                   help="watch: re-estimate g block by block from the tracking data and raise an "
                        "alarm when it falls (a crack) or rises (a jammed part); adapt: also let the "
                        "feedforward follow it; with --rig each channel's row of G, the alarm "
                        "acting on every channel (default %(default)s)")
    g.add_argument("--gain-block-s", type=float, default=10.0, metavar="S",
                   help="stand time per estimate (default %(default)s)")
    g.add_argument("--gain-fall", type=float, default=2.0, metavar="PCT",
                   help="alarm when g falls more than PCT %% below the model's (default %(default)s)")
    g.add_argument("--gain-rise", type=float, default=5.0, metavar="PCT",
                   help="alarm when g rises more than PCT %% above the model's (default %(default)s)")
    g.add_argument("--gain-alarm-action", choices=ALARM_ACTIONS, default="note",
                   help="note (recorded, the test goes on), hold (the valve holds) or unload (a "
                        "controlled unload, then hold) (default %(default)s)")
    p.add_argument("--unload-to", type=float, default=0.0, metavar="KGF",
                   help="force to unload to at the end, kgf (default %(default)s)")
    p.add_argument("--json", action="store_true",
                   help="print the tracking summary as JSON (schema hydrostand-load/1)")
    add_gateway(p, programme_error_limit("each channel's programme range"))
    g = p.add_argument_group("a rig of many channels (docs/loading.md, \"Loading a rig\")")
    g.add_argument("--rig", metavar="RIG.toml",
                   help="load every channel of a rig at once: PROGRAM is a load-case CSV (a column "
                        "per channel, a row per load case) or a TOML of [channel.NAME] programmes, "
                        "--controller a rig controller (stand design RIG-MODEL.toml); each "
                        "channel's peak/valley compensation learns between passes; --plan, "
                        "--fastest, --accuracy and --schedule time its load cases, every valve's "
                        "limit counted with its neighbours' flows through G")
    g.add_argument("--fault-action", choices=("hold", "unload"), default="hold",
                   help="with --rig: what a channel's communication or valve fault does to the "
                        "others: hold every channel, or unload them keeping the load ratios "
                        "(default %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_effects(p)
    p.set_defaults(func=main)


def _plan(args, programme, controller, config) -> int:
    """``--plan``: the programme's time beside its valve-limited minimum."""
    from loading.minimum_time import programme_timing
    limit = min(controller.command_limit_pct, config.limits.command_limit_pct)
    timing = programme_timing(programme, controller.model, limit)
    if programme.stand:
        p = programme.channels[0]
        return print_plan(args, timing, {"programme": p.source, "turning_points": int(len(p.turning_idx)),
                                         "range_kgf": p.range_kgf, "command_limit_pct": limit},
                          f"{p.source}: {len(p.turning_idx)} turning points, range {p.range_kgf:.0f} kgf, "
                          f"command limit ±{limit:g} %")
    return print_plan(args, timing, {"programme": programme.source, "channels": programme.names,
                                     "load_cases": int(len(programme.turning_idx)),
                                     "ranges_kgf": dict(zip(programme.names, programme.ranges_kgf.tolist())),
                                     "command_limit_pct": limit},
                      f"{programme.source}: {len(programme.turning_idx)} load cases on {programme.n} "
                      f"channels ({', '.join(programme.names)}), command limit ±{limit:g} %")


def print_plan(args, timing, fields: dict, heading: str) -> int:
    """``--plan``'s output (a stand's or a rig's): ``fields`` and the timing's as JSON, or the
    heading and the timing's text."""
    if args.json:
        json.dump({**fields, **timing.to_dict()}, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    print(heading)
    label = ("the schedule" if args.schedule else "the starting schedule"
             if (args.fastest or args.accuracy is not None) and args.rate is None and args.frequency is None
             else "at the requested rate")
    print(timing.text(label))
    return 0


def scaling_options(args):
    """``--fastest``/``--accuracy`` as :class:`loading.time_scaling.ScalingOptions` (None without
    them), refused beside ``--schedule``."""
    from loading.time_scaling import ScalingOptions
    if not (args.fastest or args.accuracy is not None):
        return None
    if args.schedule:
        raise ParameterError("--schedule replays a schedule; --fastest/--accuracy make one: give "
                             "one or the other")
    scaling = ScalingOptions(accuracy_pct=args.accuracy if args.accuracy is not None else DEFAULT_ACCURACY_PCT)
    scaling.check()
    return scaling


def pacing_options(args):
    """``--pacing`` and its options as :class:`loading.pacing.PacingOptions`, checked."""
    from loading.pacing import PacingOptions
    pacing = PacingOptions(args.pacing, args.pacing_tolerance, args.pacing_min_speed, args.pacing_timeout)
    pacing.check()
    return pacing


def monitor_options(args):
    """``--gain watch|adapt`` as :class:`loading.gain_monitor.MonitorOptions` (None when off)."""
    from loading.gain_monitor import MonitorOptions
    if args.gain == "off":
        return None
    monitor = MonitorOptions(block_s=args.gain_block_s, fall_pct=args.gain_fall, rise_pct=args.gain_rise,
                             action=args.gain_alarm_action, follow=args.gain == "adapt")
    monitor.check()
    return monitor


def schedule_line(result, scaling, repeat: int, where: str = "") -> str:
    """Time scaling's outcome in one line (``where``: e.g. " on every channel")."""
    s = result.schedule
    if s is None:
        return f"schedule: no pass met {scaling.accuracy_pct:g} %{where} in {repeat} passes"
    return (f"schedule: {s.time_s:.1f} s, {s.time_s / s.minimum_time_s:.2f}x the valve-limited minimum "
            f"{s.minimum_time_s:.1f} s, met {s.accuracy_pct:g} %{where} "
            + ("(converged)" if result.converged else f"(not converged in {repeat} passes: the fastest "
               "that met it)"))


def exit_code(result, alarm: tuple[str, str] | None) -> int:
    """The gain alarm and a pass that stopped, on stderr; 1 when a pass stopped."""
    if alarm is not None:
        print(f"stand load: gain alarm ({alarm[0]}): {alarm[1]}", file=sys.stderr)
    if result.end_reason not in (None, "complete"):
        print(f"stand load: stopped ({result.end_reason}): {result.end_message}", file=sys.stderr)
        return 1
    return 0


def main(args: argparse.Namespace) -> int:
    from gateway import Gateway
    from gateway.load import check_load, minimum_s, run_load
    from loading.compensation import Compensation
    from loading.controller_files import load_controller
    from loading.programme import STAND
    from loading.programme_files import load_programme, needs_rate
    from loading.time_scaling import Schedule
    config = gateway_config(args)
    names = config.rig.names if config.rig is not None else [STAND]
    controller = load_controller(args.controller, config.period_s, names)
    scaling = scaling_options(args)
    untimed = (args.rate is None and args.frequency is None and (scaling is not None or args.schedule)
               and needs_rate(args.program))
    programme = load_programme(args.program, names, config.period_s,
                               PLACEHOLDER_RATE_KGF_S if untimed else args.rate, args.frequency)
    if not programme.load_cases and (scaling is not None or args.schedule or args.plan):
        flags = [f for f, on in (("--fastest/--accuracy", scaling is not None), ("--schedule", args.schedule),
                                 ("--plan", args.plan)) if on]
        raise ParameterError(f"{', '.join(flags)} with --rig: time load cases (a CSV with a column per "
                             f"channel); {args.program} holds per-channel sequences, which share no "
                             "segments to time")
    if untimed:                              # the placeholder rate is no part of its name
        programme = programme.with_durations(programme.segment_durations_s,
                                             programme.source.rsplit(", ", 1)[0])
    schedule = Schedule.load(args.schedule) if args.schedule else None
    if schedule is not None:
        programme = schedule.apply(programme)
    if untimed and scaling is not None:
        programme = programme.with_durations(2 * minimum_s(config, programme, controller, required=True),
                                             f"{programme.source}, from twice the minimum")
    if args.plan:
        return _plan(args, programme, controller, config)
    if not args.out:
        raise ParameterError("give --out DIR for the passes and the report (or --plan to see the "
                             "programme's time and its valve-limited minimum without loading)")
    repeat = args.repeat if args.repeat is not None else (SCALING_PASSES if scaling else 1)
    if not (1 <= repeat <= 1000):
        raise ParameterError(f"--repeat {repeat}: it must be from 1 to 1000")
    pacing = pacing_options(args)
    monitor = monitor_options(args)
    # a schedule replays with the corrections its pass ran with, unless others are given
    from_schedule = schedule.compensation_path if schedule is not None and not args.compensation else None
    if from_schedule is not None and not from_schedule.is_file():
        raise ParameterError(f"{args.schedule} was met with the corrections of {from_schedule}, which is not "
                             "there: keep it beside the schedule, or give --compensation FILE")
    comp = (Compensation.load(args.compensation or from_schedule, names)
            if args.compensation or from_schedule else None)
    # everything that can be refused is refused before the station is touched
    check_load(config, programme, controller, comp, args.unload_to, pacing=pacing)
    with sigterm_as_interrupt():
        with Gateway(config) as gw:
            result = run_load(gw, programme, controller, args.out, repeat, comp,
                              learn=not args.no_learn, unload_kgf=args.unload_to,
                              progress=False if args.no_progress else None, scaling=scaling,
                              monitor=monitor, pacing=pacing)
    if args.json:
        json.dump(result.summary(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        _print_result(result, programme, scaling, repeat)
    return exit_code(result, result.monitor.alarm if result.monitor is not None else None)


def _print_result(result, programme, scaling, repeat: int) -> None:
    """Each pass in a line, the last pass's report, time scaling's outcome, the gain; on a
    station's load cases, what the feedforward covers, what each pass learnt and every load case
    pass by pass."""
    from gateway.load import feedforward_text, learned_text
    from loading.report import cases_table, case_moves
    if programme.n > 1 and result.feedforward is not None:
        print(feedforward_text(result.feedforward))
    for i, (p, timing) in enumerate(zip(result.passes, result.timings), start=1):
        if programme.n == 1:
            r = p.channels[0]
            pv = r.peak_valley_error_pct
            print(f"pass {i}: peak/valley error p95 {pv['p95']:.2f} %, max {pv['max']:.2f} %, RMS "
                  f"{r.rms_error_pct:.2f} %, extra cycles {r.extra_cycles:g}; {timing.text()}")
            continue
        figures = p.figures()
        pv = figures["peak_valley_error_pct"]
        ratio = p.ratio_error_pct
        moves = ""
        if i > 1 and "load_cases" in figures:
            m = case_moves(result.passes[i - 2].figures()["load_cases"], figures["load_cases"])
            moves = (f"; load cases closer {m['cases_closer']}, within the band {m['cases_within_band']}, worse "
                     f"{len(m['cases_worse'])}" + (f" ({', '.join(m['cases_worse'])})" if m["cases_worse"] else ""))
        print(f"pass {i}: worst channel {p.worst_channel}: peak/valley error p95 {pv['p95']:.2f} %, "
              f"max {pv['max']:.2f} %; extra cycles (all channels) {sum(r.extra_cycles for r in p.channels):g}"
              + (f"; ratio error {ratio:.2f} %" if ratio is not None else "") + moves + f"; {timing.text()}")
        learned = result.learned[i - 1] if i - 1 < len(result.learned) else None
        if learned is not None and (learned["not_learning"] or learned.get("stretched_segments")):
            print(learned_text(learned))
    if result.passes:
        print(result.passes[-1].text())
        if programme.n > 1:
            table = cases_table(result.passes)
            if table:
                print(table)
    if result.converged is not None:
        print(schedule_line(result, scaling, repeat, "" if programme.n == 1 else " on every channel"))
    if result.monitor is not None:
        print(result.monitor.text())
    written = [n for n in ("report.txt", "report.json", "tracking.png", "compensation.toml", "schedule.toml")
               if (result.out / n).is_file()]
    print(f"-> {result.out} ({', '.join(written + ['pass-N/'])})")
