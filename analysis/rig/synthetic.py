"""Synthetic rig runs with a known answer: a :class:`~plant.rig.RigModel` behind one
:class:`~plant.Dynamometer` per channel, driven by open-loop meanders, and written as the
gateway writes a rig run (``run.json`` with a ``rig`` section, ``signals.parquet`` with
``t, cycle`` and ``u.<name>, y.<name>, r.<name>`` per channel, ``truth.json``).

The identification's tests, the benchmark and the documentation's examples use these until the
rig gateway records them from the rig emulator through the bus; the analysis reads both alike.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import numpy as np

from plant import Dynamometer
from plant.rig import RigModel
from rig.excitation import hadamard_order, hadamard_signs

from .record import RigRecord, make_rig_record


def square(amplitude_pct: float, period_s: float, n: int, dt: float) -> np.ndarray:
    """The gateway's meander over ``n`` samples: ``±u0`` switching every half period, the first
    segment a quarter period long (as :func:`analysis.records.synthetic.square_wave`)."""
    t = np.arange(n) * dt
    seg = np.floor((t + period_s / 4) / (period_s / 2) + 1e-9)
    return np.where(seg % 2 == 0, amplitude_pct, -amplitude_pct).astype(float)


def rig_meander(rig: RigModel, amplitudes_pct: Sequence[float], periods_s: Sequence[float],
                duration_s: float, dt: float = 0.002, noise_kgf: float = 2.0,
                resolution_kgf: float = 0.5, range_kgf: float = 10000.0, seed: int = 0,
                y0_kgf: float | Sequence[float] = 0.0, source: str | None = None,
                u_before_pct: float | Sequence[float] = 0.0) -> RigRecord:
    """Every channel a meander of its own amplitude and period at once (an amplitude of 0: the
    channel's valve held at a zero command), for ``duration_s``; the commands before the run at
    ``u_before_pct`` (0: from rest; the other way than the meander's first: a valve held so,
    its rod reverses at the run's start). Channel i's dynamometer has the seed ``seed + i``."""
    n = int(round(duration_s / dt))
    u = np.vstack([square(a, p, n, dt) if a else np.zeros(n)
                   for a, p in zip(amplitudes_pct, periods_s)])
    if u.shape[0] != rig.n:
        raise ValueError(f"{u.shape[0]} amplitudes/periods for a rig of {rig.n} channels")
    moving = [nm for nm, a in zip(rig.names, amplitudes_pct) if a]
    label = source or f"synthetic rig meander ({', '.join(moving) or 'no channel'} moving)"
    params = {"amplitude_pct": dict(zip(rig.names, map(float, amplitudes_pct))),
              "period_s": dict(zip(rig.names, map(float, periods_s)))}
    return _measured(rig, u, dt, "meander", params, label, noise_kgf, resolution_kgf, range_kgf,
                     seed, y0_kgf, u_before_pct)


def _measured(rig: RigModel, u: np.ndarray, dt: float, experiment: str, params: dict,
              label: str, noise_kgf: float, resolution_kgf: float, range_kgf: float, seed: int,
              y0_kgf: float | Sequence[float], u_before_pct: float | Sequence[float]) -> RigRecord:
    """The rig driven by the commands ``u`` (N, K), each force read by its own dynamometer
    (seed ``seed + i``), as a record of ``experiment`` with ``params``."""
    y = rig.simulate(u, dt, y0=y0_kgf, u_before=u_before_pct)
    readings = np.vstack([
        Dynamometer(noise_kgf=noise_kgf, resolution_kgf=resolution_kgf, range_kgf=range_kgf,
                    seed=seed + i).measure(y[i])[0] for i in range(rig.n)])
    meta = {"experiment": {"name": experiment, "params": params}}
    return make_rig_record(np.arange(u.shape[1]) * dt, u, readings, rig.names, source=label,
                           meta=meta, experiment=experiment)


def rig_one_run(rig: RigModel, amplitude_pct: float | Sequence[float], slot_s: float,
                repeats: int = 1, dt: float = 0.002, noise_kgf: float = 2.0,
                resolution_kgf: float = 0.5, range_kgf: float = 10000.0, seed: int = 0,
                y0_kgf: float | Sequence[float] = 0.0, source: str | None = None,
                u_before_pct: float | Sequence[float] = 0.0) -> RigRecord:
    """The one-run experiment (:mod:`rig.excitation`): every channel a ±u0 meander whose signs
    follow its row of a Hadamard matrix as doublets, all switching every ``slot_s``, the
    pattern ``repeats`` times, as the gateway's :class:`~gateway.experiments.one_run.OneRun`
    plays it."""
    amps = np.broadcast_to(np.asarray(amplitude_pct, float), (rig.n,))
    signs = hadamard_signs(rig.n, repeats)
    per = int(round(slot_s / dt))
    u = amps[:, None] * np.repeat(signs, per, axis=1)
    params = {"excitation": "hadamard", "slot_s": per * dt, "repeats": repeats,
              "order": hadamard_order(rig.n), "slots": int(signs.shape[1]),
              "amplitude_pct": dict(zip(rig.names, map(float, amps)))}
    label = source or f"synthetic one-run rig excitation ({rig.n} channels, slots of {slot_s:g} s)"
    from gateway.experiments.one_run import OneRun
    return _measured(rig, u, dt, OneRun.name, params, label, noise_kgf, resolution_kgf,
                     range_kgf, seed, y0_kgf, u_before_pct)


def per_column_meanders(rig: RigModel, amplitude_pct: float = 5.0, period_s: float = 4.0,
                        cycles: int = 5, **kw) -> list[RigRecord]:
    """The per-column experiment: one run per channel, that channel a meander, the others'
    valves at a zero command (each run's dynamometer seeds differ)."""
    seed = kw.pop("seed", 0)
    out = []
    for j, name in enumerate(rig.names):
        amps = [amplitude_pct if i == j else 0.0 for i in range(rig.n)]
        out.append(rig_meander(rig, amps, [period_s] * rig.n, cycles * period_s,
                               seed=seed + 100 * j, source=f"synthetic column run: {name} moving",
                               **kw))
    return out


def rig_truth(rig: RigModel) -> dict:
    """What ``truth.json`` says of a rig, as the rig emulator writes it
    (``rig.emulated.rig_truth``): the channels, G, and each channel's plant by name."""
    return {"channels": rig.names, "G": rig.G.tolist(), "structure_from": "G",
            "plants": {n: {"model": m.spec, "params": m.params()}
                       for n, m in zip(rig.names, rig.channels)}}


def write_rig_run(rec: RigRecord, path: str | Path, truth: dict | None = None,
                  rig_name: str = "synthetic rig") -> Path:
    """Write ``rec`` as a rig run directory (the gateway's format, see the module docstring);
    ``truth``: written to ``truth.json`` (the analysis never reads it)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    u, y, r = rec.u, rec.y, rec.r
    driven = [n for n, row in zip(rec.names, u) if np.any(row != 0)]
    meta = {
        "format": "hydrostand-run/1",
        "experiment": rec.meta.get("experiment") or {"name": rec.channels[0].experiment,
                                                     "params": {}},
        "period_s": rec.dt,
        "status": "completed",
        "source": rec.source,
        "rig": {"name": rig_name, "period_ms": rec.dt * 1e3,
                "buses": [{"name": "can0", "spec": "udp_loopback:rig0",
                           "capture": "capture-can0.log"}],
                "channels": [{"name": n, "bus": "can0",
                              "nodes": {"valve": 2 * i + 1, "dynamometer": 2 * i + 2}}
                             for i, n in enumerate(rec.names)],
                "driven": driven},
    }
    columns = {"t": rec.t, "cycle": np.arange(len(rec), dtype=np.int64)}
    for col, data in (("u", u), ("y", y), ("r", r)):
        for n, row in zip(rec.names, data):
            columns[f"{col}.{n}"] = row
    pq.write_table(pa.table(columns), path / "signals.parquet")
    (path / "run.json").write_text(json.dumps(meta, indent=2))
    if truth is not None:
        (path / "truth.json").write_text(json.dumps(truth, indent=2))
    return path
