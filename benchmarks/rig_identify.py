"""Rig identification: a 4-channel rig, neighbours coupled 30 %, identified only through `stand estimate` and `stand diagnose --rig-model`.

The truth: a chain of four attachment points (stiffness 10 kgf/mm each, -3 between
neighbours: 30 %), actuators of flow gains 12, 10, 14, 8 mm/(%·s), so ``G = K·diag(c/A)`` with
g = 120, 100, 140, 80 kgf/(%·s) on the diagonal; τ = 40, 50, 60, 45 ms; reversal boosts 1.5, 2,
3, 2.5 (decay 0.15 s); trends 8, -5, 3, 0 kgf/s; 2 kgf dynamometer noise, 0.5 kgf resolution.

Two experiments, written as rig runs in the run format (synthetic from
:class:`plant.rig.RigModel` until the rig gateway records them from the rig emulator): the
per-column campaign (a ±5 % meander of 4 s on one channel at a time, 5 periods, the other
valves at zero) and one simultaneous run (every channel ±5 %, periods 12, 15, 18, 22.5 s:
:func:`analysis.rig.periods.separating_periods`, 180 s). Then, as a user would, each a
separate process: ``stand estimate RUN --json --save rig.toml`` (G against the truth: target
every entry within 5 % of the diagonal) and ``stand diagnose RUN --rig-model rig.toml --stepwise
--save`` with 1 and with 2 worker processes (the time of identifying all channels; the same
models either way).
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from analysis.rig.periods import separating_periods
from analysis.rig.synthetic import per_column_meanders, rig_meander, rig_truth, write_rig_run
from plant import PlantModel
from plant.rig import RigModel
from plant.config import load_rig_model

from .table import Row

ORDER = 45
NAMES = ["root_l", "mid_l", "mid_r", "tip_r"]
K = np.array([[10.0, -3.0, 0.0, 0.0], [-3.0, 10.0, -3.0, 0.0],
              [0.0, -3.0, 10.0, -3.0], [0.0, 0.0, -3.0, 10.0]])
FLOW = np.array([12.0, 10.0, 14.0, 8.0])
CHANNELS = [(0.040, 8.0, 1.5), (0.050, -5.0, 2.0), (0.060, 3.0, 3.0), (0.045, 0.0, 2.5)]
TARGET = 0.05
#: the simultaneous run's periods: separating_periods(4, 12.0), half periods of 6-11 s, several
#: times the 1.4 s left out after each reversal (8-15 s ones lost correlated phases: VIF 3.2)
PERIODS = separating_periods(4, 12.0)


def truth() -> RigModel:
    models = [PlantModel.from_spec("base+reversal", {"tau": tau, "delta": d, "reversal.boost": b})
              for tau, d, b in CHANNELS]
    return RigModel(models, K * FLOW[None, :], NAMES)


def stand(*args: object) -> tuple[str, float]:
    """``stand ARGS`` as a separate process: its stdout and wall time; raises if it failed."""
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "stand", *map(str, args)], capture_output=True,
                         text=True, timeout=3600)
    if res.returncode != 0:
        raise RuntimeError(f"stand {' '.join(map(str, args))} failed: {res.stderr[-2000:]}")
    return res.stdout, time.perf_counter() - t0


def g_row(label: str, doc: dict, rig: RigModel, seconds: float) -> Row:
    G = np.array(doc["G"], float)
    ci = np.array(doc["G_ci"], float)
    diag = np.minimum.outer(np.diag(rig.G), np.diag(rig.G))
    rel = np.abs(G - rig.G) / diag
    inside = int(((ci[..., 0] <= rig.G) & (rig.G <= ci[..., 1])).sum())
    half = 0.5 * (ci[..., 1] - ci[..., 0]) / diag
    tau_err = np.max(np.abs(np.array(doc["tau_s"]) - [t for t, _, _ in CHANNELS])) * 1e3
    return Row(f"rig G, {label}", f"largest error {100 * rel.max():.3g} % of the diagonal",
               f"target every entry within {100 * TARGET:.0f} %",
               f"{rel.max() / TARGET:.3f} of target",
               f"{inside} of 16 entries inside their 95 % intervals (half-widths up to "
               f"{100 * half.max():.2g} % of the diagonal); τ within {tau_err:.2g} ms; physical "
               f"check: {'physical' if doc['physical']['physical'] else 'not physical'}; "
               f"stand estimate {seconds:.1f} s")


def run(quick: bool) -> list[Row]:
    rig = truth()
    rows: list[Row] = []
    with tempfile.TemporaryDirectory(prefix="bench-rig-") as tmp:
        root = Path(tmp)
        cycles = 2 if quick else 5        # quick: a smoke run of seconds
        for rec in per_column_meanders(rig, 5.0, 4.0, cycles, seed=1):
            moving = rec.source.split(": ")[1].split()[0]
            write_rig_run(rec, root / "columns" / f"meander-{moving}", rig_truth(rig))
        duration = 45.0 if quick else 180.0     # quick: two periods of the longest
        sim = write_rig_run(rig_meander(rig, [5.0] * 4, PERIODS, duration, seed=2),
                            root / "simultaneous", rig_truth(rig))
        out, s = stand("estimate", root / "columns", "--json")
        rows.append(g_row(f"per-column campaign (4 runs, {cycles} periods of 4 s each)",
                          json.loads(out), rig, s))
        out, s = stand("estimate", sim, "--json", "--save", root / "rig.toml")
        rows.append(g_row(f"one simultaneous run ({'/'.join(f'{p:g}' for p in PERIODS)} s, "
                          f"{duration:.0f} s)",
                          json.loads(out), rig, s))
        candidates = ["reversal", "lag"] if quick else []
        extra = ["--candidates", ",".join(candidates)] if quick else []
        times, models = {}, {}
        for jobs in (1, 2):
            saved = root / f"rig-{jobs}.toml"
            _, times[jobs] = stand("diagnose", sim, "--rig-model", root / "rig.toml", "--stepwise",
                                   "--save", saved, "--jobs", jobs, "--no-progress", *extra)
            models[jobs] = load_rig_model(saved)
    same = all(a.params() == b.params() for a, b in zip(models[1].channels, models[2].channels))
    found = models[2]
    per = []
    for m, (tau, _, boost) in zip(found.channels, CHANNELS):
        p = m.params()
        eff = (p["reversal.boost"] * 2.0 ** p["reversal.exponent"] / (boost * 2.0 ** 0.7)
               if "reversal.boost" in p else float("nan"))
        per.append(f"{m.spec} τ {1e3 * (p['tau'] - tau):+.1f} ms boost at 5 % ×{eff:.3f}")
    g_err = np.max(np.abs(np.diag(found.G) - np.diag(rig.G)) / np.diag(rig.G))
    label = "4 channels, stepwise" + (f" ({len(candidates)} candidates)" if quick else " (every effect)")
    rows.append(Row(f"rig diagnose --rig-model, {label}, 1 worker", f"{times[1]:.1f} s", "", "",
                    "each channel with the others' part of its force rate as a known input"))
    rows.append(Row(f"rig diagnose --rig-model, {label}, 2 workers", f"{times[2]:.1f} s",
                    f"1 worker: {times[1]:.1f} s", f"{times[1] / times[2]:.2f}x",
                    f"{'same models' if same else 'DIFFERENT models'} either way; g within "
                    f"{100 * g_err:.2g} %; " + "; ".join(f"{n}: {x}" for n, x in zip(NAMES, per))))
    return rows
