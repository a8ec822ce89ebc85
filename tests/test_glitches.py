"""Glitches in the force reading (1-3 samples far off the trend) are replaced and said; corners,
steps, oscillations and quantized plateaus are left alone."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from analysis import diagnose, make_record
from analysis.records.glitches import remove_glitches
from tests.support import independent_stand as sim


def glitched(y: np.ndarray, rng, count: int, spacing: int = 12) -> tuple[np.ndarray, list]:
    """``y`` with ``count`` blocks of 1-3 samples moved 60-500 kgf off, at least ``spacing``
    samples apart."""
    slots = rng.choice(np.arange(10, (len(y) - 10) // spacing), count, replace=False) * spacing
    z = y.copy()
    placed = []
    for k in np.sort(slots):
        w = int(rng.integers(1, 4))
        z[k:k + w] += rng.choice([-1.0, 1.0]) * rng.uniform(60.0, 500.0)
        placed.append((int(k), w))
    return z, placed


@pytest.mark.slow
def test_clean_data_of_every_simulated_effect_is_left_alone():
    for effect in sim.EFFECT_PARAMS:
        for _, _, t, u, y, r, _ in sim.make_dataset(effect, 11):
            out, found = remove_glitches(y)
            assert found.count == 0 and out is y, effect


def test_sharp_corners_steps_oscillations_and_plateaus_are_not_glitches():
    t = np.arange(0, 4, 0.002)
    rng = np.random.default_rng(2)
    tri = 12000 * np.abs(((t / 0.5) % 2) - 1) * 0.5          # ±100 % meander at g = 120: corners
    step = np.where(t > 2.0, 800.0, 0.0) + 100 * t            # an offset jump
    osc = 200 * np.sin(2 * np.pi * 80 * t)                     # a fast oscillation
    flat = np.round(rng.normal(0, 0.2, len(t)) / 10) * 10      # 10 kgf resolution, mostly flat
    for y in (tri, step, osc, flat):
        y = y + rng.normal(0, 2.0, len(t))
        assert remove_glitches(y)[1].count == 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_glitches_are_replaced_by_the_trend(seed):
    rng = np.random.default_rng(seed)
    for _, _, t, u, y, r, y_true in sim.make_dataset("rev_flow+deadzone", 30 + seed):
        z, placed = glitched(y, rng, 30)
        out, found = remove_glitches(z)
        assert found.count == len(placed)
        assert found.samples == sum(w for _, w in placed)
        assert np.max(np.abs(out - y)) < 15.0          # back on the trend, within the noise
        assert 60.0 * 0.9 < found.largest_kgf <= 500.0 * 1.1


@pytest.mark.slow
def test_glitches_no_longer_hide_the_missing_effect_and_are_noted(tmp_path):
    """One 60-500 kgf glitch per ~600 samples made a perfect model 4.6× the noise floor
    ("unexplained") and hid a dead zone; now base is adequate, the dead zone is named."""
    rng = np.random.default_rng(7)
    for effect, verdict in (("none", "adequate"), ("deadzone", "missing_effect")):
        recs = []
        for name, _, t, u, y, r, _ in sim.make_dataset(effect, 91):
            z, _ = glitched(y, rng, len(y) // 600)
            recs.append(make_record(t, u, z, r if np.isfinite(r).any() else None, source=name))
        assert all(any("glitch" in n for n in rec.notes) for rec in recs)
        d = diagnose(recs)
        assert d.verdict == verdict, d.summary
        if effect == "deadzone":
            assert d.best == "deadzone"
    # the CLI says what it changed
    rec = recs[0]
    raw = np.column_stack([rec.t, rec.u, glitched(rec.y, rng, 5)[0]])
    np.savetxt(tmp_path / "g.csv", raw, delimiter=",", header="t,u,y", comments="")
    res = subprocess.run([sys.executable, "-m", "stand", "fit", str(tmp_path / "g.csv"),
                          "--model", "base"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "note: " in res.stderr and "replaced 5 glitch(es)" in res.stderr, res.stderr
    res = subprocess.run([sys.executable, "-m", "stand", "diagnose", str(tmp_path / "g.csv"),
                          "--json", "--no-progress", "--candidates", "deadzone"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    notes = json.loads(res.stdout)["data_notes"]
    assert list(notes) == [str(tmp_path / "g.csv")] and "replaced 5 glitch(es)" in notes[str(tmp_path / "g.csv")][0]
