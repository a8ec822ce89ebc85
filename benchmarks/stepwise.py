"""Stepwise diagnosis of a stand with three hidden effects: identification in a minute (issue 29).

A stand the project never saw: g = 95 kgf/(%·s), τ = 60 ms, Δ = 5 kgf/s, a reversal boost of
2.5 decaying in 0.12 s, a specimen that stiffens with the load (k = 1.5 at 10⁴ kgf) and rod
stiction (a play of 150 kgf); three open-loop meanders of 8 cycles of 4 s at 5, 10 and 20 % (96 s
of stand time at 500 Hz), as a user would run them. ``stand diagnose m5 m10 m20 --stepwise``
must find the three effects and end within the noise.

Rows: the whole build-up's wall and CPU time against the target on this machine's cores (45 s,
issue 41), and one fit of the final model with the force-dependent integration solved in blocks
(now) against the per-step Python loop it replaced (the profile's 76 %), measured in the same
run. Then a rig's: ``stand diagnose COLUMNS --rig-model RIG --stepwise`` on a 16-channel chain
(neighbours coupled 30 %, each channel its own g, τ and reversal boost), one stepwise diagnosis
per channel on its column run, as a separate process on this machine's cores (issue 41's goal:
under 10 minutes on 2 cores). ``--quick``: the one-fit row on a quarter of the data and the rig
row on 4 channels with 3 candidates (seconds).
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from analysis import fit_model, stepwise
from analysis.records import synthetic as S
from analysis.rig.synthetic import per_column_meanders, rig_truth, write_rig_run
from plant import PlantModel
from plant.config import load_rig_model
from plant.rig import RigModel

from .table import Row

ORDER = 41
TARGET_S = 45.0
RIG_TARGET_S = 600.0
TRUTH = {"g": 95.0, "tau": 0.06, "delta": 5.0, "reversal.boost": 2.5, "reversal.decay": 0.12,
         "reversal.exponent": 0.7, "stiffness.k_abs": 1.5, "stiction.width": 150.0}
SPEC = "base+reversal+stiffness+stiction"


def meanders(cycles: int = 8) -> list:
    """The three meanders (one record each), 2 kgf noise, 0.5 kgf resolution."""
    truth = PlantModel.from_spec(SPEC, TRUTH)
    return [S.meander(truth, (a,), period_s=4.0, cycles=cycles, seed=i + 3)
            for i, a in enumerate((5.0, 10.0, 20.0))]


def _stepping(self, drv, y0, dt, guess=None, growth=None):
    """The per-step Python loop the block solver replaced (the reference; it gives no growth
    factors, so the Jacobian's columns are solved as the points are)."""
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
        return rows + [rig_row(True)]
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
    rows.append(rig_row(False))
    return rows


def chain_rig(n: int) -> RigModel:
    """A chain of ``n`` attachment points (stiffness 10 kgf/mm, -3 between neighbours: 30 %),
    flow gains 8-14 mm/(%·s), τ 40-60 ms, reversal boosts 1.5-3 (decay 0.15 s), trends of a
    few kgf/s: every channel its own plant."""
    K = 10.0 * np.eye(n) - 3.0 * (np.eye(n, k=1) + np.eye(n, k=-1))
    i = np.arange(n)
    flow = 8.0 + 6.0 * ((i * 5) % n) / max(n - 1, 1)
    models = [PlantModel.from_spec("base+reversal", {
        "tau": 0.040 + 0.020 * ((j * 7) % n) / max(n - 1, 1), "delta": float((j % 5) - 2) * 3.0,
        "reversal.boost": 1.5 + 1.5 * ((j * 3) % n) / max(n - 1, 1)}) for j in range(n)]
    return RigModel(models, K * flow[None, :], [f"ch{j:02d}" for j in range(n)])


def _stand(*args: object) -> float:
    """``stand ARGS`` as a separate process: its wall time; raises if it failed."""
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "stand", *map(str, args)], capture_output=True,
                         text=True, timeout=7200)
    if res.returncode != 0:
        raise RuntimeError(f"stand {' '.join(map(str, args))} failed: {res.stderr[-2000:]}")
    return time.perf_counter() - t0


def rig_row(quick: bool) -> Row:
    """Every channel of a chain rig diagnosed stepwise from its column run (the per-column
    campaign, 5 periods of a ±5 % meander of 4 s), G from ``stand estimate`` of the same runs."""
    n = 4 if quick else 16
    rig = chain_rig(n)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    with tempfile.TemporaryDirectory(prefix="bench-rig-diagnose-") as tmp:
        root = Path(tmp)
        for rec in per_column_meanders(rig, 5.0, 4.0, 2 if quick else 5, seed=1):
            moving = rec.source.split(": ")[1].split()[0]
            write_rig_run(rec, root / "columns" / f"meander-{moving}", rig_truth(rig))
        _stand("estimate", root / "columns", "--json", "--save", root / "rig.toml")
        extra = ["--candidates", "reversal,lag,command_reversal"] if quick else []
        load0 = os.getloadavg()[0]
        seconds = _stand("diagnose", root / "columns", "--rig-model", root / "rig.toml",
                         "--stepwise", "--save", root / "found.toml", "--jobs", cores,
                         "--no-progress", *extra)
        load1 = os.getloadavg()[0]
        found = load_rig_model(root / "found.toml")
    right = sum(m.spec == "base+reversal" for m in found.channels)
    g_err = np.max(np.abs(np.diag(found.G) - np.diag(rig.G)) / np.diag(rig.G))
    tau_err = max(abs(a.params()["tau"] - b.params()["tau"])
                  for a, b in zip(found.channels, rig.channels))
    label = f"{n} channels, stepwise" + (" (3 candidates)" if quick else " (every effect)")
    return Row(f"rig diagnose --rig-model, {label}, {cores} workers", f"{seconds:.1f} s",
               f"goal <= {RIG_TARGET_S:.0f} s", f"{seconds / RIG_TARGET_S:.2f} of goal",
               f"{right} of {n} channels base+reversal (right); g within {100 * g_err:.2g} %, τ "
               f"within {1e3 * tau_err:.1f} ms; per-column runs of {2 if quick else 5} periods "
               f"of 4 s; load average {load0:.1f} before, {load1:.1f} after")
