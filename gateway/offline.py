"""A station's load pass without a bus: the emulator's own coupled lockstep plant
(:class:`plant_emulator.lockstep_plant.LockstepRig`, what ``stand emulate --rig --lockstep``
runs; one channel's is the stand's) stepped one period per cycle with each dynamometer's noise,
the commands quantized to counts as on the wire. For tests and benchmarks of the control law
apart from the CANopen gateway; a pass on the station (``stand load``) is
:func:`gateway.load.run_load`.

At cycle k the plant has advanced to t_k under the commands of cycle k-1; the experiment reads
every force and returns every command, which acts over [t_k, t_k + T).

Passes one after the other on one plant (an endurance test's flights) give each pass the stand
time it starts at (``start_s``: the previous pass's :attr:`OfflinePass.end_s`), which a
structure's scheduled change (:class:`plant.rig.StructureChange`) counts on."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from dbc import profile as P
from loading.report import TrackingReport, tracking_report
from plant.rig import RigModel
from plant_emulator.lockstep_plant import LockstepRig

from .load_experiment import LoadProgramme


@dataclass
class OfflinePass:
    report: TrackingReport | None
    t: np.ndarray                  #: the programme's clock (0 at its start)
    y: np.ndarray                  #: (N, K) forces read
    u: np.ndarray                  #: (N, K) commands sent
    abort: tuple[str, str] | None
    #: the plant's stand time at the pass's end (the next pass's ``start_s``)
    end_s: float = 0.0


def emulated_truth(rig_file: str | Path) -> tuple[RigModel, list[float]]:
    """A rig file's coupled plant as the emulator runs it, and each channel's noise (kgf)."""
    from rig.config import load_rig_file
    from rig.emulated import emulated_plant
    plant = emulated_plant(load_rig_file(rig_file))
    return plant.model, [float(p.sensor.get("noise_kgf", 0.0)) for p in plant.plants]


def run_offline_pass(experiment: LoadProgramme, truth: RigModel, y0: float | Sequence[float] = 0.0,
                 seed: int = 0, noise_kgf: float | Sequence[float] = 2.0,
                 force_limits: Sequence[float] | None = None, period_s: float = 0.002,
                 max_s: float = 5000.0, start_s: float = 0.0) -> OfflinePass:
    """One pass of ``experiment`` on ``truth`` (module docstring), from the stand time
    ``start_s``."""
    n = truth.n
    T = period_s
    noise = np.broadcast_to(np.asarray(noise_kgf, float), (n,))
    plant = LockstepRig(truth, y0, 0.0005, start_s=start_s)
    rng = np.random.default_rng(seed)
    experiment.configure_rig(T, force_limits if force_limits is not None else [1e5] * n)
    y = np.array(plant.forces) + rng.normal(0.0, 1.0, n) * noise
    t = 0.0
    experiment.begin_rig(y)
    ts, ys, us = [], [], []
    while not experiment.finished_rig(t, y) and t < max_s:
        u, _ = experiment.step_rig(t, y)
        if experiment.abort is not None:
            break
        u = [P.counts_to_percent(P.percent_to_counts(max(-100.0, min(100.0, v)))) for v in u]
        y = np.array(plant.step(T, u)) + rng.normal(0.0, 1.0, n) * noise
        t += T
        ts.append(t)
        ys.append(y)
        us.append(u)
    Y, U = np.array(ys).T, np.array(us).T
    abort = experiment.abort
    if abort is not None and experiment.abort_channel is not None:
        abort = (abort[0], f"channel {experiment.names[experiment.abort_channel]}: {abort[1]}")
    start = experiment.programme_start_s
    end_s = plant.stand_time_s
    if start is None or abort is not None:
        return OfflinePass(None, np.array(ts), Y, U, abort, end_s)
    tp = experiment.programme_times(np.array(ts))
    return OfflinePass(tracking_report(experiment.programme, tp, Y), tp, Y, U, None, end_s)
