"""Run every benchmark and print one table (``scripts/bench [--quick] [NAME ...]``)."""
from __future__ import annotations

import argparse
import datetime as dt
import importlib
import inspect
import os
import platform
import sys
import time
import traceback

from .table import Row, format_table



def discover() -> dict[str, str]:
    """Every module in :mod:`benchmarks` with a ``run(quick)`` function, with its summary (the
    first line of its docstring). Order: the module's ``ORDER`` number, then name."""
    import pkgutil
    import benchmarks
    found = []
    for m in pkgutil.iter_modules(benchmarks.__path__):
        if m.name in ("runner", "table"):
            continue
        mod = importlib.import_module(f"benchmarks.{m.name}")
        if callable(getattr(mod, "run", None)):
            doc = (mod.__doc__ or m.name).strip().splitlines()[0]
            found.append((getattr(mod, "ORDER", 50), m.name, doc))
    return {name: doc for _, name, doc in sorted(found)}


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="scripts/bench", description=__doc__)
    ap.add_argument("--quick", action="store_true", help="small sizes: a smoke run under a minute")
    ap.add_argument("--seed", type=int, metavar="N",
                    help="the seed of the benchmarks that draw random moments (endurance), to repeat a run "
                         "whose rows printed it (default: a fresh one)")
    ap.add_argument("names", nargs="*",
                    help="benchmarks to run (default: all modules in benchmarks/)")
    args = ap.parse_args(argv)
    BENCHMARKS = discover()
    # a name as written on the command line: rig-identify is the module rig_identify
    names = [n.replace("-", "_") for n in args.names] or list(BENCHMARKS)
    unknown = [n for n in names if n not in BENCHMARKS]
    if unknown:
        ap.error(f"unknown benchmark(s) {', '.join(unknown)}; choose from {', '.join(BENCHMARKS)}")
    rows: list[Row] = []
    failed = 0
    for name in names:
        t0 = time.monotonic()
        print(f"running {name} ({BENCHMARKS[name]}) ...", file=sys.stderr, flush=True)
        try:
            module = importlib.import_module(f"benchmarks.{name}")
            seeded = args.seed is not None and "seed" in inspect.signature(module.run).parameters
            rows += module.run(args.quick, seed=args.seed) if seeded else module.run(args.quick)
        except Exception as exc:  # a broken benchmark is reported, the others still run
            failed += 1
            traceback.print_exc()
            rows.append(Row(name, "FAILED", note=f"{type(exc).__name__}: {exc}"))
        print(f"  {name}: {time.monotonic() - t0:.1f} s", file=sys.stderr)
    print(f"Benchmarks {'(quick) ' if args.quick else ''}on {dt.date.today()}, {machine()}")
    print()
    print(format_table(rows))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
