"""An experiment driven offline: a tiny discrete stand with the control loop's timing (read y[k]
at t_k, command u[k] held over [t_k, t_k+1), plant advanced in 0.5 ms sub-steps like the emulator,
dynamometer noise and resolution)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from analysis import Record, make_record
from dbc import profile as P
from gateway.experiments import Experiment
from plant.config import PlantConfig


@dataclass
class OfflineRun:
    record: Record
    reason: str | None
    message: str | None


def run_offline(experiment: Experiment, config: PlantConfig, period_s: float = 0.002, seed: int = 0,
                force_limit_kgf: float = 9500.0, y0: float | None = None,
                max_cycles: int = 2_000_000) -> OfflineRun:
    """Run ``experiment`` against the plant of ``config`` with the gateway loop's timing.

    At cycle k: the plant has advanced to t_k = k·T under the command u[k−1]; the dynamometer
    reads y[k]; the supervisor checks |y| against the force limit; the experiment returns u[k]
    (quantized as on the wire), which acts over [t_k, t_k+T)."""
    model = config.model
    sub = max(1, math.ceil(period_s / 0.0005 - 1e-9))
    dt = period_s / sub
    state = model.new_state(1, dt, y0=config.initial_force_kgf if y0 is None else y0)
    sensor = config.dynamometer(seed)
    experiment.abort = None
    experiment.configure(period_s, force_limit_kgf)
    rows = []
    reason = message = None
    u = 0.0
    for k in range(max_cycles):
        if k:
            model.advance(state, np.full((1, sub), u), dt)
        reading, _ = sensor.measure(state.y[0])
        y = float(reading)
        t = k * period_s
        if abs(y) > force_limit_kgf:
            reason, message = "force_limit", f"force {y:.0f} kgf beyond the limit"
            break
        if k == 0:
            experiment.begin(y)
        if experiment.finished(t, y):
            break
        u_req, r = experiment.step(t, y)
        if experiment.abort is not None:
            reason, message = experiment.abort
            break
        u = P.counts_to_percent(P.percent_to_counts(max(-100.0, min(100.0, u_req))))
        rows.append((t, u, y, r))
    a = np.array(rows, float).reshape(-1, 4)
    rec = make_record(a[:, 0], a[:, 1], a[:, 2], a[:, 3], source=f"offline {experiment.name}",
                      experiment=experiment.name,
                      meta={"experiment": {"name": experiment.name, "params": experiment.params()},
                            "period_s": period_s, "clock": "offline"}, min_samples=2)
    return OfflineRun(rec, reason, message)
