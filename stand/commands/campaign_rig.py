"""The rig's side of ``stand campaign`` (``--rig RIG.toml``): the identification meanders run
through the rig gateway (a thin wrapper over :func:`gateway.rig_campaign.run_rig_campaign`).
Not a sub-command of its own (no ``register``)."""
from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import os
import sys
from pathlib import Path

from core.errors import ParameterError

#: one-channel options that mean nothing on a rig
ONE_CHANNEL_ONLY = (("bus", "--bus"), ("config", "--config"), ("model", "--model"), ("set", "--set"),
                    ("only", "--only"), ("quick", "--quick"), ("force_limit", "--force-limit"))


def main(args: argparse.Namespace) -> int:
    from analysis.rig.periods import planned_inflation, separating_periods
    from gateway import Gateway, GatewayConfig, SafetyLimits
    from gateway.rig_campaign import CAMPAIGN_FILE, RigCampaignPlan, run_rig_campaign
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
    if args.simultaneous:
        shortest = 12.0 if args.meander_period_s is None else args.meander_period_s
        periods = separating_periods(len(rig.names), shortest, rig.period_s)
        plan = RigCampaignPlan(True, args.amplitude_pct, periods, duration_s=args.duration_s)
        vif = max(planned_inflation(periods, args.duration_s, rig.period_s))
        what = (f"one simultaneous run, periods {', '.join(f'{p:g}' for p in periods)} s over "
                f"{args.duration_s:g} s (planned variance inflation ≤ {vif:.2f})")
    else:
        period = 8.0 if args.meander_period_s is None else args.meander_period_s
        if not (2 <= args.cycles <= 1000):
            raise ParameterError(f"--cycles {args.cycles}: it must be from 2 to 1000 (the estimate "
                                 "needs two reversals of each channel's command)")
        plan = RigCampaignPlan(False, args.amplitude_pct, [period], args.cycles)
        what = f"{len(rig.names)} runs, one per column of G: ±{args.amplitude_pct:g} %, {args.cycles} × {period:g} s"
    plan.check(rig)              # before anything is opened
    out = Path(args.out or f"campaigns/rig-campaign-{dt.datetime.now():%Y%m%d-%H%M%S}")
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
        print(f"rig campaign on {rig.name}: {what} -> {out}/")
        with Gateway(config) as gw:
            result = run_rig_campaign(gw, plan, out, progress=False if args.no_progress else None,
                                      truth=truth)
    for r in result.runs:
        line = f"  {r['path']}: {r['status']}, {r['stand_s']:.0f} s of stand time in {r['wall_s']:.0f} s"
        if r["status"] != "complete":
            line += f" ({r['reason']}: {r['message']})"
        print(line)
    print(f"rig campaign {result.status}: {result.stand_s:.0f} s of stand time in {result.wall_s:.0f} s; "
          f"{out / CAMPAIGN_FILE}; next: stand estimate {out} --save rig-model.toml")
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
