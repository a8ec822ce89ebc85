"""G from one short run: 16-channel rigs (a chain and a plate) identified by one run of Hadamard meanders, beside per-column and simultaneous meanders.

The rigs (:func:`rig_config`): sixteen attachment points on four 1 Mbit/s buses, every channel
with its own flow gain (8-14 mm/(%·s): g = 80-140 kgf/(%·s)), delay (35-65 ms), trend (-6 to
8 kgf/s) and reversal boost (b = 1.2-3, decaying in 0.10-0.15 s: transitional windows of
0.23-0.35 s), 2 kgf dynamometer noise; the structure

* **chain**: each point 10 kgf/mm, its neighbours 3 (30 %), as :func:`rig.chain.chain_rig`;
* **plate**: a 4 × 4 grid of points, each 10 kgf/mm, the four beside it +2 (20 %) and the four
  across the diagonals -0.8 (-8 %): up to eight neighbours, some rows' couplings summing to 1.7
  times their own g.

Rows, each structure:

* **one run, through the gateway** (full mode): the rig written as a rig file, ``stand campaign
  --rig FILE --one-run --with-emulator`` (the plan's defaults: every entry within 1 % of the
  smallest diagonal, ±5 %) against ``stand emulate --rig`` in its own process, then ``stand
  estimate --json``, each a separate process: stand and wall time, the largest ``|G − G_true|``
  as % of the diagonal (the smaller of the entry's row and column), the entries inside their
  95 % intervals, τ's largest error;
* **one run over seeds** (synthetic runs of the same plant, :mod:`analysis.rig.synthetic`, the
  design the plan gives): the share of all entries inside their 95 % intervals, the largest
  error over the seeds;
* **multisine**: random-phase multisines on interleaved frequency grids,
  G by least squares with τ known, with and without the reversal boosts: why the one-run
  excitation is a meander;
* **per column** (16 runs, each a ±5 % meander of 8 s, 4 periods: 512 s) and **simultaneous**
  (the periods :func:`analysis.rig.periods.separating_periods` must give sixteen channels, from
  131 s, two of the longest, at the amplitude the swing check allows), synthetic, a few seeds.

``--quick``: four channels of each structure, one seed of each design, synthetic only (a smoke
test of seconds).
"""
from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .table import Row

ORDER = 46
ROOT = Path(__file__).resolve().parents[1]
#: the one-run campaign's amplitude and the per-column meanders'
AMPLITUDE_PCT = 5.0
#: the per-column campaign as `stand campaign --rig` runs it by default: 4 periods of 8 s
COLUMN_PERIOD_S, COLUMN_CYCLES = 8.0, 4


def structure(kind: str, n: int) -> np.ndarray:
    """The stiffness at the attachment points, kgf/mm (module docstring)."""
    if kind == "chain":
        return 10.0 * (np.eye(n) + 0.3 * (np.eye(n, k=1) + np.eye(n, k=-1)))
    side = int(round(np.sqrt(n)))
    if side * side != n:
        raise ValueError(f"a plate of {n} points: give a square number")
    K = 10.0 * np.eye(n)
    for a in range(n):
        for b in range(n):
            dr, dc = abs(a // side - b // side), abs(a % side - b % side)
            if dr + dc == 1:
                K[a, b] = 2.0
            elif dr == 1 and dc == 1:
                K[a, b] = -0.8
    return K


def channels(n: int) -> list[dict]:
    """Each channel's own flow gain (mm/(%·s)), τ (s), Δ (kgf/s) and reversal boost, spread
    over their ranges in an order of their own."""
    def spread(lo: float, hi: float, seed: int) -> np.ndarray:
        return np.linspace(lo, hi, n)[np.random.default_rng(seed).permutation(n)]
    flow, tau = spread(8.0, 14.0, 7), np.round(spread(0.035, 0.065, 8), 4)
    boost, decay, delta = spread(1.2, 3.0, 9), spread(0.10, 0.15, 10), np.linspace(-6.0, 8.0, n)
    return [{"flow": f, "tau": t, "delta": d, "reversal.boost": b, "reversal.decay": T}
            for f, t, d, b, T in zip(flow, tau, delta, boost, decay)]


def rig_config(kind: str, n: int = 16, buses: int = 4, tag: str = "one-run"):
    """The benchmark's rig (module docstring) as a :class:`rig.config.RigConfig` on loopback
    buses ``udp_loopback:{tag}-canK``: the example rig's first channel copied (its range,
    limit, sensor), each channel's plant its own."""
    from rig.chain import chain_rig
    from rig.config import load_rig_file
    template = load_rig_file(ROOT / "examples" / "rig.toml").channels[0]
    base = chain_rig(template, n, buses, 0.3, tag=tag)
    K = structure(kind, n)
    own = channels(n)
    flow = np.array([c["flow"] for c in own])
    G = K * flow[None, :]
    chans = []
    for c, p, g in zip(base.channels, own, np.diag(G)):
        params = {k: v for k, v in p.items() if k != "flow"}
        plant = dataclasses.replace(c.plant, model=c.plant.model.with_params({**params, "g": g}))
        chans.append(dataclasses.replace(c, plant=plant))
    name = f"{kind} of {n} channels, each its own g, τ and reversal boost"
    return dataclasses.replace(base, name=name, channels=chans, G=G, K=K, structure_from="K")


def truth_model(rig):
    from rig.emulated import emulated_plant
    return emulated_plant(rig).model


def errors(G: np.ndarray, ci: np.ndarray, truth: np.ndarray) -> tuple[float, int, float]:
    """The largest ``|G − G_true|`` as % of the smaller diagonal of its row and column, the
    entries inside their intervals, the largest half-width (same %)."""
    diag = np.minimum.outer(np.diag(truth), np.diag(truth))
    rel = 100 * np.abs(G - truth) / diag
    inside = int(((ci[..., 0] <= truth) & (truth <= ci[..., 1])).sum())
    return float(np.max(rel)), inside, float(np.max(100 * 0.5 * (ci[..., 1] - ci[..., 0]) / diag))


def stand(*args: object, timeout: float = 3600) -> tuple[str, float]:
    """``stand ARGS`` as a separate process: its stdout and wall time; raises if it failed."""
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "stand", *map(str, args)], capture_output=True,
                         text=True, timeout=timeout, cwd=ROOT)
    if res.returncode != 0:
        raise RuntimeError(f"stand {' '.join(map(str, args))} failed: {res.stderr[-2000:]}")
    return res.stdout, time.perf_counter() - t0


def through_gateway(rig, root: Path) -> dict:
    """``stand campaign --rig FILE --one-run --with-emulator`` then ``stand estimate --json``:
    the campaign's stand and wall time, the estimate and its time."""
    from rig.files import rig_to_toml
    path = root / f"{rig.name.split()[0]}.toml"
    path.write_text(rig_to_toml(rig, header=rig.name, path=path))
    out = root / f"{path.stem}-campaign"
    text, wall = stand("campaign", "--rig", path, "--one-run", "--with-emulator", "--no-progress",
                       "--out", out)
    camp = json.loads((out / "rig-campaign.json").read_text())
    doc, est_s = stand("estimate", out, "--json")
    plan = text.splitlines()[1].strip().rsplit(" -> ", 1)[0].removeprefix("planned: ")
    return {"plan": plan, "stand_s": camp["stand_s"],
            "wall_s": camp["wall_s"], "campaign_s": wall, "estimate": json.loads(doc),
            "estimate_s": est_s}


def over_seeds(make, rig, seeds: list[int]) -> dict:
    """Estimate ``make(seed)``'s runs for each seed: the largest error, the entries inside,
    the largest half-width and the estimate's time, summed up."""
    from analysis.rig.estimate import estimate_rig
    truth = np.asarray(rig.G, float)
    worst, inside, half, secs, tau = 0.0, 0, 0.0, 0.0, 0.0
    taus = np.array([c.plant.model.params()["tau"] for c in rig.channels])
    for seed in seeds:
        records = make(seed)
        t0 = time.perf_counter()
        est = estimate_rig(records)
        secs += time.perf_counter() - t0
        w, k, h = errors(est.G, est.G_ci, truth)
        worst, inside, half = max(worst, w), inside + k, max(half, h)
        tau = max(tau, float(np.max(np.abs(est.tau_s - taus))))
    n = truth.size * len(seeds)
    return {"worst": worst, "inside": inside, "entries": n, "half": half, "estimate_s": secs,
            "tau_ms": 1e3 * tau, "seeds": len(seeds)}


def multisine_errors(model, duration_s: float, amplitude_pct: float, boost: bool,
                     dt: float = 0.002, seed: int = 0) -> np.ndarray:
    """G from one run of random-phase multisines on interleaved frequency grids (channel j the
    lines ``(kN + j + 1)/T`` below 1 Hz, peaks ``±amplitude_pct``), by least squares of each
    force on every channel's integrated command delayed by its true τ (favourable to it),
    with or without the channels' reversal boosts: ``(Ĝ − G)/G_jj``."""
    from plant import Dynamometer, PlantModel
    from plant.rig import RigModel
    n, N = int(round(duration_s / dt)), model.n
    t = np.arange(n) * dt
    rng = np.random.default_rng(seed)
    u = np.zeros((N, n))
    for j in range(N):
        f = (np.arange(64) * N + j + 1) / duration_s
        f = f[f < 1.0]
        s = np.cos(2 * np.pi * f[:, None] * t[None, :] + rng.uniform(0, 2 * np.pi, len(f))[:, None]).sum(0)
        u[j] = amplitude_pct * s / np.max(np.abs(s))
    plant = model if boost else RigModel(
        [PlantModel.from_spec("base", {k: v for k, v in m.params().items() if k in ("g", "tau", "delta")})
         for m in model.channels], model.G, model.names)
    y = plant.simulate(u, dt)
    lags = [int(round(m.params()["tau"] / dt)) for m in model.channels]
    U = np.vstack([np.cumsum(np.concatenate([np.zeros(k), u[j, :n - k]])) * dt
                   for j, k in enumerate(lags)])
    X = np.vstack([U, t, np.ones(n)]).T
    G = np.vstack([np.linalg.lstsq(X, Dynamometer(noise_kgf=2.0, seed=seed + i).measure(y[i])[0],
                                   rcond=None)[0][:N] for i in range(N)])
    return (G - model.G) / np.diag(model.G)[None, :]


def run(quick: bool) -> list[Row]:
    from analysis.rig.onerun import TRANSITIONAL_S, describe_design, plan_for_rig
    from analysis.rig.periods import planned_inflation, separating_periods
    from analysis.rig.synthetic import per_column_meanders, rig_meander, rig_one_run
    from gateway.campaign import SWING_SHARE, GPlan
    n = 4 if quick else 16
    rows: list[Row] = []
    for kind in ("chain", "plate"):
        rig = rig_config(kind, n)
        model = truth_model(rig)
        label = f"{n}-channel {kind}"
        design = plan_for_rig(rig, AMPLITUDE_PCT, 1.0)
        if not quick:
            with tempfile.TemporaryDirectory(prefix="bench-one-run-") as tmp:
                g = through_gateway(rig, Path(tmp))
            doc = g["estimate"]
            w, k, h = errors(np.array(doc["G"], float), np.array(doc["G_ci"], float), rig.G)
            taus = np.array([c.plant.model.params()["tau"] for c in rig.channels])
            tau = 1e3 * np.max(np.abs(np.array(doc["tau_s"], float) - taus))
            rows.append(Row(
                f"rig G from one run, {label}, through the gateway",
                f"{g['stand_s']:.1f} s of stand time: largest error {w:.2g} % of the diagonal",
                "≤ 60 s, every entry within 1 %", f"{w:.2g} of target",
                f"{k} of {n * n} entries inside their 95 % intervals (half-widths ≤ {h:.2g} %); "
                f"τ within {tau:.2g} ms; physical check: "
                f"{'physical' if doc['physical']['physical'] else 'not physical'}; campaign "
                f"{g['wall_s']:.0f} s wall (lockstep, {g['stand_s'] / g['wall_s']:.1f}x real time), "
                f"estimate {g['estimate_s']:.1f} s; planned: {g['plan']}"))
        seeds = [1] if quick else list(range(1, 13))
        one = over_seeds(lambda s: [rig_one_run(model, AMPLITUDE_PCT, design.slot_s,
                                                design.repeats, seed=1000 * s)], rig, seeds)
        rows.append(_seeds_row(f"one run ({design.slots} slots of {design.slot_s:.3g} s)", label,
                               design.duration_s, one))
        cols = [1] if quick else [1, 2]
        for period, cycles in ((COLUMN_PERIOD_S, COLUMN_CYCLES), (4.0, 2)):
            res = over_seeds(lambda s: per_column_meanders(model, AMPLITUDE_PCT, period, cycles,
                                                           seed=100 * s), rig, cols)
            rows.append(_seeds_row(f"per column ({n} runs of {cycles} × {period:g} s)", label,
                                   n * period * cycles, res))
        rel = {b: multisine_errors(model, 60.0, AMPLITUDE_PCT, b) for b in (True, False)}
        off = ~np.eye(n, dtype=bool)
        rows.append(Row(f"rig G, {label}, multisine (60 s, interleaved grids below 1 Hz), synthetic",
                        f"diagonal {100 * np.mean(np.diag(rel[True])):+.3g} % on average, up to "
                        f"{100 * np.max(np.abs(np.diag(rel[True]))):.3g} %",
                        "without the reversal boost: "
                        f"{100 * np.max(np.abs(rel[False])):.2g} %", "",
                        f"off-diagonal up to {100 * np.max(np.abs(rel[True][off])):.3g} % of the "
                        "diagonal; least squares of each force on the integrated commands delayed "
                        "by their true τ: each zero crossing of a command reverses its valve, and "
                        "its boost counts as gain"))
        shortest = 12.0 if quick else 131.072
        periods = separating_periods(n, shortest)
        duration = (90.0 if quick else 8 * shortest)
        swing = GPlan(True, AMPLITUDE_PCT, periods, duration_s=duration).swings_kgf(rig.G)
        limits = np.array([c.limit_kgf for c in rig.channels])
        amp = min(AMPLITUDE_PCT, float(np.floor(100 * AMPLITUDE_PCT * np.min(
            SWING_SHARE * limits / swing)) / 100))
        vif = max(planned_inflation(periods, duration))
        res = over_seeds(lambda s: [rig_meander(model, [amp] * n, periods, duration, seed=10 * s)],
                         rig, [1])
        rows.append(_seeds_row(f"simultaneous ({periods[0]:g}-{periods[-1]:g} s, ±{amp:g} %, "
                               f"planned VIF {vif:.2g})", label, duration, res))
    rows.append(Row("rig G from one run: the plan", describe_design(design, TRANSITIONAL_S)
                    .splitlines()[0], "", "", describe_design(design, TRANSITIONAL_S)
                    .splitlines()[1].strip()))
    return rows


def _seeds_row(design: str, label: str, stand_s: float, r: dict) -> Row:
    return Row(f"rig G, {label}, {design}, synthetic",
               f"{stand_s:.4g} s of stand time: largest error {r['worst']:.2g} % of the diagonal",
               "every entry within 1 %", f"{r['worst']:.2g} of target",
               f"over {r['seeds']} seed(s): {r['inside']} of {r['entries']} entries "
               f"({100 * r['inside'] / r['entries']:.1f} %) inside their 95 % intervals "
               f"(half-widths ≤ {r['half']:.2g} %); τ within {r['tau_ms']:.2g} ms; estimate "
               f"{r['estimate_s'] / r['seeds']:.1f} s per seed")
