"""A sweep of `stand diagnose --stepwise` over random pairs of the independent simulator's
effects (tests/support/independent_stand.py): does it arrive at the true pair, or its exact
equivalent?

    .venv/bin/python -m tests.independent_sweep SEED N [--k 3]   # N random pairs (or triples)

Not a test (too slow for CI, and the pairs are random): a probe to run after changing the
diagnosis; docs/benchmarks.md keeps the latest figures."""
from __future__ import annotations

import argparse
import time

import numpy as np

from analysis import stepwise
from tests.support.records import EQUIVALENT, independent_records

#: the simulator's reversal boosts (timed from the rod, the command, or over the force travelled):
#: at most one per data set
REVERSAL_LAWS = {"rev_flow", "rev_cmd", "rev_force"}
#: laws added after the sweeps of docs/analysis.md, left out so a seed draws what it drew then
LATER = {"lostmotion", "dirlatch"}


def random_sets(seed: int, n: int, k: int = 2) -> list[tuple[str, ...]]:
    """``n`` different random sets of ``k`` simulator effects that no catalogue effect names
    twice (and at most one reversal law)."""
    rng = np.random.default_rng(seed)
    names = sorted(set(EQUIVALENT) - LATER)
    sets: set[tuple[str, ...]] = set()
    while len(sets) < n:
        pick = tuple(sorted(str(x) for x in rng.choice(names, k, replace=False)))
        named = [EQUIVALENT[x] for x in pick]
        clash = any(named[i] & named[j] for i in range(k) for j in range(i + 1, k))
        if not clash and len(REVERSAL_LAWS & set(pick)) < 2:
            sets.add(pick)
    return sorted(sets)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seed", type=int)
    ap.add_argument("n", type=int)
    ap.add_argument("--k", type=int, default=2, help="effects per data set (default 2)")
    args = ap.parse_args()
    ok = 0
    sets = random_sets(args.seed, args.n, args.k)
    for i, combo in enumerate(sets):
        recs = independent_records("+".join(combo), 5000 + i)
        t0 = time.perf_counter()
        res = stepwise(recs)
        got = {e.name for e in res.model.effects}
        good = len(got) == len(combo) and all(got & EQUIVALENT[x] for x in combo)
        ok += good
        values = {k: round(v, 4) for k, v in res.model.params().items() if "." in k}
        print(f"{'+'.join(combo)}: {'OK ' if good else 'BAD'} {res.verdict} {res.model.spec} "
              f"{res.steps[-1].over_floor:.2f}x {time.perf_counter() - t0:.0f}s {values}", flush=True)
    print(f"{ok}/{len(sets)}")


if __name__ == "__main__":
    main()
