"""``stand pcap CAPTURE [-o OUT.pcap]``: a bus capture as a pcap for Wireshark's CANopen dissector."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gateway.errors import StandError


def register(sub) -> None:
    from captures.formats import SUFFIXES
    p = sub.add_parser("pcap", help="write a bus capture as a pcap (SocketCAN frames) for Wireshark",
                       description="Write a bus capture as a pcap of SocketCAN frames (link type 227), "
                                   "which Wireshark and tshark open and decode with their CANopen "
                                   "dissector: tshark -r OUT.pcap -d can.subdissector,canopen. "
                                   f"Formats: {', '.join(SUFFIXES)} (also .gz). A pcap holds one bus: "
                                   "a capture of several is written one channel at a time.",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("capture", metavar="CAPTURE", help="capture file, or a rig run directory (with "
                                                      "--channel NAME: that channel's bus capture)")
    p.add_argument("-o", "--out", metavar="OUT.pcap",
                   help="pcap file to write (default: the capture's name with .pcap, beside it)")
    p.add_argument("--channel", metavar="NAME",
                   help="a capture: only this bus channel as the capture names it (e.g. can1); "
                        "needed when it holds several. A rig run directory: the rig channel whose "
                        "bus to write")
    p.add_argument("--skip-damaged", action="store_true",
                   help="go on past damaged lines (candump) or objects (BLF) instead of stopping at "
                        "the first; what was skipped is counted")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from captures.pcap import capture_to_pcap
    capture, channel = Path(args.capture), args.channel
    if capture.is_dir():
        from gateway.runs import CAPTURE_FILE, channel_capture, is_run_dir
        if not is_run_dir(capture):
            raise StandError(f"{capture} is a directory but not a run (no run.json)")
        if (capture / CAPTURE_FILE).exists() and channel is None:     # a one-channel run
            capture = capture / CAPTURE_FILE
        else:
            capture, _nodes = channel_capture(capture, channel)
            capture, channel = Path(capture), None
    out = Path(args.out) if args.out else _default_out(capture)
    if out.resolve() == capture.resolve():
        raise StandError(f"-o {out}: that is the capture itself; give another file")
    result = capture_to_pcap(capture, out, channel=channel,
                             on_damage="skip" if args.skip_damaged else "stop")
    print(result.summary())
    if result.read.damaged:
        print(f"  note: skipped {result.read.damaged} damaged lines or objects, the first at "
              f"{result.read.first_damage}")
    print(f"-> {out}  (tshark -r {out} -d can.subdissector,canopen)")
    if result.damage is not None:
        print(f"stand pcap: error: {result.damage}; everything before it was written into {out}",
              file=sys.stderr)
        return 1
    return 0


def _default_out(capture: Path) -> Path:
    name = capture.name
    if name.lower().endswith(".gz"):
        name = name[:-3]
    return capture.with_name(Path(name).stem + ".pcap")
