"""End to end: the paper's reversal effect is found on emulator runs with it switched on.

The emulator runs as a separate process on the loopback bus (its default plant: base + reversal),
the gateway runs the meander in lockstep at two amplitudes, and `stand diagnose` reads the two
run directories as one data set.
"""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from analysis import diagnose, read_run
from gateway import Gateway, GatewayConfig, SafetyLimits
from gateway.experiments import Meander
from tests.support.stand import BASE, plant

pytestmark = pytest.mark.e2e


def _config(bus_spec: str) -> GatewayConfig:
    # lockstep: stand time is not wall time; on a loaded test machine the wall-clock heartbeat
    # watchdog must not end the run
    return GatewayConfig(bus=bus_spec, lockstep=True, limits=SafetyLimits(heartbeat_timeout_s=10.0))


def _runs(bus_spec, start_emulator, tmp_path, model, values: dict | None = None):
    start_emulator(plant({**BASE, **(values or {})}, model=model), lockstep=True, seed=5)
    paths = []
    with Gateway(_config(bus_spec)) as gw:
        for amp in (5.0, 20.0):
            res = gw.run(Meander(amplitude_pct=amp, period_s=2.0, cycles=3), tmp_path / f"m{amp:g}",
                         progress=False)
            assert res.status == "complete", res.outcome.message
            paths.append(res.path)
    return paths


@pytest.mark.slow
def test_reversal_effect_is_found_on_emulator_runs(bus_spec, start_emulator, tmp_path):
    paths = _runs(bus_spec, start_emulator, tmp_path, "base+reversal")
    d = diagnose([read_run(p) for p in paths])
    assert d.verdict == "missing_effect" and d.best == "reversal", d.summary
    best = d.best_candidate
    assert best.rmse_reduction >= 0.70
    assert best.params["reversal.boost"] == pytest.approx(2.0, rel=0.15)
    assert best.params["g"] == pytest.approx(120.0, rel=0.03)
    # the same through the command line, as JSON (the two run directories are one data set)
    out = subprocess.run([sys.executable, "-m", "stand", "diagnose", *map(str, paths), "--json",
                          "--no-progress"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    assert doc["verdict"] == "missing_effect" and doc["candidates"][0]["effect"] == "reversal"


@pytest.mark.slow
def test_a_boost_that_dies_out_over_the_travel_is_told_from_a_timed_one_on_emulator_runs(
        bus_spec, start_emulator, tmp_path):
    """travel_reversal behind CANopen, at 5 and 20 %: its transition is four times shorter at
    20 % (the timed `reversal` lasts the same at both), which is how the two are told apart."""
    truth = {"travel_reversal.boost": 2.5, "travel_reversal.travel": 1.2}
    paths = _runs(bus_spec, start_emulator, tmp_path, "base+travel_reversal", truth)
    d = diagnose([read_run(p) for p in paths])
    assert d.verdict == "missing_effect" and d.best == "travel_reversal", d.summary
    p = d.best_candidate.params
    assert p["travel_reversal.boost"] == pytest.approx(2.5, rel=0.1)
    assert p["travel_reversal.travel"] == pytest.approx(1.2, rel=0.1)
    timed = next(c for c in d.candidates if c.effect == "reversal")
    assert timed.objective_rmse > 1.5 * d.best_candidate.objective_rmse


@pytest.mark.slow
def test_the_emulator_without_the_effect_is_adequate(bus_spec, start_emulator, tmp_path):
    """The emulator integrates in 0.5 ms sub-steps behind CANopen, the analysis at the 2 ms
    control period: the base model must still be adequate (no false alarm)."""
    paths = _runs(bus_spec, start_emulator, tmp_path, "base")
    d = diagnose([read_run(p) for p in paths])
    assert d.verdict == "adequate", d.summary


@pytest.mark.slow
def test_a_specimen_that_stiffens_with_the_load_is_found_on_emulator_runs(bus_spec, start_emulator,
                                                                          tmp_path):
    """A catalogue effect that depends on the force, behind CANopen: the emulator steps it in
    0.5 ms sub-steps period by period, the analysis in 2 ms windows."""
    truth = {"stiffness.k_abs": 2.0, "stiffness.k_sgn": -0.5}
    paths = _runs(bus_spec, start_emulator, tmp_path, "base+stiffness", truth)
    d = diagnose([read_run(p) for p in paths])
    assert d.verdict == "missing_effect" and d.best == "stiffness", d.summary
    p = d.best_candidate.params
    assert p["stiffness.k_abs"] == pytest.approx(2.0, rel=0.1)
    assert p["stiffness.k_sgn"] == pytest.approx(-0.5, abs=0.15)
    assert d.best_candidate.rmse_reduction >= 0.7


@pytest.mark.slow
def test_rod_stiction_is_found_on_emulator_runs(bus_spec, start_emulator, tmp_path):
    """The reading holds after each reversal until the force has crossed the play (0.2 s at 5 %,
    0.05 s at 20 %): a state the emulator carries from period to period."""
    paths = _runs(bus_spec, start_emulator, tmp_path, "base+stiction", {"stiction.width": 120.0})
    d = diagnose([read_run(p) for p in paths])
    assert d.verdict == "missing_effect" and d.best == "stiction", d.summary
    p = d.best_candidate.params
    assert p["stiction.width"] == pytest.approx(120.0, rel=0.05)
    assert p["tau"] == pytest.approx(BASE["tau"], abs=0.003)
    assert d.best_candidate.rmse_reduction >= 0.7


@pytest.mark.parametrize("effect, rate", [("gain_drift", 0.03),
                                          pytest.param("null_drift", 0.06, marks=pytest.mark.slow)])
def test_a_drift_from_the_start_of_every_run_is_found_on_emulator_runs(bus_spec, start_emulator,
                                                                       tmp_path, effect, rate):
    """The gain grows 3 %/s, or the valve's null moves 0.06 %/s, from the start of each run:
    the emulator's plant clock restarts when the gateway starts the nodes for the next run, as
    the run's record does (one clock over both runs would start the second one drifted, and
    the fit could not match both)."""
    truth = {f"{effect}.rate": rate, f"{effect}.time_constant": 1e5}
    paths = _runs(bus_spec, start_emulator, tmp_path, f"base+{effect}", truth)
    d = diagnose([read_run(p) for p in paths])
    assert d.verdict == "missing_effect" and d.best == effect, d.summary
    p = d.best_candidate.params
    assert p[f"{effect}.rate"] == pytest.approx(rate, rel=0.1)
    assert p["g"] == pytest.approx(BASE["g"], rel=0.03)
    assert d.best_candidate.rmse_reduction >= 0.7
