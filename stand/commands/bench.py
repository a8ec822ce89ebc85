"""``stand bench scan``: find the devices on a bus (and give fresh ones a node id by LSS);
``stand bench dcf``: write the configuration the gateway gives each node as a DCF."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .common import add_bus, add_node_ids, device_set


def register(sub) -> None:
    p = sub.add_parser("bench", help="find the devices on a bench (scan, LSS) and write their "
                                     "configuration as DCF files",
                       description="The devices of a bench: `scan` lists every node that answers "
                                   "and gives fresh ones a node id by LSS; `dcf` writes the "
                                   "configuration the gateway gives each node as a DCF "
                                   "(docs/devices.md).")
    bench = p.add_subparsers(dest="bench_command", metavar="{scan,dcf}", required=True)

    s = bench.add_parser("scan", help="list every node on the bus and match it to your device files",
                         description="Every node that answers an SDO upload of 0x1000 and its "
                                     "identity 0x1018 (node ids 1-127, all at once), and with LSS "
                                     "(CiA 305 fastscan) every fresh device without a node id, "
                                     "given the next free one. Each is matched against the device "
                                     "files given (and the emulated pair); the table is printed "
                                     "with a skeleton rig file of the channels found.")
    add_bus(s)
    s.add_argument("--devices", action="append", default=[], metavar="DEVICES.toml",
                   help="a device file to match the nodes against (repeatable; the emulated pair "
                        "is always known)")
    s.add_argument("--no-lss", action="store_true",
                   help="do not look for devices without a node id (LSS)")
    s.add_argument("--first-id", type=int, default=1, metavar="ID",
                   help="LSS gives fresh devices free node ids from ID on (default %(default)s)")
    s.add_argument("--timeout-ms", type=float, default=300.0, metavar="MS",
                   help="how long to wait for the SDO answers of each round (default %(default)g)")
    s.add_argument("--lss-timeout-ms", type=float, default=50.0, metavar="MS",
                   help="how long to wait for an LSS answer (default %(default)g; fastscan asks "
                        "~130 times)")
    s.add_argument("--rig-out", metavar="RIG.toml",
                   help="write the skeleton rig file there (default: print it)")
    s.set_defaults(func=scan_main)

    d = bench.add_parser("dcf", help="write each node's configuration as a DCF (CiA 306)",
                         description="The configuration the gateway writes at start-up (PDOs, "
                                     "error control, period, device mode), one DCF per node, "
                                     "without a bus: for a rig file every channel's nodes, else "
                                     "the stand's (--devices, --valve-id, --dynamometer-id). The "
                                     "stand's DBC for the devices goes beside them.")
    d.add_argument("--rig", metavar="RIG.toml", help="every channel of this rig")
    add_node_ids(d)
    d.add_argument("--period-ms", type=float, default=2.0, metavar="MS",
                   help="control period, ms (default %(default)s; a rig: its file's)")
    d.add_argument("--heartbeat-ms", type=int, default=100, metavar="MS",
                   help="heartbeat or guard time, ms (default %(default)s; a rig: its file's)")
    d.add_argument("--rpdo-timeout", type=int, default=100, metavar="MS",
                   help="the valve's RPDO timeout, ms (default %(default)s)")
    d.add_argument("--bitrate", type=int, default=1_000_000, help="bit/s (default %(default)s; a rig: each bus's)")
    d.add_argument("-o", "--out", required=True, metavar="DIR", help="directory for the DCF files")
    d.set_defaults(func=dcf_main)


def scan_main(args: argparse.Namespace) -> int:
    import canopen

    from core.errors import ParameterError
    from devices import default_devices, load_device_set
    from gateway.bench import result_table, scan_bench, skeleton_rig
    from standbus import BusSpecError, open_bus
    if not 1 <= args.first_id <= 127:
        raise ParameterError(f"--first-id {args.first_id}: a node id is 1..127")
    for name, value in (("--timeout-ms", args.timeout_ms), ("--lss-timeout-ms", args.lss_timeout_ms)):
        if not 1 <= value <= 10_000:
            raise ParameterError(f"{name} {value:g}: give 1 to 10000 ms")
    sets = [load_device_set(path) for path in args.devices] + [default_devices()]
    try:
        bus = open_bus(args.bus)
    except BusSpecError as exc:
        raise ParameterError(str(exc)) from None
    network = canopen.Network(bus)
    network.connect()
    try:
        print(f"stand bench scan: {args.bus}: SDO to node ids 1-127"
              + ("" if args.no_lss else ", LSS fastscan for devices without a node id"), flush=True)
        result = scan_bench(network, sets, lss=not args.no_lss, first_id=args.first_id,
                            timeout_s=args.timeout_ms / 1e3, lss_timeout_s=args.lss_timeout_ms / 1e3,
                            bus=args.bus)
    finally:
        network.disconnect()
    if not result.nodes:
        print(f"no node answered on {args.bus} within {args.timeout_ms:g} ms"
              + ("" if args.no_lss else ", and no device without a node id answered LSS")
              + ": is the bus right (and its bit rate), are the devices powered?", file=sys.stderr)
        return 1
    print(result_table(result))
    print(f"{len(result.nodes)} node(s), {result.lss_found} given a node id by LSS, in "
          f"{result.seconds:.1f} s")
    text, left = skeleton_rig(result, args.bus,
                              base=Path(args.rig_out).resolve().parent if args.rig_out else None)
    if args.rig_out:
        Path(args.rig_out).write_text(text)
        print(f"skeleton rig file: {args.rig_out} (stand rig check {args.rig_out})")
    else:
        print()
        print(text, end="")
    return 0


def dcf_main(args: argparse.Namespace) -> int:
    from devices import default_devices, plan_node
    from devices.dbcfile import stand_dbc
    from devices.dcf import write_dcf
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.rig:
        from rig.config import load_rig_file
        rig = load_rig_file(args.rig)
        bitrates = {b.name: b.bitrate for b in rig.buses}
        channels = [(c.name, c.valve_id, c.dynamometer_id, c.devices, bitrates[c.bus])
                    for c in rig.channels]
        period_s, heartbeat_ms = rig.period_s, rig.heartbeat_ms
    else:
        channels = [("stand", args.valve_id, args.dynamometer_id,
                     device_set(args) or default_devices(), args.bitrate)]
        period_s, heartbeat_ms = args.period_ms / 1e3, args.heartbeat_ms
    for name, valve_id, dyn_id, devices, bitrate in channels:
        plans = [plan_node(d, nid, period_s=period_s, heartbeat_ms=heartbeat_ms,
                           rpdo_timeout_ms=args.rpdo_timeout if d is devices.valve else 0)
                 for d, nid in ((devices.valve, valve_id), (devices.dynamometer, dyn_id))]
        for plan in plans:
            path = write_dcf(plan, out / f"{name}-{plan.kind}-{plan.node_id}.dcf", bitrate)
            print(f"{path}: {plan.device.name}, node {plan.node_id}: "
                  + "; ".join(f"{p.name} {', '.join(p.describe()['objects'])}"
                              for p in (plan.rpdo, plan.tpdo) if p is not None))
            for note in plan.notes:
                print(f"  note: {note}")
        if not devices.is_default:
            from devices.units import FULL_SCALE_DEFAULT
            dbc = out / f"{name}.dbc"
            dbc.write_text(stand_dbc(plans[0], plans[1], devices.dynamometer.nominal_kgf_per_count(),
                                     devices.valve.setpoint_full_scale or FULL_SCALE_DEFAULT))
            print(f"{dbc}: the stand's DBC for these devices (the force as the device file or "
                  "the EDS defaults give its unit)")
    return 0
