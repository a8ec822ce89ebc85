"""A sweep of `stand diagnose --stepwise` over random pairs of the independent simulator's
effects (tests/independent_stand.py): does it arrive at the true pair, or its exact equivalent?

    .venv/bin/python -m tests.independent_sweep SEED N      # N random pairs, 10-70 s each

Not a test (too slow for CI, and the pairs are random): a probe to run after changing the
diagnosis; docs/analysis.md keeps the latest figures."""
from __future__ import annotations

import argparse
import time

import numpy as np

from analysis.data import make_record
from analysis.stepwise import stepwise
from tests import independent_stand as sim

#: simulator effect -> the catalogue effects that name it exactly or equivalently
EQUIVALENT = {"rev_flow": {"reversal"}, "rev_cmd": {"command_reversal"},
              "lag": {"lag", "sensor_lag"}, "sensorlag": {"lag", "sensor_lag"},
              "deadzone": {"deadzone"}, "saturation": {"saturation"}, "asymmetry": {"asymmetry"},
              "loadpress": {"load_pressure"}, "leakage": {"leakage"}, "backlash": {"backlash"},
              "flownl": {"flow_curve"}, "friction": {"deadzone"}}


def random_pairs(seed: int, n: int) -> list[tuple[str, str]]:
    rng = np.random.default_rng(seed)
    names = sorted(EQUIVALENT)
    pairs: set[tuple[str, str]] = set()
    while len(pairs) < n:
        a, b = sorted(rng.choice(names, 2, replace=False))
        if not EQUIVALENT[a] & EQUIVALENT[b] and {a, b} != {"rev_flow", "rev_cmd"}:
            pairs.add((a, b))
    return sorted(pairs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seed", type=int)
    ap.add_argument("n", type=int)
    args = ap.parse_args()
    ok = 0
    pairs = random_pairs(args.seed, args.n)
    for i, (a, b) in enumerate(pairs):
        runs = sim.make_dataset(f"{a}+{b}", 5000 + i)
        recs = [make_record(t, u, y, r if np.isfinite(r).any() else None, source=name)
                for name, _, t, u, y, r, _ in runs]
        t0 = time.perf_counter()
        res = stepwise(recs)
        got = {e.name for e in res.model.effects}
        good = len(got) == 2 and all(got & EQUIVALENT[x] for x in (a, b))
        ok += good
        values = {k: round(v, 4) for k, v in res.model.params().items() if "." in k}
        print(f"{a}+{b}: {'OK ' if good else 'BAD'} {res.verdict} {res.model.spec} "
              f"{res.steps[-1].over_floor:.2f}x {time.perf_counter() - t0:.0f}s {values}", flush=True)
    print(f"{ok}/{len(pairs)}")


if __name__ == "__main__":
    main()
