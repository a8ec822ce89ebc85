"""``stand demo``: the whole chain in seconds — emulator process, gateway, lockstep run, estimate.
With ``--rig [RIG.toml]`` the same for a rig of many channels (:mod:`.rig_demo`)."""
from __future__ import annotations

import argparse
import datetime as dt
import os
import time
from pathlib import Path

from gateway.experiments import Meander

from .common import parse_assignments


def register(sub) -> None:
    p = sub.add_parser("demo", help="start the emulator, run a lockstep meander, print the estimates",
                       description="Start the plant emulator as a separate process on a private "
                                   "loopback bus, connect the gateway, run an open-loop meander in "
                                   "lockstep, record it and print the paper's estimates beside the "
                                   "emulator's truth.")
    p.add_argument("--out", metavar="DIR", help="run directory (default runs/demo-TIMESTAMP)")
    p.add_argument("--amplitude-pct", type=float, default=5.0, help="meander amplitude u0, %% (default %(default)s)")
    p.add_argument("--period-s", type=float, default=4.0, help="meander period, s (default %(default)s)")
    p.add_argument("--cycles", type=int, default=5, help="meander periods (default %(default)s)")
    p.add_argument("--config", metavar="PLANT.toml", help="emulator plant configuration")
    p.add_argument("--set", action="append", metavar="NAME=VALUE", help="override a plant parameter (repeatable)")
    p.add_argument("--seed", type=int, default=1, help="noise seed (default %(default)s)")
    p.add_argument("--bus", default=None, metavar="SPEC",
                   help="bus to use (default: a private udp_loopback channel for this demo)")
    g = p.add_argument_group("a rig of many channels (docs/rig.md)")
    g.add_argument("--rig", nargs="?", const="example", default=None, metavar="RIG.toml",
                   help="demonstrate a rig instead (default: examples/rig.toml, 4 channels on 2 "
                        "buses): stand emulate --rig on private loopback buses (never the file's "
                        "interfaces), a meander on one channel, every channel recorded, the "
                        "column of G estimated beside the rig file's; --config, --set and --bus "
                        "are not used (the plants are the rig file's)")
    g.add_argument("--channel", action="append", default=None, metavar="NAME",
                   help="with --rig: the channel the meander drives (default: the first); repeat "
                        "it for one run per channel, each a column of G")
    g.add_argument("--every-channel", action="store_true",
                   help="with --rig: one run per channel: all of G (4 channels: about 4x the time)")
    g.add_argument("--real-time", action="store_true",
                   help="with --rig: emulator and gateway on the wall clock instead of lockstep")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from .rig_demo import main_rig, refuse_rig_options
    if args.rig is not None:
        return main_rig(args)
    refuse_rig_options(args)
    from analysis import estimate_meander, read_run
    from gateway import Gateway, GatewayConfig
    from gateway.recorder import write_json
    from gateway.runs import TRUTH_FILE
    from plant.config import load_plant_config
    from plant_emulator.process import EmulatorProcess
    config = load_plant_config(args.config, None, parse_assignments(args.set))
    experiment = Meander(args.amplitude_pct, args.period_s, args.cycles)
    bus = args.bus or f"udp_loopback:demo-{os.getpid()}"
    out = Path(args.out or f"runs/demo-{dt.datetime.now():%Y%m%d-%H%M%S}")
    print(f"emulator: {config.model.spec} on {bus} (lockstep, separate process)")
    t0 = time.monotonic()
    with EmulatorProcess(bus, config, lockstep=True, seed=args.seed):
        with Gateway(GatewayConfig(bus=bus, lockstep=True)) as gw:
            result = gw.run(experiment, out, progress=None)
    write_json(result.path / TRUTH_FILE, config.to_dict())
    wall = time.monotonic() - t0
    stats = result.outcome.stats
    print(f"run {result.status}: {stats.cycles} cycles = {stats.cycles * 0.002:.1f} s of stand time "
          f"in {wall:.1f} s wall ({stats.cycles * 0.002 / max(stats.wall_s, 1e-9):.1f}x real time)")
    if result.reason:
        print(f"stopped early ({result.reason}): {result.outcome.message}")
        return 1
    est = estimate_meander(read_run(result.path))
    truth = config.model.params()
    print()
    print(f"open-loop meander ±{args.amplitude_pct:g} %, eq. (2) estimates      truth (emulator)")
    print(f"  g main portions   {est.g:8.2f} kgf/(%·s)  [{est.g_ci[0]:.2f}, {est.g_ci[1]:.2f}]"
          f"   {truth['g']:.2f}")
    for name in ("transitional_rise", "transitional_fall"):
        p = est.portion(name)
        if p:
            print(f"  g {name.replace('_', ' '):16s}{p.g:8.2f} kgf/(%·s)  [{p.ci_low:.2f}, {p.ci_high:.2f}]"
                  f"   (window {est.transitional_s * 1e3:.0f} ms after each reversal)")
    print(f"  trend Δ           {est.delta:8.2f} kgf/s                         {truth['delta']:.2f}")
    if est.tau is not None:
        print(f"  delay τ (rough)   {est.tau * 1e3:8.1f} ms                            {truth['tau'] * 1e3:.1f}")
    print()
    print(f"run directory: {result.path}/")
    for f in sorted(result.path.iterdir()):
        print(f"  {f.name:18s} {f.stat().st_size:>10,d} bytes")
    return 0
