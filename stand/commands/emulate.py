"""``stand emulate``: impersonate the stand's valve and dynamometer nodes and the plant; with
``--rig RIG.toml``, every channel of a rig on every one of its buses, in one process (the
structure couples channels on different buses)."""
from __future__ import annotations

import argparse
import contextlib
import math

from dbc import profile as P
from standbus.realtime import make_realtime, short_gil_slices
from standbus.spec import DEFAULT_BUS

from .common import (add_bus, add_effects, add_node_ids, add_rt_priority, device_set,
                     parse_assignments)

#: the one-channel options a rig file replaces (option, argparse name, default)
_ONE_CHANNEL = (("--bus", "bus", DEFAULT_BUS), ("--valve-id", "valve_id", P.VALVE_NODE_ID),
                ("--dynamometer-id", "dynamometer_id", P.DYNAMOMETER_NODE_ID),
                ("--config", "config", None), ("--model", "model", None), ("--set", "set", None),
                ("--devices", "devices", None))


def register(sub) -> None:
    p = sub.add_parser("emulate", help="run the plant emulator (both CANopen nodes, or a whole rig) on a bus",
                       description="Impersonate the servo-valve drive (CiA 408) and the dynamometer "
                                   "(CiA 404) with a plant model behind them, until interrupted. "
                                   "With --rig, every channel of a rig on every bus of its file, "
                                   "coupled by its structure (docs/rig.md).")
    add_bus(p)
    add_node_ids(p)
    p.add_argument("--rig", metavar="RIG.toml",
                   help="emulate a rig: its buses, node ids, plants and structure from the rig "
                        "file (then leave out --bus, --valve-id, --dynamometer-id, --config, "
                        "--model and --set)")
    p.add_argument("--change", action="append", metavar="CHANNEL:FACTOR@FROM_S[+RAMP_S]",
                   help="with --rig: the structure at CHANNEL's attachment softens to FACTOR of "
                        "its stiffness from the stand time FROM_S (s since the emulator started; "
                        "in lockstep the run's own time for a first run), at once or linearly "
                        "over RAMP_S; e.g. inner:0.97@600 (a crack). Repeatable, after the rig "
                        "file's [[structure.change]] (docs/rig.md)")
    p.add_argument("--fault", action="append", metavar="KIND:CHANNEL[:KGF]@T[+D]",
                   help="a fault the stand makes at stand time T (s, the clock of --change): "
                        "spike:CHANNEL:KGF@T, its dynamometer reads KGF more once; "
                        "heartbeat:CHANNEL@T+D, its valve sends no heartbeat for D s. A stand's "
                        "channel is 'stand'. Repeatable (plant_emulator/scheduled_faults.py)")
    p.add_argument("--unconfigured", action="append", default=[], metavar="CHANNEL",
                   help="CHANNEL's valve and dynamometer start as fresh devices without a node id: "
                        "silent but for LSS (CiA 305) until a master gives them one, as `stand "
                        "bench scan` does. A stand's channel is 'stand'. Repeatable")
    p.add_argument("--lockstep", action="store_true",
                   help="advance the plant one communication period (0x1006) per SYNC instead of "
                        "on the wall clock (a rig: per cycle, once every bus's SYNC came)")
    p.add_argument("--config", metavar="PLANT.toml", help="plant configuration (model, sensor, initial force)")
    p.add_argument("--model", metavar="SPEC", help="which effects, e.g. base+reversal+lag (default: base+reversal)")
    p.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="override a parameter: g=130, tau=0.04, reversal.boost=0, sensor.noise_kgf=1, "
                        "initial.force_kgf=500 (repeatable)")
    p.add_argument("--seed", type=int, default=None, help="seed of the measurement noise (reproducible runs)")
    add_effects(p)
    p.add_argument("--step-ms", type=float, default=0.5, help="plant integration step, ms (default %(default)s)")
    add_rt_priority(p, "real time: run the emulator (the stand's hardware)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from plant.params import ModelError
    from plant_emulator import EmulatorOptions
    if not (0.01 <= args.step_ms <= 100 and math.isfinite(args.step_ms)):
        raise ModelError(f"--step-ms {args.step_ms:g} is out of range: use 0.01 to 100 ms")
    options = EmulatorOptions(lockstep=args.lockstep, seed=args.seed, valve_id=args.valve_id,
                              dynamometer_id=args.dynamometer_id, step_s=args.step_ms / 1000.0,
                              devices=None if args.rig else device_set(args),
                              unconfigured=tuple(args.unconfigured))
    if args.rig:
        given = [opt for opt, name, default in _ONE_CHANNEL if getattr(args, name) != default]
        if given:
            raise ModelError(f"--rig takes the buses, node ids and plants from the rig file: "
                             f"leave out {', '.join(given)}")
        from rig.config import load_rig_file, parse_change, with_changes
        rig = load_rig_file(args.rig)
        rig = with_changes(rig, [parse_change(text, rig) for text in args.change or ()])
        options.faults = _faults(args, rig.names)
        run = lambda clock: _serve_rig(rig, options, clock)        # noqa: E731
    else:
        if args.change:
            raise ModelError("--change changes a rig's structure: give it with --rig RIG.toml")
        from plant.config import load_plant_config
        config = load_plant_config(args.config, args.model, parse_assignments(args.set))
        from plant_emulator.stand import BUS_NAME       # the stand's one channel
        options.faults = _faults(args, [BUS_NAME])
        if set(args.unconfigured) - {BUS_NAME}:
            raise ModelError(f"--unconfigured {', '.join(args.unconfigured)}: a stand's one channel "
                             f"is '{BUS_NAME}' (a rig's channels are named in its file)")
        run = lambda clock: _serve_stand(args, config, options, clock)   # noqa: E731
    scheduling = "lockstep"
    if not args.lockstep:   # before any thread starts: they all inherit it
        if not 0 <= args.rt_priority <= 99:
            raise ModelError(f"--rt-priority {args.rt_priority} is out of range: use 0 (off) to 99")
        result = make_realtime(args.rt_priority) if args.rt_priority else "off"
        scheduling = (f"SCHED_FIFO priority {args.rt_priority}" if not isinstance(result, str)
                      else f"ordinary scheduling ({result})")
    # real time: the thread answering SYNC gets the GIL within 0.2 ms (see short_gil_slices)
    with contextlib.nullcontext() if args.lockstep else short_gil_slices():
        stand = run(f"{'lockstep' if args.lockstep else 'real time'}, {scheduling}")
    buses = stand.buses
    dropped = sum(b.frame_filter.dropped for b in buses)
    length_errors = sum(ch.valve.rpdo_length_errors for ch in stand.channels)
    faults = sum(ch.valve.faults for ch in stand.channels)
    discarded = sum(n.sync_window_discards for ch in stand.channels for n in ch.nodes)
    if dropped or length_errors or faults or discarded:
        not_classic = sum(b.frame_filter.not_classic for b in buses)
        wrong_dlc = sum(b.frame_filter.wrong_dlc for b in buses)
        print(f"emulator stopped: acceptance filter dropped {dropped} frames "
              f"({not_classic} error/remote/extended/FD, {wrong_dlc} wrong DLC); "
              f"{length_errors} RPDO length errors; {faults} valve faults; "
              f"{discarded} TPDOs discarded past their SYNC's window (0x1007: the emulator "
              "lagged)", flush=True)
    return 0


def _faults(args: argparse.Namespace, names: list[str]) -> tuple:
    from plant_emulator.scheduled_faults import parse_fault
    return tuple(parse_fault(text, names) for text in args.fault or ())


def _fault_text(options, names: list[str]) -> str:
    return "".join(f"; fault: {f.text(names)}" for f in options.faults)


def _serve_stand(args: argparse.Namespace, config, options, clock: str):
    from plant_emulator import EmulatedStand
    from plant_emulator.process import serve_until_signalled
    return serve_until_signalled(
        lambda bus: EmulatedStand(bus, config, options), args.bus,
        lambda stand: f"valve node {args.valve_id}, dynamometer node {args.dynamometer_id} on "
                      f"{args.bus} ({clock}); model {config.model.spec}"
                      + _devices_text(options.devices)
                      + _fault_text(options, [stand.channel.name]))


def _devices_text(devices) -> str:
    return "" if devices is None else f"; devices {devices.name} ({devices.where})"


def _serve_rig(rig, options, clock: str):
    from plant_emulator.emulated_rig import EmulatedRig
    from plant_emulator.process import serve_until_signalled
    from rig.emulated import emulated_plant
    emulated_plant(rig)          # refused before any bus opens: no plant, not physical, ...
    buses = "; ".join(
        f"{b.name} {b.spec}: " + ", ".join(f"{c.name} (valve {c.valve_id}, dynamometer "
                                           f"{c.dynamometer_id})" for c in rig.channels_on(b.name))
        for b in rig.buses)
    return serve_until_signalled(
        lambda opened: EmulatedRig.from_rig(opened, rig, options),
        {b.name: b.spec for b in rig.buses},
        lambda stand: f"rig {rig.name!r}, {len(rig.channels)} channel(s) on {len(rig.buses)} "
                      f"bus(es): {buses} ({clock}); structure from "
                      f"{rig.structure_from}" + "".join(f"; change {rig.change_text(c)}"
                                                        for c in rig.changes)
                      + _fault_text(options, rig.names))
