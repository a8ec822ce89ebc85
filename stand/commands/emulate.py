"""``stand emulate``: impersonate the stand's valve and dynamometer nodes and the plant."""
from __future__ import annotations

import argparse
import contextlib
import math


from standbus.realtime import make_realtime, short_gil_slices

from .common import add_effects, add_bus, add_node_ids, add_rt_priority, parse_assignments


def register(sub) -> None:
    p = sub.add_parser("emulate", help="run the plant emulator (both CANopen nodes) on a bus",
                       description="Impersonate the servo-valve drive (CiA 408) and the dynamometer "
                                   "(CiA 404) with a plant model behind them, until interrupted.")
    add_bus(p)
    add_node_ids(p)
    p.add_argument("--lockstep", action="store_true",
                   help="advance the plant one communication period (0x1006) per SYNC instead of "
                        "on the wall clock")
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
    from plant.config import load_plant_config
    from plant_emulator import EmulatedStand, EmulatorOptions
    from plant_emulator.process import serve_until_signalled
    config = load_plant_config(args.config, args.model, parse_assignments(args.set))
    if not (0.01 <= args.step_ms <= 100 and math.isfinite(args.step_ms)):
        raise ModelError(f"--step-ms {args.step_ms:g} is out of range: use 0.01 to 100 ms")
    options = EmulatorOptions(lockstep=args.lockstep, seed=args.seed, valve_id=args.valve_id,
                              dynamometer_id=args.dynamometer_id, step_s=args.step_ms / 1000.0)
    scheduling = "lockstep"
    if not args.lockstep:   # before any thread starts: they all inherit it
        if not 0 <= args.rt_priority <= 99:
            raise ModelError(f"--rt-priority {args.rt_priority} is out of range: use 0 (off) to 99")
        result = make_realtime(args.rt_priority) if args.rt_priority else "off"
        scheduling = (f"SCHED_FIFO priority {args.rt_priority}" if not isinstance(result, str)
                      else f"ordinary scheduling ({result})")
    # real time: the thread answering SYNC gets the GIL within 0.2 ms (see short_gil_slices)
    with contextlib.nullcontext() if args.lockstep else short_gil_slices():
        stand = serve_until_signalled(
            lambda bus: EmulatedStand(bus, config, options), args.bus,
            lambda stand: f"valve node {args.valve_id}, dynamometer node {args.dynamometer_id} on "
                          f"{args.bus} ({'lockstep' if args.lockstep else 'real time'}, {scheduling}); "
                          f"model {config.model.spec}")
    flt = stand.frame_filter
    if flt.dropped or stand.valve.rpdo_length_errors or stand.valve.faults:
        print(f"emulator stopped: acceptance filter dropped {flt.dropped} frames "
              f"({flt.not_classic} error/remote/extended/FD, {flt.wrong_dlc} wrong DLC); "
              f"{stand.valve.rpdo_length_errors} RPDO length errors; {stand.valve.faults} valve faults",
              flush=True)
    return 0
