"""Stepwise diagnosis of a stand with three hidden effects: identification in a minute (issue 29).

A stand the project never saw: g = 95 kgf/(%·s), τ = 60 ms, Δ = 5 kgf/s, a reversal boost of
2.5 decaying in 0.12 s, a specimen that stiffens with the load (k = 1.5 at 10⁴ kgf) and rod
stiction (a play of 150 kgf); three open-loop meanders of 8 cycles of 4 s at 5, 10 and 20 % (96 s
of stand time at 500 Hz), as a user would run them. ``stand diagnose m5 m10 m20 --stepwise``
must find the three effects and end within the noise.

Rows: the whole build-up's wall and CPU time against the 60 s target on this machine's cores,
and one fit of the final model with the force-dependent integration solved in blocks (now)
against the per-step Python loop it replaced (the profile's 76 %), measured in the same run.
``--quick``: the one-fit row on a quarter of the data.
"""
from __future__ import annotations

import os
import time

import numpy as np

from analysis import fit_model, stepwise
from analysis.records import synthetic as S
from plant import PlantModel

from .table import Row

ORDER = 41
TARGET_S = 60.0
TRUTH = {"g": 95.0, "tau": 0.06, "delta": 5.0, "reversal.boost": 2.5, "reversal.decay": 0.12,
         "reversal.exponent": 0.7, "stiffness.k_abs": 1.5, "stiction.width": 150.0}
SPEC = "base+reversal+stiffness+stiction"


def meanders(cycles: int = 8) -> list:
    """The three meanders (one record each), 2 kgf noise, 0.5 kgf resolution."""
    truth = PlantModel.from_spec(SPEC, TRUTH)
    return [S.meander(truth, (a,), period_s=4.0, cycles=cycles, seed=i + 3)
            for i, a in enumerate((5.0, 10.0, 20.0))]


def _stepping(self, drv, y0, dt, guess=None):
    """The per-step Python loop the block solver replaced (the reference)."""
    n, K = drv.q.shape
    out = np.empty((n, K + 1))
    out[:, 0] = y = np.asarray(y0, float).copy()
    for k in range(K):
        aux = [None if a is None else a[:, k] for a in drv.aux]
        y = y + dt * self._rate(drv.q[:, k], aux, None if drv.dist is None else drv.dist[:, k], y)
        out[:, k + 1] = y
    return out


def one_fit(records: list) -> tuple[float, float, float]:
    """CPU seconds of one fit of the true model's structure, solved in blocks and stepped, and
    the largest relative difference between the two fits' parameters."""
    t0 = time.process_time()
    blocks = fit_model(records, SPEC)
    t_blocks = time.process_time() - t0
    solver = PlantModel._integrate_in_blocks
    PlantModel._integrate_in_blocks = _stepping
    try:
        t0 = time.process_time()
        stepped = fit_model(records, SPEC)
        t_step = time.process_time() - t0
    finally:
        PlantModel._integrate_in_blocks = solver
    diff = max(abs(blocks.params[k] - stepped.params[k]) / max(abs(stepped.params[k]), 1e-9)
               for k in blocks.params)
    return t_blocks, t_step, diff


def run(quick: bool) -> list[Row]:
    rows = []
    records = meanders(2 if quick else 8)
    t_blocks, t_step, diff = one_fit(records)
    rows.append(Row(f"one fit of {SPEC}, {'24' if quick else '96'} s of meanders",
                    f"{t_blocks:.1f} s CPU", f"per-step loop: {t_step:.1f} s CPU",
                    f"{t_step / t_blocks:.1f}x faster",
                    f"the same fit: parameters within {diff:.1g} relative"))
    if quick:
        return rows
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    t0, c0 = time.perf_counter(), time.process_time()
    children0 = os.times()
    s = stepwise(records)
    wall = time.perf_counter() - t0
    children = os.times()
    cpu = (time.process_time() - c0 + children.children_user - children0.children_user
           + children.children_system - children0.children_system)
    found = sorted(e.name for e in s.model.effects)
    right = found == ["reversal", "stiction", "stiffness"] and s.verdict == "adequate"
    rows.append(Row("stand diagnose --stepwise, 3 meanders x 8 cycles (96 s at 500 Hz)",
                    f"{wall:.1f} s wall, {cpu:.0f} s CPU on {cores} cores",
                    f"target <= {TARGET_S:.0f} s", f"{wall / TARGET_S:.2f} of target",
                    f"verdict {s.verdict} with {s.model.spec} ({'right' if right else 'WRONG'}), "
                    f"{s.steps[-1].over_floor:.2f}x the noise floor; path "
                    + " -> ".join([s.steps[0].model] + [f"+{st.added}" for st in s.steps if st.added])))
    return rows
