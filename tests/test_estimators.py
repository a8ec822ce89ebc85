"""The three estimators on synthetic data with known answers, and on bad data.

Open loop: :meth:`PlantModel.simulate` behind a :class:`Dynamometer`. Closed loops: the
experiments themselves driven through :func:`tests.support.offline.run_offline` (the loop's
timing, the plant stepped with new_state/advance, dynamometer noise and resolution).
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from analysis import (EstimateOptions, detect_experiment, error_json, estimate_meander,
                      estimate_pfeedback, estimate_record, estimate_relay, make_record, read_csv,
                      result_json, write_csv)
from analysis.estimators.relay import DF_PEAK_BIAS
from gateway.errors import DataError
from gateway.experiments.meander import Meander
from gateway.experiments.pfeedback import PFeedback
from gateway.experiments.relay import Relay
from plant import Dynamometer, PlantModel
from tests.support.offline import run_offline
from tests.support.stand import BASE, plant

TRUTH = dict(g=120.0, tau=0.05)


def square(u0: float, period_s: float, cycles: int, dt: float = 0.002) -> np.ndarray:
    t = np.arange(int(round(cycles * period_s / dt))) * dt
    seg = np.floor((t + period_s / 4) / (period_s / 2) + 1e-9)
    return np.where(seg % 2 == 0, u0, -u0).astype(float)


def open_loop_record(model: PlantModel, u: np.ndarray, seed: int = 0, dt: float = 0.002,
                     sensor: Dynamometer | None = None, y0: float = 0.0, r=None):
    y = model.simulate(u, dt, y0=y0, u_before=0.0)
    reading, _ = (sensor or Dynamometer(seed=seed)).measure(y)
    return make_record(np.arange(len(u)) * dt, u, reading, r, source="synthetic meander")


# == relay ======================================================================================
@pytest.mark.parametrize("u0, r", [(5, 0.0), (10, -1500.0), (20, 2500.0)])
def test_relay_exact_estimates_recover_g_and_tau(u0, r):
    run = run_offline(Relay(amplitude_pct=u0, reference_kgf=r, duration_s=4), plant(BASE, "base"), seed=u0)
    est = estimate_relay(run.record)
    assert est.g == pytest.approx(TRUTH["g"], rel=0.03)
    assert est.tau == pytest.approx(TRUTH["tau"], rel=0.04)
    assert est.g_ci[0] < est.g < est.g_ci[1] and est.cycles >= 10
    assert est.amplitude_pct == pytest.approx(u0, rel=1e-3) and est.reference_kgf == r
    # the triangle: P = 4τ_e, A = g·u0·τ_e with τ_e = τ + T/2
    assert est.period_s == pytest.approx(4 * (TRUTH["tau"] + 0.001), rel=0.04)
    assert est.peak_kgf == pytest.approx(TRUTH["g"] * u0 * (TRUTH["tau"] + 0.001), rel=0.05)


def test_relay_describing_function_with_the_peak_is_biased_by_pi2_over_8_and_reported():
    run = run_offline(Relay(amplitude_pct=10, duration_s=4), plant(BASE, "base"), seed=4)
    est = estimate_relay(run.record)
    assert est.g_df_peak / TRUTH["g"] == pytest.approx(DF_PEAK_BIAS, rel=0.03)   # +23 %
    assert est.df_bias == pytest.approx(math.pi ** 2 / 8, rel=0.02)
    assert est.g_df_harmonic == pytest.approx(TRUTH["g"], rel=0.03), "first harmonic: unbiased"
    assert est.tau_df == pytest.approx(est.period_s / 4)


def test_relay_other_plant_and_slower_sampling_need_the_half_period_correction():
    model = {"g": 80.0, "tau": 0.08, "delta": 0.0}
    run = run_offline(Relay(amplitude_pct=10, duration_s=8), plant(model, "base"), period_s=0.01, seed=1)
    est = estimate_relay(run.record)
    assert est.sampling_correction_s == pytest.approx(0.005)
    assert est.g == pytest.approx(80.0, rel=0.03)
    assert est.tau == pytest.approx(0.08, rel=0.04)
    # without the correction P/4 is off by T/2 (6 %)
    assert est.tau_df - 0.08 == pytest.approx(0.005, abs=0.002)


def test_relay_hysteresis_is_taken_from_the_run_and_corrected():
    run = run_offline(Relay(amplitude_pct=10, hysteresis_kgf=40.0, duration_s=4), plant(BASE, "base"), seed=2)
    est = estimate_relay(run.record)
    assert est.hysteresis_kgf == 40.0
    assert est.g == pytest.approx(120.0, rel=0.03)
    assert est.tau == pytest.approx(0.05, rel=0.05)
    ignoring = estimate_relay(run.record, hysteresis_kgf=0.0)
    assert ignoring.tau > 0.07, "ignoring ε would inflate τ by ε/(g·u0) ≈ 33 ms"


def test_relay_reports_an_asymmetric_gain():
    cfg = plant({**BASE, "asymmetry.ratio": 0.2}, "base+asymmetry")
    est = estimate_relay(run_offline(Relay(amplitude_pct=10, duration_s=4), cfg, seed=5).record)
    assert est.slope_rise / est.slope_fall == pytest.approx(1.2 / 0.8, rel=0.06)
    assert est.fall_s > est.rise_s
    assert any("asymmetric slopes" in w for w in est.warnings)
    assert est.g == pytest.approx(120.0, rel=0.04), "the mean of the two gains"
    sym = estimate_relay(run_offline(Relay(amplitude_pct=10, duration_s=4), plant(BASE, "base"), seed=5).record)
    assert not any("asymmetric" in w for w in sym.warnings)


def test_relay_with_the_reversal_effect_sees_a_larger_gain_at_small_amplitude():
    cfg = plant(BASE, "base+reversal")
    g = [estimate_relay(run_offline(Relay(amplitude_pct=u0, duration_s=3), cfg, seed=u0).record).g
         for u0 in (5, 10, 20)]
    assert g[0] > g[1] > g[2] > 120.0, g


def test_relay_bad_data_gives_clear_errors():
    short = run_offline(Relay(amplitude_pct=10, duration_s=0.4), plant(BASE, "base")).record
    with pytest.raises(DataError, match="no sustained oscillation"):
        estimate_relay(short)
    flat = make_record(np.arange(500) * 0.002, np.full(500, 10.0), np.linspace(0, 600, 500), np.zeros(500))
    with pytest.raises(DataError, match="no sustained oscillation"):
        estimate_relay(flat)
    zero = make_record(np.arange(500) * 0.002, np.zeros(500), np.zeros(500))
    with pytest.raises(DataError, match="zero throughout"):
        estimate_relay(zero)
    two_refs = run_offline(Relay(amplitude_pct=10, duration_s=2), plant(BASE, "base")).record
    two_refs.r[len(two_refs) // 2:] = 100.0
    with pytest.raises(DataError, match="reference changes"):
        estimate_relay(two_refs)
    cfg = plant({**BASE, "sensor.range_kgf": 1000.0}, "base")
    clipped = run_offline(Relay(amplitude_pct=10, reference_kgf=980.0, duration_s=3), cfg,
                          force_limit_kgf=5000.0).record
    with pytest.raises(DataError, match="saturated"):
        estimate_relay(clipped)


# == P feedback ====================================================================================
@pytest.mark.parametrize("omega, amp", [(0.6283, 2000.0), (2.5133, 1000.0)])
def test_pfeedback_eq3_recovers_g_and_the_phase_gives_tau(omega, amp):
    exp = PFeedback(gain=0.005, amplitude_kgf=amp, omega_rad_s=omega, periods=2, transient_s=9)
    est = estimate_pfeedback(run_offline(exp, plant(BASE, "base"), seed=7).record)
    assert est.g == pytest.approx(120.0, rel=0.01)
    assert est.g_ci[0] <= est.g <= est.g_ci[1] and est.g_ci[1] - est.g_ci[0] < 0.05 * est.g
    assert est.tau == pytest.approx(0.05, rel=0.05)
    assert est.omega_rad_s == omega and est.periods >= 1
    assert est.transient_s > 3.0, "the start-up transient (1/(k·g) = 1.7 s) is left out"


def test_pfeedback_from_a_csv_fits_omega_and_k_itself(tmp_path):
    exp = PFeedback(gain=0.004, amplitude_kgf=1500.0, omega_rad_s=1.7, periods=3, transient_s=9)
    rec = run_offline(exp, plant({"g": 90.0, "tau": 0.03, "delta": 5.0}, "base"), seed=8).record
    write_csv(rec, tmp_path / "pf.csv")
    csv = read_csv(tmp_path / "pf.csv")
    assert csv.experiment is None and not csv.meta
    est = estimate_pfeedback(csv)
    assert est.omega_rad_s == pytest.approx(1.7, rel=1e-4)
    assert est.gain == pytest.approx(0.004, rel=0.01)
    assert est.g == pytest.approx(90.0, rel=0.01)


def test_pfeedback_with_the_reversal_effect_shows_g_growing_with_frequency():
    cfg = plant(BASE, "base+reversal")
    g = [estimate_pfeedback(run_offline(PFeedback(amplitude_kgf=1000.0, omega_rad_s=w, periods=2,
                                                  transient_s=9), cfg, seed=1).record).g
         for w in (0.6283, 2.5133)]
    assert g[1] > 1.1 * g[0], g


def test_pfeedback_bad_data_gives_clear_errors():
    cfg = plant(BASE, "base")
    short = run_offline(PFeedback(omega_rad_s=2.5, periods=1, transient_s=0.5), cfg).record
    with pytest.raises(DataError, match="no stationary period"):
        estimate_pfeedback(short)
    tiny = run_offline(PFeedback(omega_rad_s=0.6283, periods=0.5, transient_s=0.0), cfg).record
    with pytest.raises(DataError, match="less than one period"):
        estimate_pfeedback(tiny)
    no_ref = make_record(short.t, short.u, short.y)
    with pytest.raises(DataError, match="needs the reference"):
        estimate_pfeedback(no_ref)
    flat_ref = make_record(short.t, short.u, short.y, np.full(len(short), 100.0))
    with pytest.raises(DataError):
        estimate_pfeedback(flat_ref)
    small = plant({**BASE, "sensor.range_kgf": 300.0}, "base")
    clipped = run_offline(PFeedback(amplitude_kgf=2000.0, omega_rad_s=2.5, periods=2, transient_s=9),
                          small, force_limit_kgf=5000.0).record
    with pytest.raises(DataError, match="saturated"):
        estimate_pfeedback(clipped)


# == meander =======================================================================================
def test_meander_ignores_the_set_point_approach_and_recovers_g():
    run = run_offline(Meander(amplitude_pct=10, period_s=2, cycles=3, set_point_kgf=0.0),
                      plant(BASE, "base"), y0=-2500.0, seed=3)
    rec = run.record
    assert np.isfinite(rec.r).sum() > 200, "an approach phase is in the record"
    est = estimate_meander(rec)
    assert est.g == pytest.approx(120.0, rel=0.01)
    assert est.delta == pytest.approx(8.0, abs=3.0)
    assert {p.portion for p in est.portions} == {"main_rise", "main_fall", "transitional_rise",
                                                 "transitional_fall"}


def test_meander_transitional_contrast_shrinks_as_the_amplitude_grows():
    model = PlantModel.from_spec("base+reversal", {**BASE})
    ratios = []
    for u0 in (5, 10, 15, 20):
        est = estimate_meander(open_loop_record(model, square(u0, 4.0, 4), seed=u0))
        tr = np.mean([est.portion(n).g for n in ("transitional_rise", "transitional_fall")])
        ratios.append(tr / est.g)
        assert est.g == pytest.approx(120.0, rel=0.03)
    assert ratios[0] > 1.8 and all(a > b for a, b in zip(ratios, ratios[1:])), ratios
    assert ratios[-1] > 1.2, "still clearly above the main portion"


def test_meander_bad_data_gives_clear_errors():
    model = PlantModel.from_spec("base", BASE)
    with pytest.raises(DataError, match="at least two reversals"):
        estimate_meander(open_loop_record(model, np.full(2000, 5.0)))
    one = np.concatenate([np.full(500, 5.0), np.full(500, -5.0)])
    with pytest.raises(DataError, match="at least two reversals"):
        estimate_meander(open_loop_record(model, one))
    clipped = open_loop_record(model, square(20, 8.0, 2), sensor=Dynamometer(range_kgf=1000.0, seed=1))
    with pytest.raises(DataError, match="saturated"):
        estimate_meander(clipped)


# == dispatch, detection and JSON ====================================================================
@pytest.mark.parametrize("experiment", [
    Meander(amplitude_pct=10, period_s=2, cycles=3, set_point_kgf=500.0),
    Relay(amplitude_pct=15, reference_kgf=-1000.0, duration_s=2),
    PFeedback(omega_rad_s=2.0, periods=2, transient_s=9),
])
def test_the_experiment_is_recognised_from_a_plain_csv(experiment, tmp_path):
    rec = run_offline(experiment, plant(BASE, "base"), seed=9).record
    write_csv(rec, tmp_path / "x.csv")
    csv = read_csv(tmp_path / "x.csv")
    det = detect_experiment(csv)
    assert det.experiment == experiment.name and det.detected_from == "signals"
    est = estimate_record(csv)
    assert est.g == pytest.approx(120.0, rel=0.03)
    doc = result_json(est)
    json.dumps(doc, allow_nan=False)
    assert doc["schema"] == "hydrostand-estimate/1" and doc["experiment"] == experiment.name
    assert set(doc["estimates"]) >= {"g", "g_ci", "tau", "tau_ci", "delta"}


def test_metadata_wins_over_detection_and_an_option_wins_over_both():
    rec = run_offline(Relay(amplitude_pct=10, duration_s=2), plant(BASE, "base")).record
    assert detect_experiment(rec).detected_from == "metadata"
    est = estimate_record(rec, EstimateOptions(experiment="relay", hysteresis_kgf=0.0))
    assert est.detection.detected_from == "option"
    with pytest.raises(DataError, match="unknown experiment"):
        estimate_record(rec, EstimateOptions(experiment="bode"))


def test_relay_json_has_the_exact_and_the_paper_estimates_side_by_side():
    rec = run_offline(Relay(amplitude_pct=10, duration_s=3), plant(BASE, "base"), seed=6).record
    doc = result_json(estimate_record(rec))
    e = doc["estimates"]
    assert e["g"] == pytest.approx(120.0, rel=0.03) and e["tau"] == pytest.approx(0.05, rel=0.04)
    assert e["g_eq4_peak"] / e["g"] == pytest.approx(DF_PEAK_BIAS, rel=0.02)
    assert e["eq4_peak_bias"] == pytest.approx(e["g_eq4_peak"] / e["g"])
    assert e["tau_eq4"] == pytest.approx(e["period_s"] / 4)
    assert set(doc["details"]["asymmetry"]) == {"slope_rise_vs_fall", "time_plus_vs_minus",
                                                "peak_above_vs_below"}


def test_data_that_is_none_of_the_three_is_refused_with_what_was_measured():
    rng = np.random.default_rng(0)
    rec = make_record(np.arange(3000) * 0.002, rng.normal(0, 5, 3000), rng.normal(0, 50, 3000))
    with pytest.raises(DataError, match="cannot tell which experiment.*--experiment"):
        detect_experiment(rec)
    doc = error_json("x.csv", "boom")
    assert doc["error"] == "boom" and doc["estimates"] is None and doc["experiment"] is None
