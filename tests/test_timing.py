"""Timing jitter of the command steps, read from the residual's jumps (analysis/diagnosis/timing.py)."""
from __future__ import annotations

import numpy as np
import pytest

from analysis import evaluate, make_record
from analysis.diagnosis.timing import jitter_observation, timing_jitter
from plant import PlantModel

DT = 0.002
FINE = 20                     # 0.1 ms steps for the "true" stand
MODEL = PlantModel(g=120.0, tau=0.05, delta=0.0)


def meanders(shift_s, amp=10.0, half=0.5, seconds=40.0, osc=0.0, seed=0):
    """A ±amp meander sampled at 2 ms; the stand sees step i shifted by shift_s(i) (s), on a
    0.1 ms grid, plus 1 kgf noise and an optional 3 Hz, ``osc`` kgf oscillation."""
    rng = np.random.default_rng(seed)
    n = int(seconds / DT)
    t = np.arange(n) * DT
    u = np.where((t // half) % 2 == 0, amp, -amp)
    edges = np.flatnonzero(np.diff(u)) + 1
    uf = np.repeat(u, FINE)
    for i, k in enumerate(edges):           # move each step by its own timing error
        at = k * FINE + int(round(shift_s(i) / (DT / FINE)))
        lo, hi = sorted((k * FINE, at))
        uf[lo:hi] = u[k - 1] if at > k * FINE else u[k]
    yf = PlantModel(g=120.0, tau=0.05).simulate(uf, DT / FINE, u_before=u[0])
    y = yf[::FINE] + rng.normal(0, 1.0, n) + osc * np.sin(2 * np.pi * 3 * t + 1.0)
    return [make_record(t, u, y, source="meander")]


def test_steps_passed_on_with_a_jitter_are_measured_and_said():
    rng = np.random.default_rng(5)
    eps = rng.normal(0, 0.0015, 200)        # 1.5 ms rms, either way
    recs = meanders(lambda i: eps[i])
    ev = evaluate(MODEL, recs)
    j = timing_jitter(ev.sims, MODEL.g)
    assert j is not None and j["steps"] >= 60
    assert j["rms_s"] == pytest.approx(0.0015, rel=0.25)
    said = jitter_observation(ev.sims, MODEL.g)
    assert len(said) == 1 and "timing jitter" in said[0]
    assert float(said[0].split("about ±")[1].split(" ms")[0]) == pytest.approx(j["rms_s"] * 1e3, abs=0.05)


@pytest.mark.parametrize("case", ["none", "late", "one_way", "oscillation"])
def test_no_jitter_is_claimed_for_exact_timing_a_fixed_error_or_a_disturbance(case):
    shift = {"none": lambda i: 0.0,
             "late": lambda i: 0.004,                          # a τ error: the fit's job
             "one_way": lambda i: 0.006 if i % 2 else 0.0,     # a direction delay: systematic
             "oscillation": lambda i: 0.0}[case]
    recs = meanders(shift, osc=15.0 if case == "oscillation" else 0.0)
    ev = evaluate(MODEL, recs)
    assert timing_jitter(ev.sims, MODEL.g) is None
    assert jitter_observation(ev.sims, MODEL.g) == []
