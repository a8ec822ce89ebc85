"""Rig loading: the example rig (4 channels, neighbours 30 %) identified through the rig gateway, 100 load cases at 2500 and 5000 kgf/s, 3 passes, decoupled vs independent.

The truth: ``examples/rig.toml`` as ``stand emulate --rig`` runs it (G = K·diag(c/A), g = 120,
100, 140, 110 kgf/(%·s), a neighbour's flow moving a force 30 % of its own; τ = 50, 45, 60,
55 ms; reversal boosts 2, 2.5, 1.8, 2.2; trends 8, 5, -3, 0 kgf/s; 2 / 1.5 kgf noise).

1. **Identify**, as a user would, each step a separate process against ``stand emulate --rig
   examples/rig.toml --lockstep`` (its own process, private loopback buses): ``stand campaign
   --rig --simultaneous`` twice, every channel ±2.5 % and ±1.25 % (at 5 % the rig file's G says
   outer would swing ±4641 kgf, refused; two amplitudes so a reversal boost's size and exponent
   come apart; periods :func:`analysis.rig.periods.separating_periods` (4, 12 s), 180 s each)
   → ``stand estimate DIR1 DIR2 --save rig.toml`` (G against the truth) → ``stand diagnose RUN1
   RUN2 --rig-model rig.toml --stepwise --save model.toml`` (each channel's effects).
2. **Design** from the identified model: ``stand design model.toml -o decoupled.toml`` and
   ``--independent -o independent.toml`` (today's one-channel design on each channel).
3. **Load through the gateway**: ``stand load cases.csv --rig --controller decoupled.toml
   --repeat 3`` against the same emulator, 20 random load cases at 2500 kgf/s (the gateway's
   lockstep runs the 4 channels at roughly real time on these 2 shared cores, so the whole
   sweep below through it would take most of an hour); then the same load cases timed to the
   valves (``--fastest``, 0.5 %), against their time at 2500 kgf/s and their valve-limited
   minimum by the identified model (``--plan``).
4. **The sweep offline**: 100 random load cases (each channel alternating between peaks and
   valleys in its band, the ratios changing from case to case: :func:`loading.programme.
   random_load_cases`, seed 1), the fastest channel of each segment at 2500 and at 5000 kgf/s,
   3 passes with per-channel compensation, both controllers, on the emulator's own coupled
   lockstep plant with its noise (:mod:`gateway.offline`: the same plant and law, no bus;
   said in the rows).

Rows: G's largest error (% of the diagonal), the designs' margins, the gateway's passes, and per
rate and controller the worst channel's peak/valley p95 and max of every pass, extra cycles, the
ratio error; the independent's worst p95 over the decoupled's (the goal: ≥ 5).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .table import Row

ORDER = 46
ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "rig.toml"
#: each channel's band (kgf): root and inner 10 t dynamometers, outer and tip 5 t
BANDS = [(500.0, 6000.0), (500.0, 6000.0), (300.0, 3200.0), (300.0, 3200.0)]
TARGET_G = 0.05
#: the simultaneous meanders' amplitude: at 5 % the example's outer channel would swing beyond
#: 60 % of its force limit (stand campaign refuses it)
#: the simultaneous campaigns' amplitudes (at 5 % the rig file's G says outer would swing ±4641
#: kgf, refused); two, as the one-channel campaign's meanders, so the reversal boost's size and
#: its amplitude exponent come apart (at one amplitude they trade off: b·(10/a)^p)
AMPLITUDES_PCT = (2.5, 1.25)
PERIOD_S = 0.002


def stand(*args: object) -> tuple[str, float]:
    """``stand ARGS`` as a separate process: its stdout and wall time; raises if it failed."""
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "stand", *map(str, args)], capture_output=True,
                         text=True, timeout=7200, cwd=ROOT)
    if res.returncode != 0:
        raise RuntimeError(f"stand {' '.join(map(str, args))} failed: {res.stderr[-2000:]}")
    return res.stdout, time.perf_counter() - t0


def emulated_example(root: Path) -> Path:
    """The example rig on private loopback buses (a file beside the run's others)."""
    path = root / "rig.toml"
    path.write_text(EXAMPLE.read_text().replace("udp_loopback:rig-", f"udp_loopback:bench-rl-{os.getpid()}-"))
    return path


def identify(root: Path, rig: Path, truth, quick: bool) -> tuple[Path, list[Row]]:
    """Step 1 through the gateway: the identified rig model file, and its rows."""
    from analysis.rig.periods import separating_periods
    # quick (a smoke run): periods from 10 s (shorter ones' steady parts, past the 1.4 s left
    # out after each reversal, correlate: from 6 s, VIF 375), two of the longest
    shortest = 10.0 if quick else 12.0
    periods = separating_periods(truth.n, shortest, PERIOD_S)
    duration = 38.0 if quick else 180.0
    camps, s_camp = [], 0.0
    for amp in AMPLITUDES_PCT:       # two amplitudes: a reversal boost's size and exponent apart
        camp = root / f"campaign-{amp:g}"
        _, s = stand("campaign", "--rig", rig, "--lockstep", "--simultaneous", "--amplitude-pct", amp,
                     "--duration-s", duration, "--emulated", "--no-progress", "--out", camp,
                     *(["--meander-period-s", shortest] if quick else []))
        camps.append(camp)
        s_camp += s
    out, s_est = stand("estimate", *camps, "--json", "--save", root / "rig-model.toml")
    doc = json.loads(out)
    G = np.array(doc["G"], float)
    diag = np.minimum.outer(np.diag(truth.G), np.diag(truth.G))
    rel = np.abs(G - truth.G) / diag
    extra = ["--candidates", "reversal,lag"] if quick else []
    _, s_diag = stand("diagnose", *[c / "01-simultaneous" for c in camps], "--rig-model", root / "rig-model.toml",
                      "--stepwise", "--save", root / "model.toml", "--no-progress", *extra)
    from plant.config import load_rig_model
    found = load_rig_model(root / "model.toml")
    specs = ", ".join(f"{n}: {m.spec}" for n, m in zip(found.names, found.channels))
    rows = [Row("rig load, G identified through the gateway (stand campaign --rig --simultaneous "
                f"{'/'.join(f'{p:g}' for p in periods)} s, ±{' and ±'.join(f'{a:g}' for a in AMPLITUDES_PCT)} %, "
                f"{duration:.0f} s each; stand estimate)",
                f"largest error {100 * rel.max():.3g} % of the diagonal",
                f"every entry within {100 * TARGET_G:.0f} %", f"{rel.max() / TARGET_G:.3f} of target",
                f"stand campaign {s_camp:.0f} s against stand emulate --rig --lockstep, stand estimate "
                f"{s_est:.0f} s, stand diagnose --rig-model --stepwise {s_diag:.0f} s: {specs}")]
    return root / "model.toml", rows


def load_through_gateway(root: Path, rig: Path, controller: Path, truth, n_cases: int, rate: float,
                         passes: int) -> list[Row]:
    """Step 3: ``stand load --rig`` against the emulator."""
    from loading.programme import random_load_cases
    from loading.programme_files import write_load_cases
    cases = write_load_cases(root / "cases.csv", random_load_cases(n_cases, BANDS, seed=1), truth.names)
    out, wall = stand("load", cases, "--rig", rig, "--controller", controller, "--rate", rate,
                      "--repeat", passes, "--lockstep", "--json", "--no-progress", "--out", root / "load")
    doc = json.loads(out)
    reps = doc["passes"]
    p95 = [p["peak_valley_error_pct"]["p95"] for p in reps]
    mx = [p["peak_valley_error_pct"]["max"] for p in reps]
    extra = [sum(f["extra_cycles"] for f in p["channels"].values()) for p in reps]
    ratio = [p["ratio_error_pct"] for p in reps]
    stand_s = sum(json.loads((Path(r) / "run.json").read_text())["stats"]["cycles"] for r in doc["runs"]) * PERIOD_S
    return [Row(f"rig load through the gateway (stand load --rig), {n_cases} load cases at {rate:g} kgf/s, "
                f"decoupled, passes 1-{len(reps)}",
                f"worst channel p95 {' / '.join(f'{v:.3f}' for v in p95)} %, max "
                f"{' / '.join(f'{v:.3f}' for v in mx)} %",
                "p95 <= 0.5 %, max <= 1 %, no extra cycle",
                "met" if max(p95) <= 0.5 and max(mx) <= 1.0 and max(extra) == 0 else "not met",
                f"worst channel {' / '.join(p['worst_channel'] for p in reps)}; extra cycles "
                f"{' / '.join(f'{v:g}' for v in extra)}; ratio error "
                f"{' / '.join(f'{v:.3f}' for v in ratio)} %; {stand_s:.0f} s of stand time "
                f"in {wall:.0f} s wall ({stand_s / wall:.1f}x real time) against stand emulate --rig --lockstep")]


def fastest_through_gateway(root: Path, rig: Path, controller: Path, n_cases: int, rate: float,
                            passes: int) -> list[Row]:
    """Step 3b: the same load cases timed to the valves (``stand load --rig --fastest``,
    0.5 %), beside their time at ``rate`` and their valve-limited minimum by the identified model."""
    cases = root / "cases.csv"
    plan, _ = stand("load", cases, "--rig", rig, "--controller", controller, "--rate", rate, "--plan",
                    "--json", "--lockstep")
    at_rate = json.loads(plan)
    out, wall = stand("load", cases, "--rig", rig, "--controller", controller, "--fastest", "--repeat",
                      passes, "--lockstep", "--json", "--no-progress", "--out", root / "fastest")
    doc = json.loads(out)
    s = doc.get("schedule")
    times = [p["programme_time_s"] for p in doc["passes"]]
    minimum = at_rate["minimum_time_s"]
    p95 = [p["peak_valley_error_pct"]["p95"] for p in doc["passes"]]
    mx = [p["peak_valley_error_pct"]["max"] for p in doc["passes"]]
    measured = (f"{s['time_s']:.1f} s, {s['time_s'] / minimum:.2f}x the valve-limited minimum"
                if s else "no pass met 0.5 %")
    return [Row(f"rig load through the gateway, {n_cases} load cases timed to the valves (stand load "
                f"--rig --fastest, 0.5 %)", measured,
                f"at {rate:g} kgf/s: {at_rate['programme_time_s']:.1f} s",
                f"{at_rate['programme_time_s'] / s['time_s']:.2f}x faster" if s else "",
                f"{len(times)} passes ({'converged' if doc.get('converged') else 'not converged'}), "
                f"programme {' / '.join(f'{t:.1f}' for t in times)} s; worst channel p95 "
                f"{' / '.join(f'{v:.2f}' for v in p95)} %, max "
                f"{' / '.join(f'{v:.2f}' for v in mx)} %; minimum {minimum:.1f} s by the identified "
                f"model, segments set by {at_rate['segments_set_by']}; {wall:.0f} s wall")]


def design(root: Path, model: Path) -> tuple[dict, list[Row]]:
    from loading.controller_files import load_controller
    controllers, rows = {}, []
    for name, extra in (("decoupled", []), ("independent", ["--independent"])):
        path = root / f"{name}.toml"
        _, s = stand("design", model, "-o", path, *extra)
        c = load_controller(path, PERIOD_S)
        controllers[name] = c
        w = c.worst(True)
        rows.append(Row(f"rig load, design {name}",
                        f"boosted: gain margin {w.gain_margin:.2f}, phase margin {w.phase_margin_deg:.1f}°",
                        "one channel: 2 / 45°", "",
                        f"worst of {len(c.margins)} cases ({w.label}"
                        + (f", coupling {100 * w.coupling_error:+.0f} %" if w.coupling_error else "")
                        + f"); λ × {c.detuning:.2f}; stand design {s:.1f} s"))
    return controllers, rows


def load(controllers: dict, truth, noise, n_cases: int, rate: float, passes: int) -> tuple[dict, list[Row]]:
    """Step 3 at one rate: every pass's reports per controller, and the rows."""
    from gateway.load_experiment import LoadProgramme
    from gateway.offline import run_offline_pass
    from loading.compensation import Compensation
    from loading.programme import from_load_cases, random_load_cases
    p = from_load_cases(random_load_cases(n_cases, BANDS, seed=1), truth.names, PERIOD_S, rate_kgf_s=rate)
    limits = [9000.0, 9000.0, 4500.0, 4500.0]
    reports, rows = {}, []
    for name, c in controllers.items():
        comp = Compensation(truth.names)
        reports[name] = []
        for k in range(passes):
            e = LoadProgramme(p, c, comp)
            e.check(PERIOD_S, limits, 100.0)
            res = run_offline_pass(e, truth, 0.0, 10 + k, noise, force_limits=limits)
            if res.report is None:
                rows.append(Row(f"rig load, {rate:g} kgf/s, {name}", f"stopped in pass {k + 1}",
                                note=str(res.abort)))
                break
            reports[name].append(res.report)
            comp.learn(res.report.channels, p.ranges_kgf)
        reps = reports[name]
        if not reps:
            continue
        p95 = [max(r.peak_valley_error_pct["p95"] for r in rep.channels) for rep in reps]
        mx = [max(r.peak_valley_error_pct["max"] for r in rep.channels) for rep in reps]
        extra = [sum(r.extra_cycles for r in rep.channels) for rep in reps]
        worst = [rep.worst_channel for rep in reps]
        rows.append(Row(f"rig load, {n_cases} load cases at {rate:g} kgf/s, {name}, passes 1-{len(reps)}",
                        f"worst channel p95 {' / '.join(f'{v:.3f}' for v in p95)} %, max "
                        f"{' / '.join(f'{v:.3f}' for v in mx)} %",
                        "p95 <= 0.5 %, max <= 1 %, no extra cycle",
                        "met" if max(p95) <= 0.5 and max(mx) <= 1.0 and max(extra) == 0 else "not met",
                        f"worst channel {' / '.join(worst)}; extra cycles (all channels) "
                        f"{' / '.join(f'{v:g}' for v in extra)}; ratio error "
                        f"{' / '.join(f'{rep.ratio_error_pct:.3f}' for rep in reps)} %; programme "
                        f"{p.duration_s:.0f} s; offline (the gateway too slow for this sweep on 2 shared cores): "
                        "the emulator's coupled lockstep plant and its noise, no bus"))
    if reports.get("decoupled") and reports.get("independent"):
        d = max(r.peak_valley_error_pct["p95"] for r in reports["decoupled"][0].channels)
        i = max(r.peak_valley_error_pct["p95"] for r in reports["independent"][0].channels)
        rows.append(Row(f"rig load, {rate:g} kgf/s: independent / decoupled, worst channel p95, pass 1",
                        f"{i:.3f} % / {d:.3f} %", "goal >= 5x", f"{i / d:.1f}x"))
    return reports, rows


def run(quick: bool) -> list[Row]:
    from gateway.offline import emulated_truth
    from plant_emulator.process import RigEmulatorProcess
    truth, noise = emulated_truth(EXAMPLE)
    rows: list[Row] = []
    with tempfile.TemporaryDirectory(prefix="bench-rig-load-") as tmp:
        root = Path(tmp)
        rig = emulated_example(root)
        emulator = RigEmulatorProcess(rig, lockstep=True, seed=1).start()
        try:
            model, r = identify(root, rig, truth, quick)
            rows += r
            controllers, r = design(root, model)
            rows += r
            # quick: 5 load cases (3 turning points per channel), the fewest that still give
            # each channel peaks and valleys to judge
            rows += load_through_gateway(root, rig, root / "decoupled.toml", truth, 5 if quick else 20,
                                         2500.0, 1 if quick else 3)
            rows += fastest_through_gateway(root, rig, root / "decoupled.toml", 5 if quick else 20,
                                            2500.0, 2 if quick else 10)
        finally:
            emulator.stop()
        n_cases = 5 if quick else 100
        for rate in (2500.0, 5000.0):
            _, r = load(controllers, truth, noise, n_cases, rate, 1 if quick else 3)
            rows += r
    return rows
