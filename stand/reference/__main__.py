"""``python -m stand.reference [DIR] [--check]``: write the reference pages into DIR (default
docs/reference), or with ``--check`` list those that differ from the code and exit 1."""
from __future__ import annotations

import argparse
import sys

from . import stale, write


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m stand.reference",
                                description="Generate the reference pages (docs/reference/) from the code.")
    p.add_argument("directory", nargs="?", default="docs/reference", metavar="DIR",
                   help="where the pages go (default %(default)s)")
    p.add_argument("--check", action="store_true",
                   help="write nothing; list the pages that differ from the code, exit 1 if any")
    args = p.parse_args(argv)
    if args.check:
        differ = stale(args.directory)
        for name in differ:
            print(f"{args.directory}/{name}: differs from the code", file=sys.stderr)
        if differ:
            print(f"regenerate: python -m stand.reference {args.directory}", file=sys.stderr)
        return 1 if differ else 0
    for path in write(args.directory):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
