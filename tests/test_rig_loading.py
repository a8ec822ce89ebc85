"""Loading a rig together, offline (loading.feedforward, loading.controller, loading.report;
gateway.load_experiment): the emulator's own coupled lockstep plant of the example rig
(4 channels, neighbours 30 %, each with its own g, τ and reversal boost) stepped one period per
cycle with its noise, the commands quantized to counts as on the wire.

What it shows: the feedforward through G⁻¹ makes the coupled model follow every channel where
each channel's own feedforward is off by hundreds of kgf; the decoupled controller tracks a
load-case programme within the issue's figures, also with a G identified a few percent off,
while today's controller on each channel is many times worse on its worst channel; the ratio
figure counts what a common scaling does not; and nothing moves after a bad programme."""
from __future__ import annotations

import numpy as np
import pytest

from core.errors import ParameterError
from dbc import profile as P
from gateway.load_experiment import LoadProgramme, held_direction, pre_roll_start
from loading.compensation import Compensation
from loading.controller import PIFeedforward
from loading.design import design
from loading.feedforward import channel_feedforward, feedforward
from loading.programme import from_channel_programmes, from_levels, from_load_cases, random_load_cases, sine
from loading.report import tracking_report
from plant import PlantModel
from plant.rig import RigModel

from tests.support.rig_offline import T, example_truth, run_offline_pass

BANDS = [(500, 6000), (500, 6000), (300, 3200), (300, 3200)]
LIMITS = [9000, 9000, 4500, 4500]


@pytest.fixture(scope="module")
def truth():
    return example_truth()


@pytest.fixture(scope="module")
def designs(truth):
    model, _ = truth
    return {"decoupled": design(model, T), "independent": design(model, T, feedback="independent")}


def quantized(u: np.ndarray) -> np.ndarray:
    return np.vectorize(lambda v: P.counts_to_percent(P.percent_to_counts(v)))(u)


def open_loop_error(model: RigModel, U: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Each channel's largest |force − reference| with the commands U held per period
    (0.5 ms steps, as the emulator)."""
    Y = model.simulate(np.repeat(U, 4, axis=1), T / 4, y0=R[:, 0], u_before=[1e-3] * model.n)[:, ::4]
    return np.max(np.abs(Y - R), axis=1)


class OneLoopPI:
    """The one-channel law, written out from its equation (loading.controller's docstring):
    ``u = clip(u_ff + s·Kp·e + i)``, ``i += s·Kp·T/Ti·e`` with conditional integration and a
    held sign."""

    def __init__(self, kp, ti, period_s, limit):
        self.kp, self.ki, self.limit, self.integral = kp, kp * period_s / ti, limit, 0.0

    def step(self, r, y, u_ff, scale, way):
        e = r - y
        integral = self.integral + scale * self.ki * e
        u = u_ff + scale * self.kp * e + integral
        if way * u < 0:
            if way * e > 0:
                self.integral = integral
            return 0.0
        if abs(u) > self.limit:
            if u * e < 0:
                self.integral = integral
            return max(-self.limit, min(self.limit, u))
        self.integral = integral
        return u


def test_the_feedforward_through_G_inverse_and_the_law_of_one_channel_are_the_channels_own():
    m = PlantModel.from_spec("base+reversal", {"g": 120.0, "tau": 0.05, "delta": 8.0})
    p = from_levels(random_sequence_levels(), T, rate_kgf_s=2500)
    one = channel_feedforward(m, p.r_kgf, T, direction=1.0)
    rig = feedforward(RigModel([m]), p.r_kgf[None, :], T, directions=[1.0], resolution_pct=0.0)
    assert np.allclose(rig.u_pct[0], one.u_pct, atol=1e-9)
    a, b = OneLoopPI(0.04, 0.9, T, 100.0), PIFeedforward([0.04], [0.9], T, 100.0)
    rng = np.random.default_rng(0)
    for _ in range(2000):
        r, y, uff = rng.normal(0, 3000), rng.normal(0, 3000), rng.normal(0, 60)
        s, w = rng.choice([1.0, 0.3]), rng.choice([0.0, 1.0, -1.0])
        assert b.step([r], [y], [uff], s, w)[0] == pytest.approx(a.step(r, y, uff, s, w), abs=1e-12)
    assert b.integral[0] == pytest.approx(a.integral, abs=1e-12)


def random_sequence_levels():
    from loading.programme import random_sequence
    return random_sequence(12, 400, 6200, seed=2)


def test_the_feedforward_through_G_inverse_makes_the_coupled_rig_follow_every_channel(truth):
    model, _ = truth
    p = from_load_cases(random_load_cases(8, BANDS, seed=5), model.names, T, rate_kgf_s=2500)
    R = p.r_kgf
    rig = feedforward(model, R, T, directions=[1.0] * 4)
    own = feedforward(model, R, T, directions=[1.0] * 4, mode="channel")
    assert np.all(open_loop_error(model, quantized(rig.u_pct), R) < 15.0)
    assert np.max(open_loop_error(model, quantized(own.u_pct), R)) > 1000.0, "the neighbours' flows"
    # planned on the valve's resolution: a planned reversal of a fraction of a count would be one
    # the rod never makes, and a reversal at a small flow is a 17x gain
    exact = feedforward(model, R, T, directions=[1.0] * 4, resolution_pct=0.0)
    assert np.all(open_loop_error(model, exact.u_pct, R) < 15.0)
    assert np.max(open_loop_error(model, quantized(exact.u_pct), R)) > 30.0


def test_decoupled_control_tracks_load_cases_where_todays_controller_per_channel_is_far_worse(truth, designs):
    model, noise = truth
    p = from_load_cases(random_load_cases(16, BANDS, seed=1), model.names, T, rate_kgf_s=2500)
    results = {}
    for name, c in designs.items():
        e = LoadProgramme(p, c)
        e.check(T, LIMITS, 100.0)
        res = run_offline_pass(e, model, 0.0, 1, noise, force_limits=LIMITS)
        assert res.abort is None
        results[name] = res.report
    dec, ind = results["decoupled"], results["independent"]
    for r in dec.channels:
        assert r.peak_valley_error_pct["p95"] <= 0.3 and r.peak_valley_error_pct["max"] <= 0.5, dec.text()
        assert r.extra_cycles == 0
    assert dec.ratio_error_pct <= 0.5
    worst = lambda rep: max(r.peak_valley_error_pct["p95"] for r in rep.channels)   # noqa: E731
    assert worst(ind) >= 10 * worst(dec), ind.text()
    assert ind.ratio_error_pct >= 10 * dec.ratio_error_pct
    # the JSON's figures: the worst channel at the top, every channel under channels
    f = dec.figures()
    assert f["worst_channel"] in model.names and set(f["channels"]) == set(model.names)
    assert f["peak_valley_error_pct"] == f["channels"][f["worst_channel"]]["peak_valley_error_pct"]


@pytest.mark.slow
def test_decoupled_control_with_a_g_off_by_1_percent_of_the_diagonal_holds_the_figures_and_compensation_learns(truth):
    """Ten times the identification's interval (0.1 %); at 3 % the figures do not hold
    (docs/loading.md, limits)."""
    model, noise = truth
    G = model.G.copy()
    rng = np.random.default_rng(4)
    d = np.diag(G)
    off = (G != 0) & ~np.eye(4, dtype=bool)
    G[off] += rng.uniform(-0.01, 0.01, off.sum()) * np.broadcast_to(d[None, :], G.shape)[off]
    G[np.diag_indices(4)] *= 1 + rng.uniform(-0.003, 0.003, 4)
    believed = RigModel([m.with_params({"g": float(G[i, i])}) for i, m in enumerate(model.channels)], G, model.names)
    c = design(believed, T)
    p = from_load_cases(random_load_cases(12, BANDS, seed=7), model.names, T, rate_kgf_s=2500)
    comp = Compensation(model.names)
    reports = []
    for k in range(3):
        e = LoadProgramme(p, c, comp)
        res = run_offline_pass(e, model, 0.0, k, noise, force_limits=LIMITS)
        reports.append(res.report)
        comp.learn(res.report.channels, p.ranges_kgf)
    for rep in reports:
        for r in rep.channels:
            assert r.peak_valley_error_pct["p95"] <= 0.5 and r.peak_valley_error_pct["max"] <= 1.0, rep.text()
            assert r.extra_cycles == 0
    first = max(r.peak_valley_error_pct["max"] for r in reports[0].channels)
    last = max(r.peak_valley_error_pct["max"] for r in reports[-1].channels)
    assert last < 0.6 * first, [rep.text() for rep in reports]


def test_a_channel_passing_its_level_at_a_load_case_is_judged_and_learns_there(truth):
    """tip rises through four load cases and falls back through three while the others turn
    at every one: its levels there are part of each load case's distribution, measured and
    compensated as the others' peaks and valleys are. The design believes tip's g 6 % high, so
    it lags there by more than the tolerance band at first."""
    model, noise = truth
    G = model.G.copy()
    G[3, 3] *= 1.06
    believed = RigModel([m.with_params({"g": float(G[i, i])}) for i, m in enumerate(model.channels)], G, model.names)
    c = design(believed, T)
    L = random_load_cases(9, BANDS[:3], seed=3)
    tip = np.array([300.0, 900, 1500, 2100, 2700, 2000, 1300, 600, 400])
    p = from_load_cases(np.vstack([L, tip]), model.names, T, rate_kgf_s=2500)
    passing = [k for k, kind in enumerate(p.channels[3].kinds()) if kind in ("rising", "falling")]
    assert len(passing) == 6 and p.turning_cases().tolist() == list(range(1, 8))
    comp = Compensation(model.names)
    errors = []
    for k in range(3):
        res = run_offline_pass(LoadProgramme(p, c, comp), model, 0.0, k, noise, force_limits=LIMITS)
        points = [tp for tp in res.report.channels[3].turning_points if tp.kind in ("rising", "falling")]
        assert len(points) == 6, "every level tip passes at a load case is judged"
        errors.append(max(abs(tp.error_pct) for tp in points))
        comp.learn(res.report.channels, p.ranges_kgf)
    assert set(comp.channels["tip"].cases) >= set(passing), "each load case tip passes learns its own"
    assert not comp.channels["tip"].table.get("rising"), "by load case, never by level"
    assert errors[0] > 0.1 and errors[-1] < 0.5 * errors[0], errors


def test_per_channel_sequences_run_together_without_load_cases(truth, designs):
    model, noise = truth
    progs = [sine(3000, 1500, 0.2, 2, T), from_levels([800, 4000, 1500, 3500], T, rate_kgf_s=2000),
             sine(1500, 800, 0.3, 3, T), from_levels([600, 3000, 900], T, rate_kgf_s=1500)]
    p = from_channel_programmes(progs, model.names)
    res = run_offline_pass(LoadProgramme(p, designs["decoupled"]), model, 0.0, 2, noise, force_limits=LIMITS)
    assert res.report.ratio_error_pct is None and res.report.cases is None
    for r in res.report.channels:
        assert r.peak_valley_error_pct["max"] <= 0.5 and r.extra_cycles == 0, res.report.text()


@pytest.mark.slow
def test_the_approach_holds_every_force_against_its_trend_with_a_model_20_percent_off(truth):
    """The approach ends holding each force against its trend, the valve's way then the way of
    the flow that holds it (−G⁻¹Δ): with G 20 % low in the design the line overshoots, and a valve
    kept on the move's way could only hold at zero while its trend carried the force away (the
    pass stopped set_point_not_reached with the forces 30-60 kgf past the start, nothing
    moving). From rest and from where a campaign left the forces, the pass completes."""
    model, noise = truth
    low = RigModel(model.channels, model.G * 0.8, names=model.names)
    p = from_load_cases(random_load_cases(4, BANDS, seed=1), model.names, T, rate_kgf_s=2500)
    for y0 in ([0.0] * 4, [846.0, 709.0, 329.0, 406.0]):
        e = LoadProgramme(p, design(low, T), None)
        e.check(T, LIMITS, 100.0)
        res = run_offline_pass(e, model, y0, 3, noise, force_limits=LIMITS)
        assert res.abort is None and res.report is not None, res.abort
        hold = -np.linalg.inv(low.G) @ np.array([m.delta for m in low.channels])
        assert np.array_equal(e.approach.way, np.sign(hold))
        assert max(r.peak_valley_error_pct["max"] for r in res.report.channels) < 3.0


def test_the_ratio_error_counts_what_a_common_scaling_of_a_load_case_does_not():
    p = from_load_cases([[100, 4000, 1000, 3000], [100, 2000, 400, 1400]], ["a", "b"], T, rate_kgf_s=2500)
    t = p.t_s
    scaled = p.r_kgf * 1.01                          # every channel 1 % high: the ratios hold
    rep = tracking_report(p, t, scaled)
    assert rep.ratio_error_pct == pytest.approx(0.0, abs=1e-9)
    assert rep.channels[0].peak_valley_error_pct["max"] > 0.5
    off = p.r_kgf.copy()
    k = p.turning_idx[2]
    off[1, k - 5:k + 5] -= 10.0                      # b misses its valley at case 3 by 10 kgf
    rep = tracking_report(p, t, off)
    case = rep.cases[1]                              # a at 1000 of 3900, b at 400 of 1900: a leads
    assert case.lead == "a" and case.deviation_pct[1] == pytest.approx(-100 * 10 / p.ranges_kgf[1], rel=1e-6)
    assert rep.ratio_error_pct == pytest.approx(100 * 10 / p.ranges_kgf[1], rel=1e-6)


def test_the_pre_roll_keeps_every_valve_on_the_sign_that_holds_the_forces():
    rng = np.random.default_rng(1)
    for _ in range(50):
        K = np.eye(4) + np.diag(rng.uniform(-0.35, 0.35, 3), 1)
        K = K + np.triu(K, 1).T
        G = K * rng.uniform(80, 150, 4)[None, :]
        delta = rng.normal(0, 8, 4)
        L0 = rng.uniform(300, 3000, 4)
        start = pre_roll_start(L0, L0 + 1000, delta, np.full(4, 5000.0), 20.0)
        hold = -np.linalg.solve(G, delta)              # the flows that hold the forces
        pre = np.linalg.solve(G, L0 - start)           # the pre-roll's extra flows
        assert np.all(np.sign(pre) == np.sign(hold))
        assert np.all(np.sign(start) == np.sign(L0))
    assert held_direction(np.array([0.0, 0.2, 0.0, -0.1, 0.0]), -1.0).tolist() == [-1, 1, 1, -1, -1]


def test_a_bad_programme_is_refused_before_anything_moves(truth, designs):
    model, _ = truth
    c = designs["decoupled"]
    high = from_load_cases([[500, 4000, 600], [500, 4700, 600], [300, 2000, 400], [300, 2500, 400]],
                           model.names, T, rate_kgf_s=2500)
    with pytest.raises(ParameterError, match="channel inner: .*4700 kgf.*force limit"):
        LoadProgramme(high, c).check(T, [9000, 4500, 4500, 4500], 100.0)
    fast = from_load_cases([[500, 6000], [500, 600], [300, 300], [300, 3000]], model.names, T, rate_kgf_s=12000)
    with pytest.raises(ParameterError, match=r"channel \w+ at t = .* needs a valve command of .* its valve cannot follow"):
        LoadProgramme(fast, c).check(T, LIMITS, 100.0)
    ok = from_load_cases([[500, 600], [500, 600], [300, 400], [300, 400]], model.names, T, rate_kgf_s=2500)
    with pytest.raises(ParameterError, match="period of 2 ms but the loop runs at 4 ms"):
        LoadProgramme(ok, c).check(0.004, LIMITS, 100.0)
    other = from_load_cases([[500, 600], [500, 600]], ["root", "tip"], T, rate_kgf_s=2500)
    with pytest.raises(ParameterError, match="the programme is for the channels root, tip"):
        LoadProgramme(other, c)
