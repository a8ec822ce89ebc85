"""``stand``: the test-stand gateway's command line.

Each sub-command lives in :mod:`stand.commands` as a module with ``register(subparsers)``; user
mistakes (bad parameters, missing nodes, unreadable files) are printed as one clear message and
exit code 2, never as a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import os
import pkgutil
import sys

from stand import commands

from core.errors import StandError
from plant.params import ModelError
from standbus.spec import BusSpecError



def command_modules() -> list[str]:
    """Every module in :mod:`stand.commands` that defines ``register`` is a sub-command."""
    return sorted(m.name for m in pkgutil.iter_modules(commands.__path__) if m.name != "common")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="stand",
        description="Scriptable CANopen gateway, plant emulator and model diagnosis for "
                    "servo-hydraulic force-loading stands.")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in command_modules():
        module = importlib.import_module(f"stand.commands.{name}")
        if hasattr(module, "register"):
            module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    try:
        if hasattr(args, "plugin_sources"):   # the command takes models: plug-ins first
            from stand.commands.common import load_effects
            load_effects(args)
        return int(args.func(args) or 0)
    except (StandError, ModelError, BusSpecError) as exc:
        print(f"stand {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"stand {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `stand estimate --json | head`: the reader left, not an error
        try:
            sys.stdout = open(os.devnull, "w")
        except OSError:
            pass
        return 0
