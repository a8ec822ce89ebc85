"""The plant model and its effect catalogue (shared by the emulator and the analysis)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from plant import CATALOGUE, Dynamometer, ModelError, PlantModel, load_model_file, load_plant_config, model_to_toml

DT = 0.002


def square(amp=10.0, period=2.0, duration=8.0, dt=DT):
    t = np.arange(0, duration, dt)
    return t, np.where(np.floor(t / (period / 2)) % 2 == 0, amp, -amp).astype(float)


def slope(t, y, a, b):
    m = (t >= a) & (t < b)
    return np.polyfit(t[m], y[m], 1)[0]


def test_base_model_ramp_slope_is_g_u_plus_delta():
    m = PlantModel(g=120, tau=0.05, delta=8)
    t = np.arange(0, 2, DT)
    y = m.simulate(np.full_like(t, 5.0), DT, u_before=0.0)
    assert slope(t, y, 0.5, 2.0) == pytest.approx(120 * 5 + 8, rel=1e-9)


@pytest.mark.parametrize("tau", [0.0, 0.002, 0.013, 0.05, 0.0771])
def test_delay_is_exact_even_between_samples(tau):
    """A step at t=0 from rest: the ramp starts exactly τ later (continuous time, ZOH input)."""
    m = PlantModel(g=100, tau=tau)
    t = np.arange(0, 0.5, DT)
    y = m.simulate(np.full_like(t, 1.0), DT, u_before=0.0)
    expected = 100 * np.maximum(t - tau, 0.0)
    assert np.max(np.abs(y - expected)) < 1e-9


@pytest.mark.parametrize("spec, values, tol", [
    ("base+slew", {"slew.rate": 400.0}, 0.05),
    ("base+deadzone", {"deadzone.width": 2.0}, 1e-6),
    ("base+backlash", {"backlash.width": 2.0}, 1e-6),
    ("base+saturation", {"saturation.limit": 15.0}, 1e-6),
    ("base+flow_curve", {"flow_curve.exponent": 0.7}, 1e-6),
    ("base+null_drift", {"null_drift.rate": 0.05}, 1e-4),
])
def test_a_delay_between_samples_reaches_the_valve_effects_as_in_continuous_time(spec, values, tol):
    """τ = 51.7 ms is 25.85 steps of 2 ms: the model on 2 ms steps must give the force of the
    same model on 0.1 ms steps (τ a whole number of them: no fraction), sampled at 2 ms. The
    valve effects see the held command (the fraction of the delay follows them): averaging
    the command across a step first shifted a slew ramp by up to a step (3.5 kgf here) and bent
    a dead zone, play, limit or flow curve at every command change (0.1-0.8 kgf)."""
    t = np.arange(0, 4, DT)
    u = np.where((t % 1.0) < 0.5, 20.0, -20.0) + 3 * np.sin(2 * np.pi * 1.3 * t)
    u[t < 0.2] = 0.0
    m = PlantModel.from_spec(spec, {"g": 100.0, "tau": 0.0517, **values})
    coarse = m.simulate(u, DT)
    fine = m.simulate(np.repeat(u, 20), DT / 20)[::20]
    assert np.max(np.abs(coarse - fine)) < tol


@pytest.mark.parametrize("spec", ["base", "base+reversal", "base+lag+deadzone", "base+saturation+asymmetry",
                                  "base+leakage", "base+load_pressure+reversal+lag+oscillation",
                                  "base+backlash+flow_curve", "base+sensor_lag+deadzone+reversal",
                                  "base+command_reversal+lag", "base+stiffness+reversal",
                                  "base+deadzone+stiction", "base+unloading+asymmetry",
                                  "base+direction_delay+lag", "base+resonance+deadzone", "base+slew+backlash", "base+supply+asymmetry",
                                  "base+gain_drift+reversal", "base+null_drift+lag+deadzone",
                                  "base+travel_reversal+slew"])
def test_emulator_blocks_and_analysis_windows_run_the_same_model(spec):
    """Stepping in small blocks (the emulator), whole records and windows (the analysis) agree."""
    extra = {"stiffness.k_abs": 2.0, "stiffness.k_sgn": -0.5} if "stiffness" in spec else {}
    extra.update({"stiction.width": 130.0} if "stiction" in spec else {})
    extra.update({"unloading.ratio": 0.2} if "unloading" in spec else {})
    extra.update({"direction_delay.extra": -0.0173} if "direction_delay" in spec else {})
    extra.update({"resonance.frequency": 7.3, "resonance.damping": 0.15} if "resonance" in spec else {})
    extra.update({"slew.rate": 333.0} if "slew" in spec else {})
    extra.update({"travel_reversal.boost": 3.0, "travel_reversal.travel": 0.7}
                 if "travel_reversal" in spec else {})
    extra.update({"supply.sag": 2.0, "supply.time_constant": 0.4} if "supply" in spec else {})
    extra.update({"gain_drift.rate": 0.03, "gain_drift.time_constant": 4.0}
                 if "gain_drift" in spec else {})
    extra.update({"null_drift.rate": -0.08, "null_drift.time_constant": 5.0}
                 if "null_drift" in spec else {})
    m = PlantModel.from_spec(spec, {"g": 110, "tau": 0.031, **extra})
    t, u = square(12.0, 1.0, 6.0)
    whole = m.simulate(u, DT, y0=100.0)
    state = m.new_state(1, DT, y0=100.0, u0=u[0])
    blocks = np.concatenate([m.advance(state, u[None, k:k + 5], DT)[0] for k in range(0, len(u), 5)])
    assert np.max(np.abs(blocks[:-1] - whole[1:])) < 1e-8
    assert np.max(np.abs(m.simulate_windows(u, whole, DT, 500) - whole)) < 1e-8


def test_deadzone_reduces_the_slope_by_the_overlap():
    m = PlantModel.from_spec("base+deadzone", {"g": 100, "tau": 0, "deadzone.width": 2.0})
    t = np.arange(0, 1, DT)
    for u0 in (5.0, 10.0):
        y = m.simulate(np.full_like(t, u0), DT, u_before=u0)
        assert slope(t, y, 0.1, 1.0) == pytest.approx(100 * (u0 - 2.0))


def test_backlash_is_a_play_the_command_must_cross_after_turning_back():
    m = PlantModel.from_spec("base+backlash", {"g": 100, "tau": 0, "backlash.width": 2.0})
    t = np.arange(0, 1, DT)
    # a held command: the spool sits at u - w/2 once the play is taken up (a dead zone of w/2)
    y = m.simulate(np.full_like(t, 6.0), DT, u_before=0.0)
    assert slope(t, y, 0.1, 1.0) == pytest.approx(100 * (6.0 - 1.0))
    # a triangle 0 → 5 → 0: up, the spool trails by w/2; turning back, it holds while the
    # command crosses the play (no flow for w / rate = 2 % / (10 %/s) = 0.2 s), then trails
    ramp = np.concatenate([np.linspace(0, 5, 250, endpoint=False), np.linspace(5, 0, 250)])
    e = m.effect("backlash")
    q = e.shape(ramp[None, :], DT, e.init_state(1, np.array([0.0])))[0]
    assert np.max(np.abs(q[50:250] - (ramp[50:250] - 1.0))) < 1e-12
    top = q.max()
    assert top == pytest.approx(5.0 - 1.0)
    held = np.flatnonzero(q == top)
    assert len(held) == pytest.approx(0.2 / DT, abs=2)
    assert np.max(np.abs(q[300:] - (ramp[300:] + 1.0).clip(max=top))) < 1e-12


def test_sensor_lag_filters_the_reading_not_the_force():
    """Linear plant: a dynamometer filter gives the reading a valve lag gives (they commute on
    an integrator). Behind a dead zone they differ; the force itself stays unfiltered."""
    u = np.repeat(np.random.default_rng(1).normal(0, 10, 100), 25)
    vals = {"g": 100, "tau": 0.02}
    valve = PlantModel.from_spec("base+lag", {**vals, "lag.time_constant": 0.03})
    sensor = PlantModel.from_spec("base+sensor_lag", {**vals, "sensor_lag.time_constant": 0.03})
    a, b = valve.simulate(u, DT, u_before=0.0), sensor.simulate(u, DT, u_before=0.0)
    assert np.max(np.abs(a - b)) < 1e-9 * np.abs(a).max()
    dz = {"deadzone.width": 4.0}
    a = PlantModel.from_spec("base+lag+deadzone", {**vals, **dz, "lag.time_constant": 0.03}).simulate(u, DT)
    b = PlantModel.from_spec("base+sensor_lag+deadzone", {**vals, **dz, "sensor_lag.time_constant": 0.03}).simulate(u, DT)
    assert np.max(np.abs(a - b)) > 5.0
    state = sensor.new_state(1, DT, y0=0.0, u0=0.0)
    reading = sensor.advance(state, np.full((1, 500), 10.0), DT)[0]
    # a ramp of 1000 kgf/s read through 30 ms: the reading trails the force by 30 kgf
    assert state.y[0] - reading[-1] == pytest.approx(1000 * 0.03, rel=1e-3)


def test_flow_curve_bends_the_slopes_as_a_power_of_the_command():
    m = PlantModel.from_spec("base+flow_curve", {"g": 100, "tau": 0, "flow_curve.exponent": 0.8})
    t = np.arange(0, 1, DT)
    for u0 in (5.0, 10.0, -20.0):
        y = m.simulate(np.full_like(t, u0), DT, u_before=u0)
        want = 100 * math.copysign(10 * (abs(u0) / 10) ** 0.8, u0)
        assert slope(t, y, 0.1, 1.0) == pytest.approx(want)


def test_saturation_caps_the_flow():
    m = PlantModel.from_spec("base+saturation", {"g": 100, "tau": 0, "saturation.limit": 8.0})
    t = np.arange(0, 1, DT)
    assert slope(t, m.simulate(np.full_like(t, 20.0), DT, u_before=20.0), 0.1, 1) == pytest.approx(800)
    assert slope(t, m.simulate(np.full_like(t, -5.0), DT, u_before=-5.0), 0.1, 1) == pytest.approx(-500)


def test_asymmetry_gives_different_extend_and_retract_gains():
    m = PlantModel.from_spec("base+asymmetry", {"g": 100, "tau": 0, "asymmetry.ratio": 0.2})
    t = np.arange(0, 1, DT)
    up = slope(t, m.simulate(np.full_like(t, 10.0), DT, u_before=10.0), 0.1, 1)
    down = slope(t, m.simulate(np.full_like(t, -10.0), DT, u_before=-10.0), 0.1, 1)
    assert up == pytest.approx(1200) and down == pytest.approx(-800)


def test_lag_reaches_63_percent_of_the_rate_after_one_time_constant():
    T = 0.1
    m = PlantModel.from_spec("base+lag", {"g": 100, "tau": 0, "lag.time_constant": T})
    t = np.arange(0, 1, DT)
    y = m.simulate(np.full_like(t, 10.0), DT, u_before=0.0)
    rate = np.gradient(y, DT)
    assert rate[int(round(T / DT))] / 1000 == pytest.approx(1 - math.exp(-1), abs=0.02)
    # the area lost to the lag is g·u·T
    assert (1000 * t[-1] - y[-1]) == pytest.approx(1000 * T, rel=0.02)


def test_leakage_decays_toward_zero_force():
    m = PlantModel.from_spec("base+leakage", {"g": 100, "tau": 0, "leakage.rate": 0.5})
    t = np.arange(0, 4, DT)
    y = m.simulate(np.zeros_like(t), DT, y0=1000.0)
    assert y[int(2.0 / DT)] == pytest.approx(1000 * math.exp(-1.0), rel=0.01)


def test_load_pressure_slows_pushing_against_the_load():
    m = PlantModel.from_spec("base+load_pressure", {"g": 100, "tau": 0, "load_pressure.stall_force": 20000})
    t = np.arange(0, 0.2, DT)
    push = slope(t, m.simulate(np.full_like(t, 10.0), DT, y0=5000, u_before=10.0), 0, 0.2)
    pull = slope(t, m.simulate(np.full_like(t, -10.0), DT, y0=5000, u_before=-10.0), 0, 0.2)
    assert push == pytest.approx(1000 * math.sqrt(1 - 0.25), rel=0.01)
    assert pull == pytest.approx(-1000 * math.sqrt(1 + 0.25), rel=0.01)


def test_stiffness_scales_the_gain_with_the_load_as_in_closed_form():
    """dy/dt = g·u·(1 + b·y) from y = 0 (y > 0, b = (k_abs + k_sgn)/10⁴) is
    y = (exp(g·u·b·t) − 1)/b; pulling back from a negative force sees (k_abs − k_sgn)."""
    m = PlantModel.from_spec("base+stiffness", {"g": 100, "tau": 0, "stiffness.k_abs": 3.0,
                                                "stiffness.k_sgn": 1.0})
    t = np.arange(0, 2, DT)
    y = m.simulate(np.full_like(t, 10.0), DT, u_before=10.0)
    b = 4.0 / 1e4
    exact = (np.exp(1000 * b * t) - 1) / b
    assert np.max(np.abs(y[1:] - exact[1:]) / exact[1:]) < 1e-3   # Euler steps of 2 ms
    down = m.simulate(np.full_like(t, -10.0), DT, u_before=-10.0)
    assert down[-1] == pytest.approx(-(np.exp(1000 * 2e-4 * t[-1]) - 1) / 2e-4, rel=1e-3)


def test_unloading_is_faster_toward_zero_force_than_away_from_it():
    """h = 0.25 at g = 100, |u| = 10 %: 750 kgf/s while the force grows away from zero (either
    sign), 1250 kgf/s on the way back; the switch is at zero force, not at the reversal."""
    m = PlantModel.from_spec("base+unloading", {"g": 100, "tau": 0, "unloading.ratio": 0.25})
    t = np.arange(0, 1, DT)
    up = m.simulate(np.full_like(t, 10.0), DT, u_before=10.0, y0=0.0)
    assert slope(t, up, 0.1, 1.0) == pytest.approx(750.0)
    back = m.simulate(np.full_like(t, -10.0), DT, u_before=-10.0, y0=1000.0)
    assert slope(t, back, 0.1, 0.7) == pytest.approx(-1250.0)     # unloading: 1000 → 0 in 0.8 s
    assert slope(t, back, 0.85, 1.0) == pytest.approx(-750.0)     # through zero: loading again
    pull = m.simulate(np.full_like(t, 10.0), DT, u_before=10.0, y0=-5000.0)
    assert slope(t, pull, 0.1, 1.0) == pytest.approx(1250.0)      # a negative force unloading


@pytest.mark.parametrize("extra", [0.0301, -0.0301])
def test_direction_delay_makes_one_direction_of_command_step_late(extra):
    """τ = 10 ms, δ = ±30.1 ms at 2 ms steps: the late direction's ramp starts at t_step + τ + |δ|
    (0.05 of a step into its 16th step: the step's mean rate is 95 % of the ramp's), the other
    at t_step + τ."""
    m = PlantModel.from_spec("base+direction_delay", {"g": 100, "tau": 0.01, "direction_delay.extra": extra})
    u = np.r_[np.full(100, -10.0), np.full(100, 10.0), np.full(100, -10.0)]
    rate = np.diff(m.simulate(u, DT, u_before=-10.0)) / DT
    up, down = (0.2 + 0.01 + abs(extra), 0.4 + 0.01) if extra > 0 else (0.2 + 0.01, 0.4 + 0.01 + abs(extra))
    for at, new in ((up, 1000.0), (down, -1000.0)):
        k = int(at / DT + 1e-9)
        assert rate[k - 1] == pytest.approx(-new)
        late = at / DT - k                    # the part of step k still at the old command
        assert rate[k] == pytest.approx(new * (1 - 2 * late), abs=1e-6)
        assert rate[k + 1] == pytest.approx(new)


@pytest.mark.parametrize("f_n,zeta", [(6.0, 0.2), (25.0, 0.5), (3.0, 2.0)])
def test_resonance_is_the_exact_second_order_response_of_the_flow(f_n, zeta):
    """A command step through ẍ + 2ζω ẋ + ω² x = ω² u: the force rate is g times the analytic
    step response, averaged over each step (the force itself: g times its integral)."""
    m = PlantModel.from_spec("base+resonance", {"g": 100, "tau": 0.0, "resonance.frequency": f_n,
                                                "resonance.damping": zeta})
    u = np.r_[np.zeros(10), np.full(400, 10.0)]
    y = m.simulate(u, DT, u_before=0.0)
    from scipy.signal import lti, step
    w = 2 * np.pi * f_n
    # the force is g·10·∫ step response: step response of ω²/(s(s² + 2ζωs + ω²))
    t = (np.arange(len(u)) - 10) * DT
    _, ramp = step(lti([w * w], [1.0, 2 * zeta * w, w * w, 0.0]), T=t[10:])
    want = np.r_[np.zeros(10), 100 * 10.0 * ramp]
    assert np.max(np.abs(y - want)) < 1e-6 * 100 * 10.0 * t[-1]
    rate = np.diff(y) / DT
    if zeta < 1:   # it overshoots by exp(−πζ/√(1−ζ²)), a lag never does
        over = np.exp(-np.pi * zeta / np.sqrt(1 - zeta * zeta))
        assert rate.max() / 1000.0 - 1 == pytest.approx(over, rel=0.05)
    else:
        assert rate.max() <= 1000.0 + 1e-9


def test_slew_makes_a_step_a_ramp_late_by_half_its_length():
    """R = 400 %/s, g = 100: 0 → 10 % takes 25 ms (12.5 steps: the ramp ends mid-step) and the
    force then trails the unlimited valve's by g·Δu²/(2R) = 12.5 kgf; the reversal 10 → −10 %
    takes 50 ms and leaves 50 kgf more (Δu/(2R) late each: twice as late for twice the step)."""
    m = PlantModel.from_spec("base+slew", {"g": 100, "tau": 0.0, "slew.rate": 400.0})
    u = np.r_[np.zeros(50), np.full(200, 10.0), np.full(200, -10.0)]
    y = m.simulate(u, DT, u_before=0.0)
    free = PlantModel(g=100, tau=0.0).simulate(u, DT, u_before=0.0)
    t = np.arange(len(u)) * DT
    ramp = (t > 0.1) & (t <= 0.1 + 0.025)                      # x = R·(t − 0.1): y = g·R·s²/2
    assert np.allclose(y[ramp], 100 * 400 * (t[ramp] - 0.1) ** 2 / 2, atol=1e-9)
    assert np.allclose((y - free)[(t > 0.13) & (t <= 0.5)], -12.5, atol=1e-9)
    assert np.allclose((y - free)[t > 0.56], -12.5 + 50.0, atol=1e-9)
    # a command that moves less than R·dt a step is reached within each step, |Δu|/R after
    # the step starts: the force trails by less than g·|u|max·(|Δu|max/R)/2 (1.96 kgf here)
    slow = np.sin(2 * np.pi * 0.5 * np.arange(2000) * DT) * 50.0   # at most 157 %/s
    ys = m.simulate(slow, DT, u_before=0.0)
    gap = np.abs(ys - PlantModel(g=100, tau=0.0).simulate(slow, DT, u_before=0.0))
    assert 0.5 < gap.max() < 100 * 50.0 * (np.abs(np.diff(slow)).max() / 400.0) / 2


def test_supply_sag_bends_a_held_ramp_down_over_its_time_constant():
    """k = 2 at full opening, T = 0.5 s: a 15 % command from rest starts at the full slope and
    settles at g·u·√(1 − k·0.15) = √0.7 of it, 1 − 1/e of the way there after T."""
    m = PlantModel.from_spec("base+supply", {"g": 100, "tau": 0.0, "supply.sag": 2.0,
                                             "supply.time_constant": 0.5})
    u = np.r_[np.zeros(10), np.full(3000, 15.0)]
    rate = np.diff(m.simulate(u, DT, u_before=0.0)) / DT
    full = 100 * 15.0
    assert rate[10] == pytest.approx(full, rel=0.01)
    assert rate[-1] == pytest.approx(full * np.sqrt(0.7), rel=1e-4)
    k_T = 10 + int(0.5 / DT)
    assert rate[k_T] == pytest.approx(full * np.sqrt(1 - 0.3 * (1 - np.exp(-1))), rel=1e-3)
    # held at the command before the data, the sag has settled: the slope is low from the start
    settled = np.diff(m.simulate(np.full(100, 15.0), DT, u_before=15.0)) / DT
    assert settled[0] == pytest.approx(full * np.sqrt(0.7), rel=1e-9)


def test_gain_drift_changes_the_slope_with_the_time_since_the_run_began():
    """r = 1 %/s, T = 5 s: a held 10 % command ramps at g·u·(1 + r·T·(1 − e^(−t/T))), exactly
    (the step averages sum to the integral); with T far beyond the run it is 1 + r·t."""
    g, u0, r, T = 100.0, 10.0, 0.01, 5.0
    m = PlantModel.from_spec("base+gain_drift", {"g": g, "tau": 0.0, "gain_drift.rate": r,
                                                 "gain_drift.time_constant": T})
    t = np.arange(0, 12.0, DT)
    y = m.simulate(np.full_like(t, u0), DT, u_before=u0)
    exact = g * u0 * (t + r * T * (t - T * (1 - np.exp(-t / T))))
    assert np.max(np.abs(y - exact)) < 1e-6 * exact[-1]
    linear = PlantModel.from_spec("base+gain_drift", {"g": g, "tau": 0.0, "gain_drift.rate": r,
                                                      "gain_drift.time_constant": 1e5})
    y = linear.simulate(np.full_like(t, u0), DT, u_before=u0)
    assert y[-1] == pytest.approx(g * u0 * (t[-1] + r * t[-1] ** 2 / 2), rel=1e-3)
    # the clock is the record's: a record started later (t0) continues the drift
    state = m.new_state(1, DT, u0=u0, t0=6.0)
    late = m.advance(state, np.full((1, 10), u0), DT)[0]
    assert np.diff(late)[0] / DT == pytest.approx(g * u0 * (1 + r * T * (1 - np.exp(-6.0 / T))),
                                                  rel=1e-3)


def test_null_drift_adds_the_same_trend_at_every_command_and_in_both_directions():
    """b = 0.05 %/s, T = 4 s: at any held command, and at zero, the force rate differs from
    g·u by g·b·T·(1 − e^(−t/T)) (exactly, step averages), the same amount for +u and −u."""
    g, b, T = 100.0, 0.05, 4.0
    m = PlantModel.from_spec("base+null_drift", {"g": g, "tau": 0.0, "null_drift.rate": b,
                                                 "null_drift.time_constant": T})
    t = np.arange(0, 10.0, DT)
    extra = g * b * T * (t - T * (1 - np.exp(-t / T)))      # the integral of g·b·W(t)
    for u0 in (-10.0, 0.0, 15.0):
        y = m.simulate(np.full_like(t, u0), DT, u_before=u0)
        assert np.max(np.abs(y - g * u0 * t - extra)) < 1e-6 * max(1.0, np.abs(y).max())


def test_stiction_holds_the_reading_after_each_reversal_for_width_over_rate():
    """A play of w = 200 kgf at g = 100: at |u| = 10 % the reading holds w/(g|u|) = 0.2 s after
    each reversal, at 5 % 0.4 s; a reversal before the play was crossed holds only as long as
    it had crossed."""
    m = PlantModel.from_spec("base+stiction", {"g": 100, "tau": 0, "stiction.width": 200.0})
    for amp, hold in ((10.0, 0.2), (5.0, 0.4)):
        t, u = square(amp, 2.0, 4.0)
        y = m.simulate(u, DT, u_before=amp)
        k = int(round(1.0 / DT))                       # the first reversal, at t = 1 s
        flat = np.flatnonzero(np.abs(np.diff(y[k:k + 400])) < 1e-9)
        assert len(flat) == int(round(hold / DT)) and flat[0] == 0
        assert slope(t, y, 1.0 + hold + 0.05, 2.0) == pytest.approx(-100 * amp, rel=1e-9)
    # +10 % for 0.1 s crosses only half the play: back to -10 % holds 0.1 s, not 0.2 s
    u = np.concatenate([np.full(500, -10.0), np.full(50, 10.0), np.full(300, -10.0)])
    y = m.simulate(u, DT, u_before=-10.0)
    assert np.ptp(y[500:551]) < 1e-9                   # +10 % never got through the play
    back = np.flatnonzero(np.abs(np.diff(y[550:700])) < 1e-9)
    assert len(back) == 50


def test_reversal_boost_starts_at_each_direction_change_and_decays():
    m = PlantModel.from_spec("base+reversal", {"g": 100, "tau": 0, "reversal.boost": 2.0,
                                               "reversal.decay": 0.1, "reversal.exponent": 0.0})
    t, u = square(10.0, 2.0, 4.0)
    y = m.simulate(u, DT)
    rate = np.diff(y) / DT
    k = int(round(1.0 / DT))            # first reversal at t = 1 s
    assert rate[k] == pytest.approx(-1000 * 3, rel=0.01)          # 1 + b right after it
    assert rate[k + int(0.1 / DT)] == pytest.approx(-1000 * (1 + 2 * math.exp(-1)), rel=0.02)
    assert rate[k - 5] == pytest.approx(1000, rel=1e-6)           # no boost at the start from rest
    # exponent 1: the extra force per reversal does not depend on the amplitude
    m1 = m.with_params({"reversal.exponent": 1.0})
    extra = []
    for amp in (5.0, 20.0):
        _, ua = square(amp, 2.0, 4.0)
        ya = m1.simulate(ua, DT)
        base = PlantModel(g=100, tau=0).simulate(ua, DT)
        extra.append((ya - base)[int(1.9 / DT)] - (ya - base)[int(0.99 / DT)])
    assert extra[0] == pytest.approx(extra[1], rel=0.01)


def test_travel_reversal_dies_out_over_the_force_travelled_as_in_closed_form():
    """dy/dt = g·q·(1 + b·e^(−|y − y_r|/F)) solved along the travel: after the reversal at
    force y_r the force is y_r − F·ln((1 + b)·e^(|u|(t − t_r)/V_r) − b), F = g·V_r; the extra
    force per reversal is F·ln(1 + b) at any amplitude, over a time V_r/|u|."""
    g, b, vr = 100.0, 2.0, 1.5
    m = PlantModel.from_spec("base+travel_reversal", {"g": g, "tau": 0.0, "travel_reversal.boost": b,
                                                      "travel_reversal.travel": vr})
    extra = []
    for amp in (5.0, 20.0):
        t, u = square(amp, 2.0, 4.0)
        y = m.simulate(u, DT)
        k, end = int(round(1.0 / DT)), int(round(1.9 / DT))     # the reversal at t = 1 s
        s = t[k:end] - t[k]
        want = y[k] - g * vr * np.log((1 + b) * np.exp(amp * s / vr) - b)
        assert np.max(np.abs(y[k:end] - want)) < 1e-6 * np.ptp(y)
        assert (y[:k + 1] == pytest.approx(g * amp * t[:k + 1]))      # no boost from rest
        base = PlantModel(g=g, tau=0).simulate(u, DT)
        extra.append((base - y)[end] - (base - y)[k])
        travelled = g * amp * 0.9                      # the base model's force change, kgf
        assert extra[-1] == pytest.approx(g * vr * math.log(1 + b - b * math.exp(-travelled / (g * vr))),
                                          rel=1e-6)
    assert extra[1] == pytest.approx(g * vr * math.log(1 + b), rel=1e-4)    # long completed


def test_command_reversal_boost_starts_when_the_command_turns_not_the_rod():
    """τ = 100 ms: the command turns at t = 1 s, the rod at 1.1 s. The command-timed boost
    already pushes the old direction during the delay; the rod-timed one starts at 1.1 s."""
    t = np.arange(0, 2, DT)
    u = np.where(t < 1.0, 10.0, -10.0)
    vals = {"g": 100, "tau": 0.1, "boost": 1.0, "decay": 0.2, "exponent": 0.0}
    cmd = PlantModel.from_spec("base+command_reversal", {k if k in ("g", "tau") else f"command_reversal.{k}": v
                                                         for k, v in vals.items()})
    rod = PlantModel.from_spec("base+reversal", {k if k in ("g", "tau") else f"reversal.{k}": v
                                                 for k, v in vals.items()})
    yc, yr = cmd.simulate(u, DT, u_before=10.0), rod.simulate(u, DT, u_before=10.0)
    before = (t > 1.0) & (t < 1.1)            # still rising: boosted only when timed from the command
    assert np.allclose(np.diff(yr)[before[1:]], 100 * 10 * DT)
    assert np.all(np.diff(yc)[before[1:]] > 1.3 * 100 * 10 * DT)
    assert cmd.delay_steps(DT) == 0 and rod.delay_steps(DT) == 50


def test_oscillation_adds_a_sinusoid():
    m = PlantModel.from_spec("base+oscillation", {"tau": 0, "oscillation.amplitude": 30, "oscillation.frequency": 5})
    t = np.arange(0, 1, DT)
    y = m.simulate(np.zeros_like(t), DT)
    assert np.max(np.abs(y - 30 * np.sin(2 * np.pi * 5 * t))) < 1.0


def test_every_catalogue_effect_documents_physics_and_equation():
    for name, cls in CATALOGUE.items():
        doc = cls.__doc__ or ""
        assert "math::" in doc and len(doc) > 200, name
        assert cls.summary and cls.params, name
        for p in cls.params:
            assert p.lower <= p.default <= p.upper and p.doc and p.unit, (name, p.name)


def test_model_spec_and_parameter_errors_are_clear():
    with pytest.raises(ModelError, match="unknown effect 'friction'.*reversal"):
        PlantModel.from_spec("base+friction")
    with pytest.raises(ModelError, match="must start with 'base'"):
        PlantModel.from_spec("reversal")
    with pytest.raises(ModelError, match="tau = -1.*outside its physical range"):
        PlantModel.from_spec("base", {"tau": -1})
    with pytest.raises(ModelError, match="no parameter"):
        PlantModel.from_spec("base+lag", {"lag.gain": 2})
    with pytest.raises(ModelError, match="must be finite"):
        PlantModel(g=float("nan"))


def test_model_file_round_trip(tmp_path):
    m = PlantModel.from_spec("base+reversal+deadzone", {"g": 99.5, "deadzone.width": 1.25})
    path = tmp_path / "model.toml"
    path.write_text(model_to_toml(m))
    back = load_model_file(path)
    assert back.spec == m.spec and back.params() == m.params()


def test_plant_config_from_toml_with_disabled_effect_and_overrides(tmp_path):
    path = tmp_path / "plant.toml"
    path.write_text("[base]\ng = 130\n[effects.reversal]\nenabled = false\nboost = 3\n"
                    "[effects.lag]\ntime_constant = 0.02\n[sensor]\nnoise_kgf = 0.5\n[initial]\nforce_kgf = 200\n")
    cfg = load_plant_config(path, None, {"tau": 0.04, "sensor.resolution_kgf": 0.0})
    assert cfg.model.spec == "base+lag" and cfg.model.g == 130 and cfg.model.tau == 0.04
    assert cfg.sensor == {"noise_kgf": 0.5, "resolution_kgf": 0.0} and cfg.initial_force_kgf == 200
    bad = tmp_path / "bad.toml"
    bad.write_text("[sensor]\nnoise = 1\n")
    with pytest.raises(ModelError, match=r"\[sensor\] has no key"):
        load_plant_config(bad)
    bad.write_text("[base\n")
    with pytest.raises(ModelError, match="not valid TOML"):
        load_plant_config(bad)


def test_dynamometer_quantizes_clips_and_flags_over_range():
    d = Dynamometer(noise_kgf=0.0, resolution_kgf=0.5, range_kgf=1000.0, seed=1)
    reading, over = d.measure(np.array([0.26, 999.9, 1500.0, -2000.0]))
    assert list(reading) == [0.5, 1000.0, 1000.0, -1000.0]
    assert list(over) == [False, False, True, True]
    a = Dynamometer(noise_kgf=2.0, seed=7).measure(np.zeros(1000))[0]
    b = Dynamometer(noise_kgf=2.0, seed=7).measure(np.zeros(1000))[0]
    assert np.array_equal(a, b) and 1.8 < a.std() < 2.2


def _stepped(model, drv, y0, dt):
    """The explicit recursion y[k+1] = y[k] + dt·rate(y[k]), one step at a time (the reference)."""
    n, K = drv.q.shape
    out = np.empty((n, K + 1))
    out[:, 0] = y = np.asarray(y0, float).copy()
    for k in range(K):
        aux = [None if a is None else a[:, k] for a in drv.aux]
        y = y + dt * model._rate(drv.q[:, k], aux, None if drv.dist is None else drv.dist[:, k], y)
        out[:, k + 1] = y
    return out


#: laws whose rate depends on the force (the block solver's and the linearised columns' cases)
FORCE_DEPENDENT = [
    ("base+stiffness", {"stiffness.k_abs": 1.5, "stiffness.k_sgn": 0.3}),
    ("base+reversal+stiffness+stiction", {"stiffness.k_abs": 1.5}),
    ("base+load_pressure", {}), ("base+unloading", {}),
    ("base+leakage+stiffness", {"stiffness.k_abs": 3.0}),
    ("base+supply+load_pressure+oscillation", {}),
]


@pytest.mark.parametrize("spec, values", FORCE_DEPENDENT)
def test_a_force_dependent_rate_is_integrated_as_the_step_by_step_recursion(spec, values):
    """The block solver (Newton on whole blocks) reaches the explicit recursion's own answer,
    from any guess, whatever the law: to 1e-12 of the force."""
    rng = np.random.default_rng(0)
    dt = 0.002
    t = np.arange(3000) * dt
    u = np.stack([np.where((t // 1.0) % 2 == 0, a, -a) for a in (5, 10, 20, 40)])
    u = u + rng.normal(0, 0.5, u.shape)
    m = PlantModel.from_spec(spec, values)
    drv = m.drive(u, dt, m.new_state(4, dt, 0.0, u[:, 0]))
    y0 = np.array([0.0, 100.0, -500.0, 3000.0])
    ref = _stepped(m, drv, y0, dt)
    scale = np.max(np.abs(ref))
    assert np.max(np.abs(m.integrate(drv, y0, dt) - ref)) <= 1e-12 * scale
    far = ref + rng.normal(0, 300.0, ref.shape)          # a poor guess: the same answer
    assert np.max(np.abs(m.integrate(drv, y0, dt, guess=far) - ref)) <= 1e-12 * scale


def test_a_guess_that_overflows_is_recovered_from_not_returned():
    """A guess so far off that the law overflows on it: the passes that overflow beyond the
    steps they made exact are computed again, and the answer is the recursion's, finite."""
    m = PlantModel.from_spec("base+stiffness", {"stiffness.k_abs": 50.0})
    dt = 0.002
    u = np.full((2, 1500), 40.0)
    drv = m.drive(u, dt, m.new_state(2, dt, 0.0, u[:, 0]))
    y0 = np.array([5000.0, -3000.0])
    ref = _stepped(m, drv, y0, dt)
    got = m.integrate(drv, y0, dt, guess=np.full((2, 1501), 1e300))
    assert np.all(np.isfinite(got)) and np.allclose(got, ref, rtol=1e-10)


def test_the_stiffness_gain_compiled_is_numpy_s_law_bit_for_bit():
    """The stiffness's gain runs compiled (one pass instead of numpy's four temporaries): the
    same numbers to the last bit, for any shape the hooks pass, NaN and both clips included."""
    from plant.effects.stiffness import Stiffness
    rng = np.random.default_rng(4)
    for k_abs, k_sgn in ((1.5, -0.3), (-1.0, 20.0), (0.0, 0.0)):
        eff = Stiffness(k_abs=k_abs, k_sgn=k_sgn)
        for y in (rng.normal(0, 8000, (70, 500)), rng.normal(0, 3e4, 7), np.array([np.nan, -1e9, 1e9]),
                  np.float64(300.0), rng.normal(0, 1e4, (4, 10))[:, 3]):
            x = np.asarray(y) / 1e4
            numpy_law = np.maximum(1.0 + k_abs * np.abs(x) + k_sgn * x, 0.0)
            got = eff.gain(None, None, y)
            assert np.shape(got) == np.shape(numpy_law)
            assert np.array_equal(got, numpy_law, equal_nan=True)


def test_flow_factors_of_read_only_drives_are_kept_bit_for_bit_and_others_computed():
    """The factors of FLOW effects that do not read the force are kept for a fit's cached
    (read-only) drives, by the effect's values: the same numbers as the gain's, a new value
    computed anew, and an emulator's (writeable) block never kept."""
    from plant import model as M
    rng = np.random.default_rng(7)
    dt = 0.002
    u = np.where((np.arange(2000) * dt // 0.5) % 2 == 0, 8.0, -8.0)[None, :] + rng.normal(0, 0.3, (1, 2000))
    m = PlantModel.from_spec("base+reversal+stiffness", {"stiffness.k_abs": 1.0})
    drv = m.drive(u, dt, m.new_state(1, dt, 0.0, u[:, 0]))
    rev = m.effect("reversal")
    j = m._flow.index(rev)                         # its prepared signal in the drive
    fresh = rev.gain(drv.q, drv.aux[j], None)
    M._FACTORS.clear()
    assert np.array_equal(M._flow_factor(rev, drv.q, drv.aux[j]), fresh) and not M._FACTORS
    for arr in (drv.q, drv.aux[j]):
        arr.flags.writeable = False
    first = M._flow_factor(rev, drv.q, drv.aux[j])
    assert np.array_equal(first, fresh) and len(M._FACTORS) == 1 and not first.flags.writeable
    assert M._flow_factor(rev, drv.q, drv.aux[j]) is first
    y = rng.normal(0, 3000.0, drv.q.shape)
    for other in (m, m.with_params({"g": 80.0, "stiffness.k_abs": 2.0})):   # the same factor
        assert np.array_equal(other.rate_along(drv, y), other._rate(
            np.array(drv.q), [np.array(a) for a in drv.aux], None, y))
    assert len(M._FACTORS) == 1
    moved = m.with_params({"reversal.boost": 3.0})
    assert np.array_equal(M._flow_factor(moved.effect("reversal"), drv.q, drv.aux[j]),
                          moved.effect("reversal").gain(drv.q, drv.aux[j], None))
    assert len(M._FACTORS) == 2


@pytest.mark.parametrize("spec, values", FORCE_DEPENDENT)
def test_the_linearised_integration_is_a_finite_difference_column_to_its_own_error(spec, values):
    """A finite-difference column of the force from the recursion linearised about the base
    solution (one pass, the base's growth factors) is the column of the solved recursion, for
    every parameter of the model: those of the law, the gain, the trend, and those that move
    the drive (delay, a boost's decay) or the start, to 1e-5 of the column (the forward
    difference's own error is of that order)."""
    rng = np.random.default_rng(1)
    dt = 0.002
    t = np.arange(2500) * dt
    u = np.stack([np.where((t // 1.0) % 2 == 0, a, -a) for a in (5, 10, 20)])
    u = u + rng.normal(0, 0.5, u.shape)
    m = PlantModel.from_spec(spec, values)
    y0 = np.array([50.0, 800.0, -1500.0])      # not on a law's step at zero force

    def solve(model, start=y0, growth=None):
        drv = model.drive(u, dt, model.new_state(3, dt, 0.0, u[:, 0]))
        return drv, model.integrate(drv, start, dt, growth=growth)

    growth: list = []
    _, base = solve(m, growth=growth)
    assert growth and growth[0].shape == (3, u.shape[1])
    cases = [(name, m.with_params({name: v + 1e-6 * max(1.0, abs(v))}), y0)
             for name, v in m.params().items() if not (name == "tau" and v == 0.0)]
    cases.append(("start", m, y0 + 1e-3))
    for name, moved, start in cases:
        drv, solved = solve(moved, start)
        linear = moved.integrate_linearised(drv, start, dt, base, growth[0])
        col = solved - base
        err = np.max(np.abs(linear - solved))
        assert err <= 1e-5 * np.max(np.abs(col)) + 1e-9 * np.max(np.abs(base)), (name, err)


def test_the_reversal_s_scale_is_kept_for_a_read_only_command_and_is_numpy_s_law():
    """The boost's power law of the command is kept by command and exponent (a fit's Jacobian
    moves the boost, its decay, g... with the same scale): its gain is the law's to the last
    bit either way, for a read-only command or one that may change."""
    from plant.effects import reversal as R
    rng = np.random.default_rng(3)
    q = rng.normal(0, 8.0, (5, 400))
    aux = rng.uniform(0, 1, q.shape)
    R._SCALES.clear()
    for p, b in ((0.7, 2.5), (0.7, 3.0), (0.0, 2.5), (1.0, 0.1)):
        eff = R.Reversal(boost=b, exponent=p)
        law = 1.0 + b * (10.0 / np.maximum(np.abs(q), 0.5)) ** p * aux
        assert np.array_equal(eff.gain(q, aux, None), law)
        frozen = q.copy()
        frozen.flags.writeable = False
        assert np.array_equal(eff.gain(frozen, aux, None), law)
    assert len(R._SCALES) == 4          # one per read-only command and exponent ...
    ro = q.copy()
    ro.flags.writeable = False
    first = R._command_scale(ro, 10.0, 0.7)
    assert R._command_scale(ro, 10.0, 0.7) is first and len(R._SCALES) == 5   # ... kept
