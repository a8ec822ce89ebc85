"""The diagnosis's confusion matrix: every catalogue effect alone and every pair with the reversal boost and with a valve lag, each simulated by a law written apart from the catalogue's.

Each cell is one ``stepwise`` diagnosis of 70 s of records (the paper's four meanders, or three
P-feedback runs) of the independent simulator (tests/support/independent_stand.py), 2 or 4 kgf
of noise; judged by tests/support/confusion.py (the true effects or their listed equivalents
and nothing else, or said precisely which cannot be told apart). The cells run in the
project's executor (:func:`analysis.executors.local_executor`, one worker per core, one
process per cell); the matrix is printed on stderr as the cells finish.

Rows: the share of right cells against the goal (95 %), per excitation; spurious effects in the
single-effect cells; overdamped resonances reported; the CPU of a cell. ``--quick``: three cells
on a short meander (17 s of records), seconds.

Outside the runner: ``python -m benchmarks.confusion [--seeds N] [--jobs N] [--out FILE.jsonl]
[--only TEXT]``: ``--out`` keeps every cell's outcome, one JSON line each, and a run given the
same file skips the cells already there (a long matrix can be resumed).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from concurrent.futures import as_completed
from pathlib import Path

from analysis.executors import local_executor

from .table import Row

ORDER = 42
GOAL = 0.95
#: the quick mode's cells: two effects alone, and a play in travel with a valve lag (the issue's second pair)
QUICK = (("reversal",), ("stiction",), ("lag", "stiction"))


def cells(quick: bool, seeds: int = 2) -> list:
    from tests.support.confusion import Cell, matrix
    if quick:
        return [Cell(e, "short_meander") for e in QUICK]
    return matrix(seeds)


def run_matrix(todo: list, jobs: int | None = None, done: list | None = None,
               out: Path | None = None, say=print) -> list:
    """Every cell of ``todo`` run in the executor; the outcomes (with ``done`` before them)."""
    from tests.support.confusion import run_cell
    outcomes = list(done or [])
    with local_executor(jobs, len(todo)) as ex:
        futures = {ex.submit(run_cell, c): c for c in todo}
        for fut in as_completed(futures):
            o = fut.result()
            outcomes.append(o)
            if out is not None:
                with out.open("a") as fh:
                    fh.write(json.dumps(o.to_dict()) + "\n")
            say(f"[{len(outcomes)}/{len(todo) + len(done or [])}] {o.cell.label} on "
                f"{o.cell.excitation} #{o.cell.seed}: {'right' if o.right else 'WRONG: ' + o.taken_for}"
                f" ({o.seconds:.0f} s CPU)")
    return outcomes


def table(outcomes: list) -> str:
    """The matrix: a line per set of true effects, a column per excitation and draw; a right
    cell ``ok`` (``~`` when right by an ambiguity said), a wrong one what it was taken for."""
    cols = sorted({(o.cell.excitation, o.cell.seed) for o in outcomes})
    by = {(o.cell.label, o.cell.excitation, o.cell.seed): o for o in outcomes}
    labels = list(dict.fromkeys(o.cell.label for o in sorted(
        outcomes, key=lambda o: (len(o.cell.effects), o.cell.label))))
    lines = ["true effects | " + " | ".join(f"{x} #{s}" for x, s in cols)]
    for lab in labels:
        row = []
        for x, s in cols:
            o = by.get((lab, x, s))
            row.append("" if o is None else ("ok" + (" ~" if o.ambiguous else "")) if o.right
                       else o.model.replace("base+", "+") + f" ({o.verdict[:5]})")
        lines.append(f"{lab} | " + " | ".join(row))
    return "\n".join(lines)


def rows(outcomes: list, quick: bool) -> list[Row]:
    n = len(outcomes)
    right = sum(o.right for o in outcomes)
    per = defaultdict(lambda: [0, 0])
    for o in outcomes:
        per[o.cell.excitation][0] += o.right
        per[o.cell.excitation][1] += 1
    singles = [o for o in outcomes if len(o.cell.effects) == 1]
    spurious = [o for o in singles if o.spurious]
    overdamped = [o for o in outcomes if o.overdamped_resonance]
    cpu = sorted(o.seconds for o in outcomes)
    wrong = [o for o in outcomes if not o.right]
    label = "quick: 3 cells, short meander" if quick else f"{n} cells"
    return [
        Row(f"confusion matrix of stepwise, {label}: right", f"{right} of {n} ({100 * right / n:.0f} %)",
            f"goal >= {100 * GOAL:.0f} %", f"{right / n / GOAL:.2f} of goal",
            "; ".join(f"{x}: {a} of {b}" for x, (a, b) in sorted(per.items()))
            + ("; wrong: " + "; ".join(f"{o.cell.label} on {o.cell.excitation} #{o.cell.seed} "
                                        f"taken for {o.taken_for}" for o in wrong) if wrong else "")),
        Row("confusion matrix: spurious effects in single-effect cells",
            f"{len(spurious)} of {len(singles)}", "goal: 0", "",
            "; ".join(f"{o.cell.label}: {', '.join(o.spurious)}" for o in spurious)),
        Row("confusion matrix: overdamped resonances reported", f"{len(overdamped)} of {n}",
            "goal: 0", "", "; ".join(o.cell.label for o in overdamped)),
        Row("confusion matrix: CPU per cell (one stepwise diagnosis)",
            f"median {cpu[len(cpu) // 2]:.1f} s, max {cpu[-1]:.1f} s CPU", "", "",
            f"all cells {sum(cpu):.0f} s CPU"),
    ]


def run(quick: bool) -> list[Row]:
    out = run_matrix(cells(quick), say=lambda m: print(m, file=sys.stderr, flush=True))
    print(table(out), file=sys.stderr)
    return rows(out, quick)


def load(path: Path) -> list:
    """The outcomes kept in ``path`` (JSON lines of :meth:`Outcome.to_dict`)."""
    from tests.support.confusion import Cell, Outcome
    out = []
    for line in path.read_text().splitlines():
        d = json.loads(line)
        c = d.pop("cell")
        out.append(Outcome(cell=Cell(tuple(c["effects"]), c["excitation"], c["seed"]), **d))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.confusion",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seeds", type=int, default=2, help="noise draws per cell (default 2)")
    ap.add_argument("--jobs", type=int, help="worker processes (default: one per core)")
    ap.add_argument("--out", type=Path, help="keep each outcome here (JSON lines); resume from it")
    ap.add_argument("--only", help="only the cells whose label contains this text")
    ap.add_argument("--table", action="store_true", help="print the matrix of --out and exit")
    args = ap.parse_args(argv)
    done = load(args.out) if args.out is not None and args.out.exists() else []
    if args.table:
        print(table(done))
        from .table import format_table
        print(format_table(rows(done, False)))
        return 0
    seen = {(o.cell.effects, o.cell.excitation, o.cell.seed) for o in done}
    todo = [c for c in cells(args.quick, args.seeds)
            if (c.effects, c.excitation, c.seed) not in seen
            and (args.only is None or args.only in f"{c.label} {c.excitation}")]
    t0 = time.perf_counter()
    out = run_matrix(todo, args.jobs, done, args.out)
    print(table(out))
    from .table import format_table
    print(format_table(rows(out, args.quick)))
    print(f"{len(todo)} cells in {time.perf_counter() - t0:.0f} s wall")
    return 0


if __name__ == "__main__":
    sys.exit(main())
