"""Windowed free-run error, noise floor, regimes and residual tests."""
from __future__ import annotations

import math

import numpy as np
import pytest

from analysis import evaluate, make_record
from analysis.identification.metrics import command_levels, noise_sigma, reversal_mask
from analysis.records import synthetic as S
from plant import PlantModel
from tests.support.records import meander4
from tests.support.stand import BASE


def test_rmse_and_fit_percent_follow_their_definitions():
    truth = PlantModel.from_spec("base", BASE)
    rec = meander4(truth)
    wrong = truth.with_params({"g": 110.0})
    ev = evaluate(wrong, [rec])
    s = ev.sims[0]
    y, yhat = s.y, s.yhat
    assert ev.rmse == pytest.approx(math.sqrt(np.mean((y - yhat) ** 2)))
    assert ev.fit_percent == pytest.approx(100 * (1 - np.linalg.norm(y - yhat) / np.linalg.norm(y - y.mean())))
    # each window starts from the measured force
    starts = np.arange(0, len(y), s.window)
    assert np.array_equal(yhat[starts], y[starts])
    assert len(ev.windows) == len(starts)
    w0 = ev.windows[0]
    seg = slice(0, s.window)
    assert w0.rmse == pytest.approx(math.sqrt(np.mean((y[seg] - yhat[seg]) ** 2)))


@pytest.mark.parametrize("noise,resolution", [(0.5, 0.5), (2.0, 0.5), (8.0, 0.0)])
def test_noise_is_estimated_from_the_data_and_the_true_model_sits_on_the_floor(noise, resolution):
    truth = PlantModel.from_spec("base+reversal", BASE)
    rec = meander4(truth, noise_kgf=noise, resolution_kgf=resolution, seed=11)
    sigma = math.sqrt(noise ** 2 + resolution ** 2 / 12)
    assert noise_sigma(rec.y) == pytest.approx(sigma, rel=0.06)
    ev = evaluate(truth, [rec])
    assert ev.noise_sigma == pytest.approx(sigma, rel=0.05)
    assert ev.noise_floor == pytest.approx(math.sqrt(2) * sigma, rel=0.06)
    assert ev.excess_ratio == pytest.approx(1.0, abs=0.2)
    # with the window starts re-estimated the floor is σ, and it does not scatter
    assert ev.rmse_adjusted == pytest.approx(ev.adjusted_floor, rel=0.04)


def test_regimes_show_an_asymmetry_as_a_retract_slope_error():
    truth = PlantModel.from_spec("base+asymmetry", {**BASE, "asymmetry.ratio": 0.1})
    rec = meander4(truth)
    ev = evaluate(PlantModel.from_spec("base", {**BASE, "delta": 8.0}), [rec])
    by = {r.name: r for r in ev.regimes if r.group == "direction"}
    ext, ret = by["extend (u > 0)"], by["retract (u < 0)"]
    # the model (symmetric) is too slow extending (data 10 % faster) and too fast retracting
    assert ext.rate_bias_rel == pytest.approx(-0.1 / 1.1, abs=0.02)
    assert ret.rate_bias_rel == pytest.approx(0.1 / 0.9, abs=0.02)
    levels = [r.name for r in ev.regimes if r.group == "command level"]
    assert levels == ["|u| = 5 %", "|u| = 10 %", "|u| = 15 %", "|u| = 20 %"]
    assert len([r for r in ev.regimes if r.group == "force level"]) == 4
    assert sum(r.time_share for r in ev.regimes if r.group == "direction") == pytest.approx(1.0)


def test_reversals_are_the_sign_changes_of_the_delayed_command():
    q = np.array([0, 1, 1, 0, 0, 1, -1, -1, 0, -1, 1, 1], float)
    rev, after = reversal_mask(q, dt=0.1, after_s=0.2)
    assert list(rev) == [6, 10]
    assert list(np.flatnonzero(after)) == [6, 7, 10, 11]
    groups, names = command_levels(np.abs(np.array([0, 5, 5, 10, 10, 20.0])))
    assert names == ["|u| = 5 %", "|u| = 10 %", "|u| = 20 %"] and list(groups) == [-1, 0, 0, 1, 1, 2]


def test_whiteness_and_input_correlation_pass_for_the_truth_and_fail_for_a_wrong_model():
    truth = PlantModel.from_spec("base", BASE)
    passed = 0
    for seed in range(6):
        ev = evaluate(truth, [meander4(truth, seed=20 + seed)])
        passed += ev.whiteness.white and ev.input_correlation.white
        assert ev.whiteness.band == pytest.approx(1.96 / math.sqrt(ev.whiteness.n))
        assert ev.whiteness.n == ev.n
    assert passed >= 5
    rec = meander4(truth, seed=30)
    bad = evaluate(truth.with_params({"g": 114.0, "tau": 0.03}), [rec])
    assert not bad.whiteness.white and not bad.input_correlation.white
    assert bad.input_correlation.max_abs > 10 * bad.input_correlation.band


def test_a_sinusoidal_reference_closed_loop_is_evaluated_too():
    truth = PlantModel.from_spec("base", BASE)
    rec = S.pfeedback(truth, omegas_rad_s=(0.6283,), seed=3)
    assert rec.has_reference()
    ev = evaluate(truth, [rec])
    assert ev.excess_ratio == pytest.approx(1.0, abs=0.2)
    assert {r.group for r in ev.regimes} == {"reversal", "direction", "command level", "force level"}


def test_the_first_half_second_only_primes_the_command_history():
    """The commands before a record are unknown: a record that starts from rest with the
    command already on must not be blamed on the model."""
    truth = PlantModel.from_spec("base", BASE)
    u = np.full(3000, 10.0)
    y = truth.simulate(u, 0.002, u_before=0.0)     # at rest before the record
    rec = make_record(np.arange(3000) * 0.002, u, y)
    ev = evaluate(truth, [rec])
    assert ev.rmse < 1e-6
    assert ev.sims[0].t[0] == pytest.approx(0.5)
