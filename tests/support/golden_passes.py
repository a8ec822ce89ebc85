"""Recorded one-channel load passes: the commands a stand's pass sent, cycle by cycle, kept so
that a change of the loading code can be held against them (tests/test_one_channel_unchanged.py).

Each scenario is a pass of the load experiment against the emulator's own lockstep plant (the
model ``stand emulate --lockstep`` runs) with the dynamometer's noise, stepped as the control
loop steps it: at cycle k the force read, the experiment's command, the command quantized to
counts as on the wire and held over the next period. What is kept is the experiment's command
before quantization (every bit of the law) and the reference.

``python -m tests.support.golden_passes`` writes ``tests/data/one_channel_passes.npz`` again:
only when a change of the one-channel commands is intended, and said so in its commit.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from dbc import profile as P

T = 0.002
DATA = Path(__file__).resolve().parent.parent / "data" / "one_channel_passes.npz"
#: the same through the gateway: ``stand load`` on the emulator process in lockstep
GATEWAY_DATA = DATA.with_name("one_channel_gateway_passes.npz")
DEFAULT = ("base+reversal", {"g": 120.0, "tau": 0.05, "delta": 8.0, "reversal.boost": 2.0})


def _truth(spec: str, values: dict):
    from plant import PlantModel
    return PlantModel.from_spec(spec, values)


def run_pass(experiment, truth, y0: float = 0.0, seed: int = 1, noise_kgf: float = 2.0,
             max_cycles: int = 400_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One pass: the commands (before quantization), the references and the forces per cycle."""
    from tests.support.station_step import stepper
    from plant_emulator.lockstep_plant import LockstepPlant
    plant = LockstepPlant(truth, y0, 0.0005)
    rng = np.random.default_rng(seed)
    begin, finished, step, aborted = stepper(experiment, T, 10000.0)
    y, t = y0, 0.0
    begin(y)
    us, rs, ys = [], [], []
    for _ in range(max_cycles):
        if finished(t, y):
            break
        u, r = step(t, y)
        if aborted():
            break
        us.append(u)
        rs.append(r)
        ys.append(y)
        sent = P.counts_to_percent(P.percent_to_counts(max(-100.0, min(100.0, u))))
        y = plant.step(T, sent) + rng.normal(0.0, noise_kgf)
        t += T
    return np.array(us, float), np.array(rs, float), np.array(ys, float)


def scenarios():
    """name -> a function making (experiment, truth, y0) afresh; a scenario named ``.../2`` runs
    after the one before it learnt (compensation, gain monitor)."""
    from tests.support.station_step import (compensation, design_from, gain_monitor, load_programme_for,
                                            pacing, proportional_from, programme_levels, programme_sine)
    model = _truth(*DEFAULT)
    c = design_from(model)
    levels = programme_levels(12, seed=3, rate=2500.0)
    out = {}
    out["plain"] = lambda: (load_programme_for(levels(), c), model, 0.0)
    out["from_above"] = lambda: (load_programme_for(levels(), c), model, 6000.0)
    comp = compensation()
    out["compensated/1"] = lambda: (load_programme_for(levels(), c, compensation=comp), model, 0.0)
    out["compensated/2"] = lambda: (load_programme_for(levels(), c, compensation=comp), model, 0.0)
    limited = _truth("base+reversal+saturation", {**DEFAULT[1], "saturation.limit": 25.0})
    fast = programme_levels(16, seed=5, rate=5000.0)
    out["paced_dynamic"] = lambda: (load_programme_for(fast(), c, pacing=pacing("dynamic")), limited, 0.0)
    out["paced_static_sine"] = lambda: (load_programme_for(programme_sine(), c, pacing=pacing("static")),
                                         limited, 0.0)
    soft = _truth(*(DEFAULT[0], {**DEFAULT[1], "g": 108.0}))
    monitor = gain_monitor(c, block_s=1.0, follow=True)
    out["gain_adapt/1"] = lambda: (load_programme_for(levels(), c, monitor=monitor), soft, 0.0)
    out["gain_adapt/2"] = lambda: (load_programme_for(levels(), c, monitor=monitor), soft, 0.0)
    out["p_only"] = lambda: (load_programme_for(levels(), proportional_from(model, 0.02)), model, 0.0)
    lagged = _truth("base+reversal+lag", {**DEFAULT[1], "lag.time_constant": 0.03})
    out["lag_model"] = lambda: (load_programme_for(levels(), design_from(lagged)), lagged, 0.0)
    return out


def record() -> dict[str, np.ndarray]:
    """Every scenario's commands and references (a compensation learns between ``/1`` and
    ``/2`` from the first pass's tracking report, as ``stand load --repeat`` does)."""
    from tests.support.station_step import learn
    out = {}
    for name, make in scenarios().items():
        experiment, truth, y0 = make()
        u, r, y = run_pass(experiment, truth, y0)
        out[f"{name}:u"], out[f"{name}:r"] = u, r
        learn(experiment, u, r, y, T)
    return out


#: ``stand load`` runs through the gateway: name -> its options (besides the programme, the
#: controller, the bus and --lockstep)
GATEWAY_RUNS = {"repeat": ["--rate", "2500", "--repeat", "2"],
                "fastest": ["--fastest", "--repeat", "3"]}
#: the emulator's seed for them
GATEWAY_SEED = 4


def gateway_inputs(directory: Path) -> tuple[Path, Path]:
    """The programme (a turning-point CSV) and the controller (designed from the emulator's
    default stand) the gateway runs load."""
    from loading.design import design
    from loading.programme import random_sequence
    programme = directory / "programme.csv"
    programme.write_text("level\n" + "\n".join(f"{v:.1f}" for v in random_sequence(8, 400, 6200, seed=7)) + "\n")
    controller = directory / "controller.toml"
    controller.write_text(design(_truth(*DEFAULT), T).to_toml(controller))
    return programme, controller


def gateway_passes(out: Path) -> tuple[list[np.ndarray], int]:
    """Every pass's recorded commands under ``out`` (pass-1, pass-2, ...), and the stale cycles
    of them all."""
    import json

    from gateway import load_run
    us, stale = [], 0
    for run in sorted(out.glob("pass-*"), key=lambda p: int(p.name.split("-")[1])):
        us.append(np.asarray(load_run(run).u, float))
        stale += int(json.loads((run / "run.json").read_text())["stats"].get("stale_cycles", 0))
    return us, stale


def gateway_record(bus: str, directory: Path) -> dict[str, np.ndarray]:
    """Every :data:`GATEWAY_RUNS` run through the gateway on ``bus`` (an emulator of the
    default stand in lockstep, seed :data:`GATEWAY_SEED`, runs there): its passes' commands."""
    from stand.cli import main as stand
    programme, controller = gateway_inputs(directory)
    out = {}
    for name, options in GATEWAY_RUNS.items():
        target = directory / name
        code = stand(["load", str(programme), "--controller", str(controller), "--out", str(target),
                      "--bus", bus, "--lockstep", "--no-progress", *options])
        if code not in (0, 1):
            raise RuntimeError(f"stand load {name}: exit {code}")
        us, stale = gateway_passes(target)
        if stale:
            raise RuntimeError(f"stand load {name}: {stale} stale cycles; record on a quieter host")
        for i, u in enumerate(us, start=1):
            out[f"{name}/{i}:u"] = u
    return out


def _record_gateway() -> dict[str, np.ndarray]:
    import os
    import tempfile

    from plant_emulator.process import EmulatorProcess
    bus = f"udp_loopback:golden-{os.getpid()}"
    proc = EmulatorProcess(bus, None, lockstep=True, seed=GATEWAY_SEED).start()
    try:
        with tempfile.TemporaryDirectory() as d:
            return gateway_record(bus, Path(d))
    finally:
        proc.stop()


def main() -> int:
    for data, path in ((record(), DATA), (_record_gateway(), GATEWAY_DATA)):
        path.parent.mkdir(exist_ok=True)
        np.savez_compressed(path, **data)
        for k, v in data.items():
            if k.endswith(":u"):
                print(f"{k[:-2]:<20} {len(v):6d} cycles")
        print(f"-> {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
