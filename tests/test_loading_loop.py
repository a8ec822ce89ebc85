"""The load experiment's control law in a closed loop, offline: the plant is the emulator's own
lockstep plant (plant_emulator.lockstep_plant, the model the emulated stand runs) stepped one
period per cycle with the dynamometer's noise, no bus, so each run takes a fraction of a second.

What it shows: the feedback is scaled down where the model predicts a gain above the design's ρ
(right after a reversal at a small command: 17× at b = 2, p = 0.7) and keeps the feedforward's
sign there, so it never reverses the valve the model did not plan: no extra cycle; without
those two the PI rings after reversals into long, slowly starting segments (the extra cycles
of 30-75 kgf the benchmark met). The approach moves the rod one way and the pre-roll plans the
programme's start, so the first turning point is as good as the others whichever side the
force starts on."""
from __future__ import annotations

import numpy as np
import pytest

from gateway.load_experiment import LoadProgramme, OneWayApproach, pre_roll
from loading.controller import PIFeedforward
from loading.design import design
from loading.feedforward import channel_feedforward as feedforward
from loading.feedforward import feedback_scale
from loading.programme import Programme, from_levels, random_sequence, sine
from loading.report import channel_report as tracking_report
from plant import PlantModel
from plant_emulator.lockstep_plant import LockstepPlant
from tests.support.station_step import stepper

T = 0.002
STANDS = {
    "default": ("base+reversal", {"g": 120.0, "tau": 0.05, "delta": 8.0, "reversal.boost": 2.0}),
    "other": ("base+asymmetry+reversal", {"g": 80.0, "tau": 0.07, "delta": 8.0, "reversal.boost": 3.0,
                                          "reversal.decay": 0.1, "asymmetry.ratio": 0.1}),
}


def closed_loop(truth: PlantModel, experiment: LoadProgramme, y0: float, seed: int):
    """Run one pass of ``experiment`` against ``truth``; the tracking report."""
    plant = LockstepPlant(truth, y0, 0.0005)
    rng = np.random.default_rng(seed)
    begin, finished, step, _aborted = stepper(experiment, T, 10000.0)
    y, t = y0, 0.0
    begin(y)
    ts, ys = [], []
    while not finished(t, y):
        u, _ = step(t, y)
        y = plant.step(T, u) + rng.normal(0.0, 2.0)
        t += T
        ts.append(t)
        ys.append(y)
    return tracking_report(experiment.programme.channels[0], np.array(ts) - experiment.programme_start_s,
                           np.array(ys))


def without_schedule_and_sign_hold(experiment: LoadProgramme) -> LoadProgramme:
    for plans in experiment.plans.values():
        for plan in plans:
            plan.scale[:] = 1.0
            plan.way[:] = 0.0
    return experiment


@pytest.mark.parametrize("stand", list(STANDS))
def test_no_extra_cycle_on_random_sequences_and_the_pi_alone_rings(stand):
    spec, values = STANDS[stand]
    truth = PlantModel.from_spec(spec, values)
    c = design(truth, T)
    rang = []
    for seed in range(10, 16):
        p = from_levels(random_sequence(30, 400, 6200, seed=seed), T, rate_kgf_s=2500)
        rep = closed_loop(truth, LoadProgramme(p, c), 0.0, seed)
        assert rep.extra_cycles == 0, (seed, rep.largest_extra_cycle_kgf)
        assert rep.peak_valley_error_pct["p95"] <= 0.3 and rep.peak_valley_error_pct["max"] <= 0.5, rep.figures()
        plain = closed_loop(truth, without_schedule_and_sign_hold(LoadProgramme(p, c)), 0.0, seed)
        if plain.extra_cycles:
            rang.append(plain.largest_extra_cycle_kgf)
    # (4 of these 6 on both stands, 33-69 kgf, the gate is 23 kgf)
    assert len(rang) >= 3 and min(rang) > 30, "the PI alone rings after reversals"


@pytest.mark.parametrize("stand", list(STANDS))
@pytest.mark.parametrize("y0", [0.0, 6000.0], ids=["from below", "from above"])
def test_the_first_turning_point_is_as_good_as_the_others_whichever_side_the_force_starts(stand, y0):
    spec, values = STANDS[stand]
    truth = PlantModel.from_spec(spec, values)
    c = design(truth, T)
    for p in (sine(3000, 2000, 0.2, 3, T), from_levels(random_sequence(12, 400, 6200, seed=3), T, rate_kgf_s=2500)):
        rep = closed_loop(truth, LoadProgramme(p, c), y0, 1)
        assert rep.extra_cycles == 0
        assert abs(rep.turning_points[0].error_pct) <= 0.25, rep.turning_points[0]
        assert rep.peak_valley_error_pct["max"] <= 0.35, rep.figures()


def test_the_feedback_is_scaled_where_the_model_gain_exceeds_rho():
    spec, values = STANDS["default"]
    model = PlantModel.from_spec(spec, values)
    c = design(model, T).channels[0]
    p = from_levels([1000, 5000, 1000], T, rate_kgf_s=2500)
    ff = feedforward(model, p.r_kgf, T)
    scale = feedback_scale(ff, c.boost)
    # right after a reversal at a command under 0.5 %: 1 + b·(10/0.5)^0.7
    assert ff.gain_factor.max() == pytest.approx(1 + 2.0 * 20 ** 0.7, rel=0.02)
    assert scale.min() == pytest.approx(c.boost / ff.gain_factor.max(), rel=1e-6)
    mid = p.turning_idx[1] // 2                      # half way up: no reversal near
    assert ff.gain_factor[mid] < 1.1 and scale[mid] == 1.0
    assert 0.05 < np.mean(scale < 1) < 0.3
    base = feedforward(PlantModel.from_spec("base", {"g": 120.0, "tau": 0.05}), p.r_kgf, T)
    assert np.all(base.gain_factor == 1.0) and np.all(feedback_scale(base, 1.0) == 1.0)


def test_the_law_holds_the_sign_it_is_given_without_winding_up():
    law = PIFeedforward(0.04, 0.9, T, 100.0)
    for _ in range(100):
        assert law.step(1000.0, 1200.0, 0.5, way=1.0) == 0.0      # the feedback wants -8 %
    assert law.integral == 0.0, "no integral growth against the held sign"
    assert law.step(1000.0, 990.0, 0.5, way=1.0) > 0.5
    assert law.integral > 0.0
    assert law.step(1000.0, 1200.0, 0.5) < 0, "free without a sign to keep"


def test_the_approach_moves_one_way_and_the_pre_roll_goes_against_the_trend():
    a = OneWayApproach(3000.0, 0.02, 20.0, 20.0, max_s=10.0)
    a.way = 1.0
    a.begin(0.0)
    assert a.step(0.0, 100.0) > 0 and a.step(0.1, 3100.0) == 0.0
    p = from_levels([400, 5000, 1000], T, rate_kgf_s=2500)
    for trend, side in ((8.0, 1.0), (-8.0, -1.0)):      # starts above the level for Δ > 0
        pre = pre_roll(Programme.of(p), [trend], 20.0)[0]
        assert np.sign(pre[0] - 400) == side and abs(pre[0] - 400) == pytest.approx(0.02 * 4600)
        assert np.all(np.diff(pre) * side <= 0) and abs(pre[-1] - 400) < 0.1
    assert pre_roll(Programme.of(p), [0.0], 20.0)[0][0] < 400, "no trend: from behind the first motion"
    low = from_levels([50, 5000, 1000], T, rate_kgf_s=2500)
    assert pre_roll(Programme.of(low), [-8.0], 20.0)[0][0] == 0.0, "a pre-roll never crosses 0 kgf"
