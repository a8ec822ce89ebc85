"""The experiments' command laws: set-point approach, force guard, meander, relay, P feedback.

Most tests drive the experiment objects through :func:`tests.support.offline.run_offline`, a tiny
discrete stand with the control loop's timing (read y[k] at t_k, command u[k] held over
[t_k, t_k+1), plant advanced in 0.5 ms sub-steps like the emulator, dynamometer noise and
resolution); the last ones run them through the real gateway and emulator.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from dbc import profile as P
from gateway.errors import ParameterError
from gateway.experiments import EXPERIMENTS, make_experiment
from gateway.experiments.meander import Meander
from gateway.experiments.phases import FORCE_NEAR_LIMIT, SET_POINT_NOT_REACHED
from gateway.experiments.pfeedback import PFeedback
from gateway.experiments.relay import Relay
from tests.support.offline import run_offline
from tests.support.stand import BASE, plant


def wire(u_pct: float) -> float:
    """A command as it goes on the wire (INT16 counts of 1/163.84 %)."""
    return P.counts_to_percent(P.percent_to_counts(u_pct))


# -- registry and parameters ------------------------------------------------------------------
def test_the_three_experiments_are_discovered_and_built_by_name():
    assert {"meander", "pfeedback", "relay"} <= set(EXPERIMENTS)
    relay = make_experiment("relay", {"amplitude_pct": 15.0, "reference_kgf": -500.0})
    assert isinstance(relay, Relay) and relay.params()["reference_kgf"] == -500.0
    pf = make_experiment("pfeedback", {"omega_rad_s": 1.2566})
    assert isinstance(pf, PFeedback)
    assert pf.main_duration_s == pytest.approx(pf.transient_s + pf.periods * 2 * math.pi / 1.2566)


@pytest.mark.parametrize("name, params, words", [
    ("relay", {"amplitude_pct": 0}, ["amplitude_pct", "out of range"]),
    ("relay", {"hysteresis_kgf": -1}, ["hysteresis_kgf"]),
    ("pfeedback", {"omega_rad_s": 0}, ["omega_rad_s"]),
    ("pfeedback", {"gain": float("nan")}, ["gain"]),
    ("meander", {"settle_max_s": -1}, ["settle_max_s"]),
    ("meander", {"guard_fraction": 2}, ["guard_fraction"]),
    ("relay", {"bogus": 1}, ["accepts", "reference_kgf"]),
])
def test_bad_parameters_are_rejected_with_the_name_and_range(name, params, words):
    with pytest.raises(ParameterError) as err:
        make_experiment(name, params)
    for w in words:
        assert w in str(err.value)


# -- the set-point approach and the guard -----------------------------------------------------
def test_meander_at_its_set_point_starts_at_once_and_keeps_the_old_length():
    run = run_offline(Meander(amplitude_pct=5, period_s=1, cycles=2, set_point_kgf=0.0), plant(BASE, "base"))
    rec = run.record
    assert run.reason is None and len(rec) == 1000
    assert np.isnan(rec.r).all(), "open loop: no reference during the square wave"
    assert set(rec.u) == {wire(5.0), wire(-5.0)}


def test_meander_without_a_set_point_starts_wherever_the_force_is():
    exp = Meander(amplitude_pct=5, period_s=1, cycles=2)
    assert exp.params()["set_point_kgf"] is None
    run = run_offline(exp, plant(BASE, "base"), y0=3000.0)
    assert run.reason is None and len(run.record) == 1000 and np.isnan(run.record.r).all()
    assert run.record.y[0] == pytest.approx(3000.0, abs=10)


def test_meander_first_brings_the_force_to_the_set_point_and_records_it_as_reference():
    exp = Meander(amplitude_pct=10, period_s=1, cycles=2, set_point_kgf=0.0)
    run = run_offline(exp, plant(BASE, "base"), y0=3000.0)
    rec = run.record
    assert run.reason is None
    approach = np.isfinite(rec.r)
    n_app = int(approach.sum())
    assert approach[:n_app].all() and not approach[n_app:].any(), "approach first, then open loop"
    assert (rec.r[:n_app] == 0.0).all()
    assert 0.5 < n_app * 0.002 < 5.0
    assert np.abs(rec.u[:n_app]).max() <= wire(20.0), "the approach loop respects its limit"
    assert abs(rec.y[n_app]) <= 20.0 + 5.0, "the square wave starts at the set point"
    assert len(rec) - n_app == 1000, "the square wave keeps its full length"
    assert exp.main_start_s == pytest.approx(n_app * 0.002)
    # the square wave is the same as without approach, shifted
    ref = run_offline(Meander(amplitude_pct=10, period_s=1, cycles=2), plant(BASE, "base")).record
    assert np.array_equal(rec.u[n_app:], ref.u)


def test_an_unreachable_set_point_stops_the_run_with_a_reason():
    exp = Meander(amplitude_pct=5, period_s=1, cycles=2, set_point_kgf=5000.0, settle_limit_pct=1.0,
                  settle_max_s=1.0)
    run = run_offline(exp, plant(BASE, "base"))
    assert run.reason == SET_POINT_NOT_REACHED
    assert "5000" in run.message and "settle_max_s" in run.message
    assert len(run.record) == pytest.approx(500, abs=2)


def test_the_guard_stops_a_meander_before_the_force_limit():
    # ramps of 120·20·5 = 12,000 kgf would cross the 5,000 kgf limit
    exp = Meander(amplitude_pct=20, period_s=20, cycles=1, set_point_kgf=0.0)
    run = run_offline(exp, plant(BASE, "base"), force_limit_kgf=5000.0)
    assert run.reason == FORCE_NEAR_LIMIT, run.message
    assert "90%" in run.message and "5000" in run.message
    assert np.abs(run.record.y).max() < 0.9 * 5000 + 10
    assert np.abs(run.record.y).max() > 0.9 * 5000 - 100


# -- relay and P feedback ---------------------------------------------------------------------
def test_relay_oscillates_about_the_reference_with_two_command_levels():
    exp = Relay(amplitude_pct=10, reference_kgf=1000.0, duration_s=2.0)
    run = run_offline(exp, plant(BASE, "base"))
    rec = run.record
    assert run.reason is None
    main = rec.t >= exp.main_start_s
    assert exp.main_start_s > 0.3, "the approach from 0 to 1000 kgf came first"
    assert set(np.abs(rec.u[main])) == {wire(10.0)}
    assert (rec.r == 1000.0).all()
    y = rec.y[main][len(rec.y[main]) // 2:]
    # triangle of peak g·u0·τ ≈ 60 kgf about r (plus the sampling's half period)
    assert 40 < y.max() - 1000 < 90 and 40 < 1000 - y.min() < 90
    switches = np.count_nonzero(np.diff(np.sign(rec.u[main])))
    assert switches >= 2 * 2.0 / 0.25, "a period of about 4τ = 0.2 s"


def test_relay_hysteresis_keeps_the_sign_inside_the_band():
    exp = Relay(amplitude_pct=5, reference_kgf=0.0, hysteresis_kgf=10.0, settle_max_s=0)
    exp.configure(0.002, 9500.0)
    exp.begin(0.0)
    assert exp.step(0.0, -20.0)[0] == 5.0
    assert exp.step(0.002, 5.0)[0] == 5.0, "inside the band: keep"
    assert exp.step(0.004, 11.0)[0] == -5.0
    assert exp.step(0.006, -9.0)[0] == -5.0, "inside the band: keep"
    assert exp.step(0.008, -10.5)[0] == 5.0


def test_pfeedback_is_a_clamped_proportional_law_on_a_sine_reference():
    exp = PFeedback(gain=0.005, amplitude_kgf=2000.0, omega_rad_s=1.0, command_limit_pct=6.0,
                    settle_max_s=0)
    exp.configure(0.002, 9500.0)
    exp.begin(0.0)
    u, r = exp.step(math.pi / 2, 1500.0)
    assert r == pytest.approx(2000.0) and u == pytest.approx(0.005 * 500.0)
    u, r = exp.step(3 * math.pi / 2, 100.0)
    assert r == pytest.approx(-2000.0) and u == -6.0, "clamped"


def test_pfeedback_offline_tracks_the_reference_with_the_expected_amplitude():
    exp = PFeedback(gain=0.005, amplitude_kgf=2000.0, omega_rad_s=2.0, periods=2, transient_s=6.0)
    run = run_offline(exp, plant(BASE, "base"))
    rec = run.record
    assert run.reason is None
    last = rec.t >= rec.t[-1] - 2 * math.pi / 2.0
    # |y/r| = k·g/|jω·e^{jωτ} + k·g| for the integrator with delay
    kg, w, tau = 0.005 * 120, 2.0, 0.05
    gain = kg / abs(1j * w * np.exp(1j * w * tau) + kg)
    amp = (rec.y[last].max() - rec.y[last].min()) / 2
    assert amp == pytest.approx(gain * 2000.0, rel=0.05)


# -- through the gateway and the emulator -----------------------------------------------------
@pytest.mark.e2e
def test_stand_run_relay_and_its_guard_on_the_emulator(bus_spec, start_emulator, tmp_path):
    start_emulator(plant(BASE, "base"), lockstep=True, seed=2)
    out = tmp_path / "relay"
    cmd = [sys.executable, "-m", "stand", "run", "relay", "--bus", bus_spec, "--lockstep",
           "--amplitude-pct", "10", "--reference-kgf", "500", "--duration-s", "1", "--out", str(out),
           "--no-progress"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr + done.stdout
    meta = json.loads((out / "run.json").read_text())
    assert meta["experiment"]["name"] == "relay"
    assert meta["experiment"]["params"]["reference_kgf"] == 500.0
    assert meta["status"] == "complete"
    # the guard: reference beyond 90 % of a 1000 kgf limit stops the run before the supervisor
    out2 = tmp_path / "guard"
    cmd2 = cmd[:cmd.index("--out")] + ["--out", str(out2), "--force-limit", "1000", "--no-progress"]
    cmd2[cmd2.index("500")] = "2000"
    done = subprocess.run(cmd2, capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr + done.stdout
    assert "force_near_limit" in done.stdout
    meta = json.loads((out2 / "run.json").read_text())
    assert meta["status"] == "stopped" and meta["end_reason"] == FORCE_NEAR_LIMIT
