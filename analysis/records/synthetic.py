"""Synthetic recordings from the plant model: the paper's three experiments, open and closed loop.

Known answers for tests, benchmarks and demonstrations come from here: a :class:`~plant.PlantModel`
(any effects) behind a :class:`~plant.Dynamometer` (noise, resolution, range), driven like the
stand is driven by the gateway. The timing convention is the control loop's (and the emulator's
in lockstep): at sample ``k`` the force ``y[k]`` is read, the command ``u[k]`` is computed from it
and held over ``[t_k, t_{k+1})``.

* :func:`meander` — open loop, square wave ``±u0`` per amplitude (paper Figs. 3-10, eq. 2);
* :func:`relay` — ``u = u0·sign(r − y)`` (Figs. 19-23, eq. 4);
* :func:`pfeedback` — ``u = k·(r − y)``, ``r = A_r·sin(ωt)`` (Figs. 13-18, eq. 3).

Closed loops are stepped with :meth:`PlantModel.new_state`/:meth:`PlantModel.advance` in blocks
no longer than the transport delay (the forces inside such a block do not depend on the block's
own commands), so a minute of 2 ms data takes well under a second.
"""
from __future__ import annotations

import copy
import math
from typing import Callable, Sequence

import numpy as np

from plant import Dynamometer, PlantModel

from .record import Record, make_record

#: control law ``(t, y_measured, k) -> (u, r)`` evaluated once per sample
Law = Callable[[float, float, int], tuple[float, float]]


def _sensor(noise_kgf: float, resolution_kgf: float, range_kgf: float, seed: int | None) -> Dynamometer:
    return Dynamometer(noise_kgf=noise_kgf, resolution_kgf=resolution_kgf, range_kgf=range_kgf, seed=seed)


def square_wave(amplitude_pct: float, period_s: float, cycles: int, dt: float) -> np.ndarray:
    """The gateway's meander: ``±u0`` switching every half period, first segment a quarter
    period long (so the force ramps symmetrically around its start)."""
    n = int(round(cycles * period_s / dt))
    t = np.arange(n) * dt
    seg = np.floor((t + period_s / 4) / (period_s / 2) + 1e-9)
    return np.where(seg % 2 == 0, amplitude_pct, -amplitude_pct).astype(float)


def meander(model: PlantModel, amplitudes_pct: Sequence[float] = (5.0, 10.0, 15.0, 20.0),
            period_s: float = 2.0, cycles: int = 4, dt: float = 0.002, noise_kgf: float = 2.0,
            resolution_kgf: float = 0.5, range_kgf: float = 10000.0, offset_kgf: float = 0.0,
            y0: float = 0.0, seed: int | None = 0) -> Record:
    """Open-loop square waves, one block of ``cycles`` periods per amplitude, back to back.

    ``offset_kgf`` is added to the reading (a dynamometer zero offset)."""
    u = np.concatenate([square_wave(a, period_s, cycles, dt) for a in amplitudes_pct])
    y = model.simulate(u, dt, y0=y0, u_before=0.0)
    reading, _ = _sensor(noise_kgf, resolution_kgf, range_kgf, seed).measure(y)
    t = np.arange(len(u)) * dt
    return make_record(t, u, reading + offset_kgf, source=f"synthetic meander {model.spec}",
                       experiment="meander")


def closed_loop(model: PlantModel, law: Law, duration_s: float, dt: float = 0.002,
                noise_kgf: float = 2.0, resolution_kgf: float = 0.5, range_kgf: float = 10000.0,
                offset_kgf: float = 0.0, y0: float = 0.0, seed: int | None = 0,
                experiment: str | None = None) -> Record:
    """Run ``law`` in closed loop around the plant for ``duration_s``.

    Block trick: with ``τ = (m + f)·dt`` the forces after the next ``m`` steps depend only on
    commands already issued, so they are computed first (on a copy of the state, commands of the
    block unknown), then the law gives the block's commands, then the real state advances."""
    n = int(round(duration_s / dt))
    sensor = _sensor(noise_kgf, resolution_kgf, range_kgf, seed)
    m = model.delay_steps(dt)
    block = m + 1
    state = model.new_state(1, dt, y0=y0, u0=0.0)
    t = np.arange(n) * dt
    u = np.zeros(n)
    r = np.full(n, np.nan)
    y = np.zeros(n)
    truth = np.zeros(n)
    k = 0
    while k < n:
        K = min(block, n - k)
        if K > 1:  # forces at k+1 .. k+K-1 do not depend on u[k:k+K]
            trial = copy.deepcopy(state)
            ahead = model.advance(trial, np.zeros((1, K)), dt)[0]
            truth[k + 1:k + K] = ahead[:K - 1]
        truth[k] = state.reading[0]     # the force as the dynamometer sees it
        meas, _ = sensor.measure(truth[k:k + K])
        y[k:k + K] = meas + offset_kgf
        for j in range(K):
            u[k + j], r[k + j] = law(t[k + j], y[k + j], k + j)
        u[k:k + K] = np.clip(u[k:k + K], -100.0, 100.0)
        model.advance(state, u[None, k:k + K], dt)
        k += K
    return make_record(t, u, y, r, source=f"synthetic {experiment or 'closed loop'} {model.spec}",
                       experiment=experiment)


def relay(model: PlantModel, amplitude_pct: float = 10.0, references_kgf: Sequence[float] = (0.0,),
          seconds_per_reference: float = 6.0, hysteresis_kgf: float = 0.0, **kw) -> Record:
    """Relay feedback ``u = u0·sign(r − y)`` (with optional hysteresis ε), one constant
    reference after the other (paper Fig. 19)."""
    refs = list(references_kgf)
    last = [amplitude_pct]

    def law(t: float, y: float, k: int) -> tuple[float, float]:
        ref = refs[min(int(t / seconds_per_reference), len(refs) - 1)]
        e = ref - y
        if e > hysteresis_kgf:
            last[0] = amplitude_pct
        elif e < -hysteresis_kgf:
            last[0] = -amplitude_pct
        return last[0], ref

    return closed_loop(model, law, seconds_per_reference * len(refs), experiment="relay", **kw)


def pfeedback(model: PlantModel, gain: float = 0.005, amplitude_kgf: float = 2000.0,
              omegas_rad_s: Sequence[float] = (0.6283,), seconds_per_omega: float | None = None,
              **kw) -> Record:
    """Proportional feedback ``u = k·(r − y)`` with ``r = A_r·sin(ωt)``, one frequency after the
    other (paper Fig. 13). Default: two periods per frequency."""
    omegas = list(omegas_rad_s)
    spans = [seconds_per_omega or 2 * 2 * math.pi / w for w in omegas]
    edges = np.cumsum([0.0] + spans)

    def law(t: float, y: float, k: int) -> tuple[float, float]:
        i = min(int(np.searchsorted(edges, t, side="right")) - 1, len(omegas) - 1)
        ref = amplitude_kgf * math.sin(omegas[i] * (t - edges[i]))
        return gain * (ref - y), ref

    return closed_loop(model, law, float(edges[-1]), experiment="pfeedback", **kw)
