"""``stand decode CAPTURE -o RUN``: a bus capture → the run format the gateway records."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gateway.errors import StandError


def register(sub) -> None:
    from captures.formats import SUFFIXES
    p = sub.add_parser("decode", help="decode a bus capture (candump .log, .blf, .asc, ...) into a run",
                       description="Decode a bus capture with the DBC into the run format the gateway "
                                   "records (run.json + signals.parquet: t, u, y, cycle, y_counts, ...), "
                                   "so every analysis command can use it. Streams: any capture length "
                                   f"in bounded memory. Formats: {', '.join(SUFFIXES)} (also .gz).",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("capture", metavar="CAPTURE", help="capture file, or a rig run directory (with "
                                                      "--channel NAME: that channel's capture)")
    p.add_argument("-o", "--out", metavar="RUN",
                   help="run directory to write (several runs in the capture: RUN/run-000, ...); "
                        "without it only the summary is printed")
    p.add_argument("--dbc", metavar="DBC", help="DBC describing the frames (default: dbc/stand.dbc)")
    p.add_argument("--period-ms", type=float, metavar="MS",
                   help="control period, if the capture does not say it (default: the 0x1006 SDO "
                        "download in the capture, else the median SYNC interval)")
    p.add_argument("--clock", choices=("lockstep", "realtime"),
                   help="how the run was clocked (default: lockstep if SYNCs came faster than the period)")
    p.add_argument("--channel", metavar="NAME",
                   help="a capture: only frames of this bus channel as the capture names it (e.g. "
                        "can0; default: the channel of the stand's first SYNC). A rig run "
                        "directory: the rig channel to decode (its bus's capture, its node ids)")
    p.add_argument("--nodes", metavar="VALVE,DYN",
                   help="read the channel whose valve and dynamometer have these node ids (a "
                        "rig's bus; default 1,2 as in the stand's DBC)")
    p.add_argument("--run", type=int, metavar="N", help="only run N (0-based) of a capture holding several")
    p.add_argument("--partition-rows", type=int, metavar="N",
                   help="write signals.parquet as a directory of part files of at most N rows each")
    p.add_argument("--frames", metavar="DIR",
                   help="also write every decoded message as a Parquet dataset DIR/<message>/ "
                        "(works with any DBC, also one that does not describe the stand)")
    p.add_argument("--skip-damaged", action="store_true",
                   help="skip damaged lines (candump logs) or containers and objects (BLF) and go "
                        "on, instead of stopping at the first; what was skipped is counted and the "
                        "first one named")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from captures import decode_capture
    from captures.decode import DecodeOptions
    if args.period_ms is not None and not args.period_ms > 0:
        raise StandError(f"--period-ms {args.period_ms}: give a positive period in ms, e.g. 2")
    if args.partition_rows is not None and args.partition_rows < 1:
        raise StandError("--partition-rows must be at least 1")
    capture, bus_channel, nodes = args.capture, args.channel, parse_nodes(args.nodes)
    if Path(capture).is_dir():
        from gateway.runs import channel_capture, is_run_dir
        if not is_run_dir(capture):
            raise StandError(f"{capture} is a directory but not a run (no run.json)")
        if nodes is not None:
            raise StandError("--nodes: a rig run knows its channels' node ids; give --channel NAME")
        capture, nodes = channel_capture(capture, args.channel)
        bus_channel = None
    options = DecodeOptions(dbc=args.dbc, period_s=None if args.period_ms is None else args.period_ms / 1000.0,
                            clock=args.clock, channel=bus_channel, run=args.run,
                            on_damage="skip" if args.skip_damaged else "stop", nodes=nodes)
    out = Path(args.out) if args.out else None
    created = out is not None and not out.exists()
    result = decode_capture(capture, out=out, collect=False, partition_rows=args.partition_rows,
                            frames_dir=args.frames, options=options,
                            progress=not args.no_progress and sys.stderr.isatty())
    print(result.summary())
    for note in result.notes():
        print(f"  note: {note}")
    if out is not None and not result.outputs and created:
        try:
            out.rmdir()
        except OSError:
            pass
    if not result.runs_with_rows() and (out is not None or result.frames_dir is None):
        where = f" before the damage at {result.damage.position}" if result.damage else ""
        raise StandError(f"{capture}: no control cycles found{where} (no SYNC followed by an "
                         "RPDO with ControlWord 7): is this a capture of the stand, and is --dbc right?")
    if args.run is not None and not result.outputs and out is not None:
        raise StandError(f"--run {args.run}: the capture holds runs "
                         f"{', '.join(str(r.index) for r in result.runs_with_rows())}")
    for path in result.outputs:
        print(f"-> {path}")
    if result.frames_dir is not None:
        print(f"-> {result.frames_dir}/<message>/ (one Parquet dataset per message)")
    if result.damage is not None:
        print(f"stand decode: error: {result.damage}; everything before it was decoded"
              + (f" into {', '.join(map(str, result.outputs))}" if result.outputs else ""), file=sys.stderr)
        return 1
    return 0


def parse_nodes(text: str | None) -> tuple[int, int] | None:
    """``"3,4"`` → ``(3, 4)`` (valve, dynamometer node ids)."""
    if text is None:
        return None
    try:
        valve, dyn = (int(x) for x in text.split(","))
    except ValueError:
        raise StandError(f"--nodes {text!r}: give the valve's and the dynamometer's node ids, e.g. "
                         "--nodes 3,4") from None
    if not (1 <= valve <= 127 and 1 <= dyn <= 127) or valve == dyn:
        raise StandError(f"--nodes {text}: two different node ids from 1 to 127")
    return valve, dyn
