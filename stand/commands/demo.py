"""``stand demo``: the whole chain in seconds — emulator process, gateway, lockstep run, estimate.

With ``--rig [RIG.toml]`` the same for a rig in tens of seconds: ``stand emulate --rig`` as its
own process on private loopback buses, the rig gateway, a meander on one channel (or one run per
channel), every channel recorded, the column of G estimated from the run beside the rig file's,
and a plot of every channel's force."""
from __future__ import annotations

import argparse
import datetime as dt
import math
import os
import time
from pathlib import Path

from gateway.experiments import Meander

from .common import device_set, parse_assignments

#: the example rig of a clone (docs/rig.md)
EXAMPLE_RIG = Path(__file__).resolve().parents[2] / "examples" / "rig.toml"
#: where the demo writes what it ran: the rig file on its private buses, one run per driven
#: channel, the plot
RIG_FILE = "rig.toml"
PLOT_FILE = "forces.png"


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
    p.add_argument("--devices", metavar="DEVICES.toml",
                   help="the valve drive and amplifier to emulate and drive: a device file "
                        "(docs/devices.md; e.g. examples/devices/hydronix/devices.toml). Default: "
                        "the emulated pair (dbc/)")
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
    if args.rig is not None:
        return _rig(args)
    refuse_rig_options(args)
    from analysis import estimate_meander, read_run
    from gateway import Gateway, GatewayConfig
    from core.durable import write_json
    from gateway.runs import TRUTH_FILE
    from plant.config import load_plant_config
    from plant_emulator.process import EmulatorProcess
    config = load_plant_config(args.config, None, parse_assignments(args.set))
    devices = device_set(args)
    experiment = Meander(args.amplitude_pct, args.period_s, args.cycles)
    bus = args.bus or f"udp_loopback:demo-{os.getpid()}"
    out = Path(args.out or f"runs/demo-{dt.datetime.now():%Y%m%d-%H%M%S}")
    print(f"emulator: {config.model.spec} on {bus} (lockstep, separate process)")
    if devices is not None:
        print(f"devices: {devices.name} ({devices.where})")
    t0 = time.monotonic()
    with EmulatorProcess(bus, config, lockstep=True, seed=args.seed, devices=devices):
        with Gateway(GatewayConfig(bus=bus, lockstep=True, devices=devices)) as gw:
            for note in gw.master.notes():
                print(f"note: {note}")
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


def refuse_rig_options(args: argparse.Namespace) -> None:
    """The rig's options without ``--rig``: refused, saying what to add."""
    from core.errors import ParameterError
    given = [opt for opt, on in (("--channel", args.channel), ("--every-channel", args.every_channel),
                                 ("--real-time", args.real_time)) if on]
    if given:
        raise ParameterError(f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} for a rig: "
                             "add --rig (the example rig) or --rig RIG.toml")


def demo_rig(args: argparse.Namespace):
    """The rig the demo runs (on private loopback buses) and the channels it drives;
    ParameterError / RigError before anything starts."""
    from core.errors import ParameterError
    from rig.config import load_rig_file
    from rig.emulated import emulated_plant
    from rig.files import on_private_loopback
    given = [opt for opt, on in (("--config", args.config), ("--set", args.set), ("--bus", args.bus),
                                 ("--devices", getattr(args, "devices", None))) if on]
    if given:
        raise ParameterError(f"--rig takes the plants, buses and devices from the rig file (the "
                             f"demo puts its buses on private loopback channels): leave out "
                             f"{', '.join(given)}")
    if args.rig == "example":
        if not EXAMPLE_RIG.exists():
            raise ParameterError(f"no example rig here ({EXAMPLE_RIG}): give a rig file, "
                                 "stand demo --rig RIG.toml")
        path = EXAMPLE_RIG
    else:
        path = Path(args.rig)
    rig = on_private_loopback(load_rig_file(path), f"demo-{os.getpid()}")
    rig.path = path
    emulated_plant(rig)                 # every channel emulated, a physical structure
    if args.every_channel and args.channel:
        raise ParameterError("give --channel NAME or --every-channel, not both")
    names = rig.names if args.every_channel else (args.channel or rig.names[:1])
    for n in names:
        rig.channel(n)                  # an unknown name: refused with the rig's channels
    if len(set(names)) != len(names):
        raise ParameterError(f"--channel {', '.join(names)}: a channel named twice; each run drives one")
    if not (0 < args.amplitude_pct <= 100 and 0 < args.period_s <= 600 and 1 <= args.cycles <= 1000):
        raise ParameterError(f"meander ±{args.amplitude_pct:g} %, {args.period_s:g} s, {args.cycles} "
                             "periods: give an amplitude of 0-100 %, a period of 0-600 s and 1-1000 periods")
    return rig, names


def _rig(args: argparse.Namespace) -> int:
    """``--rig``: the rig's demo (module docstring)."""
    from analysis.reports.plots import plot_rig_forces
    from analysis.rig.estimate import estimate_rig
    from analysis.rig.load import read_rig_run
    from gateway import Gateway, GatewayConfig
    from core.durable import write_json
    from gateway.runs import TRUTH_FILE
    from plant_emulator.process import RigEmulatorProcess
    from rig.files import write_as_run

    rig, driven = demo_rig(args)
    source = _shown(rig.path)
    out = Path(args.out or f"runs/rig-demo-{dt.datetime.now():%Y%m%d-%H%M%S}")
    out.mkdir(parents=True, exist_ok=True)
    rig_file = out / RIG_FILE
    write_as_run(rig, rig_file, source, "stand demo --rig")
    lockstep = not args.real_time
    clock = "lockstep" if lockstep else "real time"
    print(f"emulator: rig {rig.name!r} from {source}, {len(rig.channels)} channels on "
          f"{len(rig.buses)} buses ({', '.join(f'{b.name} {b.spec}' for b in rig.buses)}), "
          f"{clock}, one separate process")
    experiment = Meander(args.amplitude_pct, args.period_s, args.cycles)
    runs = []
    t0 = time.monotonic()
    with RigEmulatorProcess(rig_file, lockstep=lockstep, seed=args.seed) as emulator:
        truth = emulator.truth()
        with Gateway(GatewayConfig(rig=rig, lockstep=lockstep)) as gw:
            for name in driven:
                result = gw.run(experiment, out / name, progress=None, channels=[name])
                write_json(result.path / TRUTH_FILE, truth)
                stats = result.outcome.stats
                stand_s = stats.cycles * rig.period_s
                print(f"run {name}: {result.status}, {stats.cycles:,} cycles = {stand_s:.1f} s of "
                      f"stand time in {stats.wall_s:.1f} s wall "
                      f"({stand_s / max(stats.wall_s, 1e-9):.1f}x real time)")
                if result.reason:
                    print(f"stopped early ({result.reason}): {result.outcome.message}")
                    return 1
                runs.append(result.path)
    wall = time.monotonic() - t0
    records = [read_rig_run(p) for p in runs]
    est = estimate_rig(records)
    print()
    for name, rec in zip(driven, records):
        print(moved_table(rig, rec, est, name, args.amplitude_pct, args.period_s))
        print()
    print(column_table(rig, est, driven))
    plot = plot_rig_forces(records, out / PLOT_FILE,
                           title=f"{rig.name}: meander ±{args.amplitude_pct:g} % of "
                                 f"{args.period_s:g} s on {', '.join(driven)}")
    print()
    print(f"{wall:.1f} s in all, emulator start and analysis included")
    print(f"demo directory: {out}/  (the rig file as run, one run per driven channel; "
          f"stand estimate {out} reads them)")
    print(f"  {RIG_FILE:18s} {rig_file.stat().st_size:>10,d} bytes")
    for p in runs:
        size = sum(f.stat().st_size for f in p.iterdir())
        print(f"  {p.name + '/':18s} {size:>10,d} bytes  ({', '.join(sorted(f.name for f in p.iterdir()))})")
    print(f"  {plot.name:18s} {plot.stat().st_size:>10,d} bytes  (every channel's force and command)")
    return 0


def _shown(path: Path) -> str:
    """A path as a user would type it here: relative to the working directory when inside it."""
    rel = os.path.relpath(path)
    return rel if not rel.startswith("..") else str(path)


def moved_table(rig, rec, est, driven: str, amplitude_pct: float, period_s: float) -> str:
    """How far each force moved in the run driven on ``driven``: peak to peak, and per half
    period of the meander (the median over its whole half periods, each shifted by the driven
    channel's estimated τ, of the force's change less the estimated trend Δ_i), beside the rig
    file's ``G_ij·u0·P/2``."""
    import numpy as np
    j = rig.names.index(driven)
    k = rec.names.index(driven)
    u, t = rec.u[k], rec.t
    switches = np.flatnonzero(np.diff(u) != 0) + 1
    tau = est.tau_s[est.names.index(driven)]
    shift = int(round((tau if math.isfinite(tau) else 0.0) / rec.dt))
    spans = [(a + shift, b + shift) for a, b in zip(switches[:-1], switches[1:]) if b + shift < len(t)]
    lines = [f"meander ±{amplitude_pct:g} % of {period_s:g} s on {driven}: how far each force moved",
             f"  {'channel':10s} {'bus':6s} {'peak to peak':>13s} {'per half period':>16s}   "
             f"rig file G_i,{driven}·u0·P/2"]
    for i, c in enumerate(rig.channels):
        r = rec.names.index(c.name)
        y = rec.y[r]
        delta = est.delta_kgf_s[est.names.index(c.name)]
        swings = [abs(y[b] - y[a] - delta * (t[b] - t[a])) for a, b in spans]
        half = float(np.median(swings)) if swings else math.nan
        swing = rig.G[i, j] * amplitude_pct * period_s / 2 if rig.G is not None else math.nan
        lines.append(f"  {c.name:10s} {c.bus:6s} {np.ptp(y):9.0f} kgf {half:12.0f} kgf   "
                     f"{swing:10.0f} kgf{'  (the driven valve)' if i == j else ''}")
    lines.append("  (peak to peak includes each channel's trend Δ over the run; the driven valve's "
                 "reversal boost adds to every swing of its column)")
    return "\n".join(lines)


def column_table(rig, est, driven: list[str]) -> str:
    """The estimated columns of G beside the rig file's, off by how much of the driven
    channel's own g."""
    level = round(100 * est.level)
    lines = [f"G estimated from the run{'s' if len(driven) > 1 else ''} (stand estimate), "
             f"kgf/(%·s), ±{level} % intervals, against the rig file's"]
    for name in driven:
        j = est.names.index(name)
        jr = rig.names.index(name)
        lines.append(f"  column {name}   {'estimated':>18s} {'rig file':>9s} {'off, % of g':>12s}")
        for i, row in enumerate(est.names):
            ir = rig.names.index(row)
            g, (lo, hi) = est.G[i, j], est.G_ci[i, j]
            true = rig.G[ir, jr]
            off = 100 * (g - true) / rig.G[jr, jr]
            lines.append(f"    {row:10s} {g:9.2f} ±{(hi - lo) / 2:<6.2f} {true:9.2f} {off:+11.2f} %")
        tau = est.tau_s[j]
        true_tau = rig.channel(name).plant.model.tau
        lines.append(f"    τ {name}: {tau * 1e3:.1f} ms (rig file {true_tau * 1e3:.1f} ms); Δ per row "
                     f"{', '.join(f'{d:.1f}' for d in est.delta_kgf_s)} kgf/s")
    note = est.physical
    lines.append(f"  physical check: {note.text}" if note.checked else
                 "  physical check: not made, the other columns are unknown (--every-channel "
                 "estimates them all)")
    lines += [f"  note: {n}" for n in est.notes if "moved in no run" not in n]
    return "\n".join(lines)
