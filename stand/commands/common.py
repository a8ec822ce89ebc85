"""Options shared by several sub-commands."""
from __future__ import annotations

import argparse

from dbc import profile as P
from gateway import GatewayConfig, SafetyLimits
from gateway.errors import ParameterError
from standbus import DEFAULT_BUS


def add_bus(p: argparse.ArgumentParser, default: str | None = DEFAULT_BUS) -> None:
    p.add_argument("--bus", default=default, metavar="SPEC",
                   help="python-can bus as INTERFACE:CHANNEL[,key=value...], e.g. "
                        "udp_loopback:stand0 (default: %(default)s), socketcan:vcan0, "
                        "pcan:PCAN_USBBUS1,bitrate=1000000")


def add_node_ids(p: argparse.ArgumentParser) -> None:
    p.add_argument("--valve-id", type=int, default=P.VALVE_NODE_ID, help="servo-valve node id (default %(default)s)")
    p.add_argument("--dynamometer-id", type=int, default=P.DYNAMOMETER_NODE_ID,
                   help="dynamometer node id (default %(default)s)")


def add_gateway(p: argparse.ArgumentParser) -> None:
    add_bus(p)
    add_node_ids(p)
    p.add_argument("--period-ms", type=float, default=2.0, help="control period, ms (default %(default)s)")
    p.add_argument("--lockstep", action="store_true",
                   help="send the next SYNC as soon as a cycle is done (needs the emulator with --lockstep)")
    p.add_argument("--force-limit", type=float, default=9500.0, metavar="KGF",
                   help="stop the run (safe state) beyond ±this force, kgf (default %(default)s)")
    p.add_argument("--boot-timeout", type=float, default=5.0, metavar="S",
                   help="seconds to wait for the nodes' boot-up (default %(default)s)")


def gateway_config(args: argparse.Namespace) -> GatewayConfig:
    return GatewayConfig(bus=args.bus, valve_id=args.valve_id, dynamometer_id=args.dynamometer_id,
                         period_s=args.period_ms / 1000.0, lockstep=args.lockstep,
                         boot_timeout_s=args.boot_timeout,
                         limits=SafetyLimits(force_limit_kgf=args.force_limit))


def parse_assignments(items: list[str] | None, what: str = "--set") -> dict[str, float]:
    """``["g=100", "reversal.boost=0"]`` → ``{"g": 100.0, "reversal.boost": 0.0}``."""
    out: dict[str, float] = {}
    for item in items or []:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise ParameterError(f"{what} {item!r}: write NAME=VALUE, e.g. {what} g=120")
        try:
            out[key.strip()] = float(value)
        except ValueError:
            raise ParameterError(f"{what} {item!r}: {value!r} is not a number") from None
    return out
