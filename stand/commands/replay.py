"""``stand replay CAPTURE --bus SPEC``: put a capture back on a bus (like can-utils' canplayer),
or ``--as-plant``: answer a gateway as the stand's two nodes with the recorded force."""
from __future__ import annotations

import argparse
import signal
import threading

from gateway.errors import StandError
from standbus import open_bus

from .common import add_bus, add_node_ids


def _ids(text: str) -> set[int]:
    try:
        return {int(x, 16) for x in text.split(",") if x.strip()}
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give hex ids separated by commas, e.g. 182,181") from None


def register(sub) -> None:
    p = sub.add_parser("replay", help="put a capture back on a bus, or replay it as the plant",
                       description="Send a capture's frames on a bus with their original timing "
                                   "(--speed scales it, --asap sends as fast as possible), like "
                                   "can-utils' canplayer. With --as-plant, impersonate the valve and "
                                   "the dynamometer instead: the dynamometer answers the k-th SYNC of "
                                   "each run with the k-th recorded force (regression tests of the "
                                   "gateway against recorded bench behaviour).")
    p.add_argument("capture", metavar="CAPTURE",
                   help="capture file (.log, .blf, .asc, ...), or a rig run directory with --channel")
    p.add_argument("--channel", metavar="NAME",
                   help="a rig run: the channel to replay (its bus's capture; --as-plant: its "
                        "recorded force, read at its node ids)")
    p.add_argument("--nodes", metavar="VALVE,DYN",
                   help="--as-plant on a capture of a rig's bus: the node ids of the channel whose "
                        "force to replay (default 1,2)")
    add_bus(p)
    timing = p.add_mutually_exclusive_group()
    timing.add_argument("--speed", type=float, default=1.0, metavar="X",
                        help="play X times faster than recorded (default %(default)s)")
    timing.add_argument("--asap", action="store_true", help="send as fast as the bus takes them")
    p.add_argument("--max-gap", type=float, metavar="S",
                   help="shorten pauses longer than S seconds to S (capture time)")
    p.add_argument("--loop", type=int, default=1, metavar="N", help="play the capture N times (default 1)")
    p.add_argument("--ids", type=_ids, metavar="ID,...", help="only these (hex) ids, e.g. 182,181")
    p.add_argument("--as-plant", action="store_true",
                   help="be the stand's two CANopen nodes; the dynamometer replays the recorded force")
    p.add_argument("--run", type=int, metavar="N", help="--as-plant: which run of the capture (0-based)")
    add_node_ids(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from captures import iter_frames
    from captures.frames import CaptureDamaged
    from captures.replay import Replayer
    if args.loop < 1:
        raise StandError("--loop must be at least 1")
    from pathlib import Path
    from .decode import parse_nodes
    args.read_nodes = parse_nodes(args.nodes)
    if Path(args.capture).is_dir():
        from gateway.runs import channel_capture
        if args.read_nodes is not None:
            raise StandError("--nodes: a rig run knows its channels' node ids; give --channel NAME")
        capture, args.read_nodes = channel_capture(args.capture, args.channel)
        args.capture = str(capture)
    elif args.channel is not None:
        raise StandError("--channel names a channel of a rig run directory; for a capture of a "
                         "rig's bus give --nodes VALVE,DYN")
    if args.as_plant:
        return as_plant(args)
    bus = open_bus(args.bus)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        replayer = Replayer(bus, speed=None if args.asap else args.speed, max_gap_s=args.max_gap,
                            ids=args.ids)
        for _ in range(args.loop):
            try:
                replayer.play(iter_frames(args.capture), stop=stop.is_set)
            except CaptureDamaged as exc:
                print(f"stand replay: error: {exc.damage}; the frames before it were sent")
                return 1
            if stop.is_set():
                break
    finally:
        bus.shutdown()
    s = replayer.stats.as_dict()
    late = f", late p99 {s['late_ms_p99']:.3f} ms" if "late_ms_p99" in s else ""
    print(f"replayed {s['sent']:,} of {s['frames']:,} frames in {s['wall_s']:.2f} s "
          f"({s['capture_span_s']:.2f} s of capture){late}"
          + (f"; {s['skipped_error_frames']} error frames skipped" if s["skipped_error_frames"] else "")
          + (f"; {s['send_errors']} send errors ({s['first_send_error']})" if s["send_errors"] else ""))
    return 1 if s["send_errors"] else 0


def as_plant(args: argparse.Namespace) -> int:
    from captures.trace import force_trace
    from plant_emulator.replayed import ReplayedStand
    from plant_emulator import EmulatorOptions
    from plant_emulator.process import serve_until_signalled
    trace = force_trace(args.capture, run=args.run, nodes=args.read_nodes)
    options = EmulatorOptions(lockstep=True, valve_id=args.valve_id, dynamometer_id=args.dynamometer_id)
    stand = serve_until_signalled(
        lambda bus: ReplayedStand(bus, trace, options), args.bus,
        lambda stand: f"replaying {len(trace):,} recorded force samples (run {trace.run}, "
                      f"{trace.period_s * 1e3:g} ms) of {args.capture} as valve node {args.valve_id} "
                      f"and dynamometer node {args.dynamometer_id} on {args.bus}")
    print(f"replayed the recording in {stand.runs_started} run(s)"
          + (f"; {stand.exhausted_syncs} SYNC(s) after its end got the last sample" if stand.exhausted_syncs else ""))
    for w in dict.fromkeys(stand.warnings):
        print(f"warning: {w}")
    return 0
