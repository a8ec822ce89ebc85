"""The rig's side of ``stand load`` (``--rig RIG.toml``): every channel of a rig loaded at once by
the rig's controller, pass by pass (a thin wrapper over :func:`gateway.rig_load.run_rig_load`).
Not a sub-command of its own (no ``register``)."""
from __future__ import annotations

import argparse
import json
import sys

from core.errors import ParameterError


def _plan(args, programme, controller, config) -> int:
    """``--plan --rig``: the load cases' time beside their valve-limited minimum."""
    from loading.rig_minimum_time import rig_programme_timing

    from .load import print_plan
    limit = min(controller.command_limit_pct, config.limits.command_limit_pct)
    timing = rig_programme_timing(programme, controller.model, limit)
    return print_plan(args, timing, {"programme": programme.source, "channels": programme.names,
                                     "load_cases": int(len(programme.turning_idx)),
                                     "ranges_kgf": dict(zip(programme.names, programme.ranges_kgf.tolist())),
                                     "command_limit_pct": limit},
                      f"{programme.source}: {len(programme.turning_idx)} load cases on {programme.n} "
                      f"channels ({', '.join(programme.names)}), command limit ±{limit:g} %")


def main(args: argparse.Namespace) -> int:
    from gateway import Gateway
    from gateway.rig_load import check_rig_load, run_rig_load, timing_text
    from loading.rig_compensation import RigCompensation
    from loading.rig_design import load_rig_controller
    from loading.rig_programme import load_rig_programme
    from loading.time_scaling import Schedule

    from .common import gateway_config, sigterm_as_interrupt
    from .load import (PLACEHOLDER_RATE_KGF_S, SCALING_PASSES, exit_code, monitor_options, pacing_options,
                       scaling_options, schedule_line)
    config = gateway_config(args)
    rig = config.rig
    controller = load_rig_controller(args.controller, config.period_s, rig.names)
    scaling = scaling_options(args)
    untimed = args.rate is None and args.frequency is None and (scaling is not None or args.schedule)
    programme = load_rig_programme(args.program, rig.names, config.period_s,
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
        programme = schedule.apply_rig(programme)
    if untimed and scaling is not None:
        from gateway.rig_load import rig_minimum_s
        programme = programme.with_durations(2 * rig_minimum_s(config, programme, controller, required=True),
                                             f"{programme.source}, from twice the minimum")
    if args.plan:
        return _plan(args, programme, controller, config)
    if not args.out:
        raise ParameterError("give --out DIR for the passes and the report (or --plan to see the "
                             "load cases' time and their valve-limited minimum without loading)")
    repeat = args.repeat if args.repeat is not None else (SCALING_PASSES if scaling else 1)
    monitor = monitor_options(args)
    pacing = pacing_options(args)
    comp = RigCompensation.load(args.compensation, rig.names) if args.compensation else None
    # everything that can be refused is refused before the rig is touched
    check_rig_load(config, programme, controller, comp, args.unload_to, pacing=pacing)
    if not (1 <= repeat <= 1000):
        raise ParameterError(f"--repeat {repeat}: it must be from 1 to 1000")
    with sigterm_as_interrupt():
        with Gateway(config) as gw:
            result = run_rig_load(gw, programme, controller, args.out, repeat, comp,
                                  learn=not args.no_learn, unload_kgf=args.unload_to,
                                  progress=False if args.no_progress else None, scaling=scaling,
                                  monitor=monitor, pacing=pacing)
    if args.json:
        json.dump(result.summary(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        for i, (p, timing) in enumerate(zip(result.passes, result.timings), start=1):
            f = p.figures()
            pv = f["peak_valley_error_pct"]
            ratio = p.ratio_error_pct
            print(f"pass {i}: worst channel {p.worst_channel}: peak/valley error p95 {pv['p95']:.2f} %, "
                  f"max {pv['max']:.2f} %; extra cycles (all channels) "
                  f"{sum(r.extra_cycles for r in p.channels):g}"
                  + (f"; ratio error {ratio:.2f} %" if ratio is not None else "")
                  + f"; {timing_text(timing, result.minimum_time_s)}")
        if result.passes:
            print(result.passes[-1].text())
        if result.converged is not None:
            print(schedule_line(result, scaling, repeat, " on every channel"))
        if result.monitor is not None:
            print(result.monitor.text())
        written = [n for n in ("report.txt", "report.json", "tracking.png", "compensation.toml",
                               "schedule.toml") if (result.out / n).is_file()]
        print(f"-> {result.out} ({', '.join(written + ['pass-N/'])})")
    return exit_code(result, result.monitor.alarm if result.monitor is not None else None)
