"""Null pacing on a rig, offline (loading.pacing on the emulator's coupled lockstep plant,
gateway.offline): one channel's valve slower than the model (a flow limit it lacks) misses
load cases and bends the ratios without pacing; with static pacing the one clock waits for it
and every channel holds every load case, with dynamic pacing it also slows for it, so the load
distribution holds between the load cases too. The clock runs sample for sample while the forces
follow, and gives up, naming the channel, on a level the rig cannot reach. Through the gateway:
tests/test_rig_load_e2e.py."""
from __future__ import annotations

import numpy as np
import pytest

from gateway.load_experiment import LoadProgramme
from loading.design import design
from loading.pacing import PACING_TIMEOUT, PacingOptions
from loading.programme import from_load_cases, random_load_cases
from plant import PlantModel
from plant.rig import RigModel
from tests.support.rig_offline import T, example_truth, run_offline_pass

LIMITS = [9000, 9000, 4500, 4500]
BANDS = [(500, 6000), (500, 6000), (300, 3200), (300, 3200)]


@pytest.fixture(scope="module")
def rig():
    model, noise = example_truth()
    L = random_load_cases(12, BANDS, seed=3)
    # 5000 kgf/s: outer's feedforward needs up to 17 % of its valve
    return model, noise, design(model, T), from_load_cases(L, model.names, T, rate_kgf_s=5000)


def with_flow_limit(model: RigModel, channel: int, limit_pct: float) -> RigModel:
    """The rig with one channel's valve passing at most ``limit_pct`` of flow."""
    chans = list(model.channels)
    c = chans[channel]
    chans[channel] = PlantModel.from_spec(c.spec + "+saturation", {**c.params(), "saturation.limit": limit_pct})
    return RigModel(chans, model.G, names=model.names)


def run(rig, truth, pacing=None):
    model, noise, design, programme = rig
    e = LoadProgramme(programme, design, pacing=pacing)
    return run_offline_pass(e, truth, 0.0, 1, noise, force_limits=LIMITS), e


def figures(report):
    return ([r.peak_valley_error_pct["p95"] for r in report.channels],
            [r.peak_valley_error_pct["max"] for r in report.channels], report.ratio_error_pct)


def test_a_slow_valve_misses_load_cases_without_pacing_and_none_with_it(rig):
    model = rig[0]
    slow = with_flow_limit(model, 2, 12.0)            # outer's valve: at most 12 % of flow
    off, _ = run(rig, slow)
    assert off.abort is None
    p95, mx, ratio = figures(off.report)
    assert mx[2] > 2.0 and ratio > 2.0, (p95, mx, ratio)      # outer lags, the ratios bend
    on, e = run(rig, slow, PacingOptions("static"))
    assert on.abort is None
    p95, mx, ratio = figures(on.report)
    # every channel holds every load case within its tolerance (0.5 % of its range), the ratios too
    assert max(mx) <= 0.5 and ratio <= 0.5, (p95, mx, ratio)
    assert all(r.extra_cycles == 0 for r in on.report.channels)
    rec = e.clock.record
    assert rec.waits >= 1 and rec.pacing_s > 0.1 and rec.pacing_s == pytest.approx(rec.wait_s, abs=0.02)
    # the report reads the forces on the programme's clock: a wait's cycles share a time
    assert np.all(np.diff(on.t) >= -1e-9) and np.sum(np.diff(on.t) == 0) >= int(rec.wait_s / T) - 2
    assert len(on.t) - len(off.t) == pytest.approx(rec.wait_s / T, abs=2)


def test_the_clock_runs_sample_for_sample_while_the_rig_follows(rig):
    model = rig[0]
    off, _ = run(rig, model)
    on, e = run(rig, model, PacingOptions("static"))
    assert e.clock.record.waits == 0 and e.clock.record.pacing_s == 0.0
    assert e.positions == list(range(len(e.positions)))
    assert figures(on.report) == figures(off.report)


def test_a_level_the_rig_cannot_reach_stops_the_pass_naming_the_channel(rig):
    model = rig[0]
    stuck = with_flow_limit(model, 3, 3.0)            # tip's valve: at most 3 % of flow
    res, e = run(rig, stuck, PacingOptions("static", timeout_s=1.0))
    assert res.abort is not None and res.abort[0] == PACING_TIMEOUT, res.abort
    assert e.abort_channel == 3 and res.abort[1].startswith("channel tip: its force did not reach load case ")
    assert "in 1 s of waiting" in res.abort[1]


def along_the_way_kgf(res, e) -> np.ndarray:
    """Each channel's largest |force − its reference at the clock's position| over the main
    phase: the load distribution the structure saw between the load cases."""
    R = np.array([e.clock.reference_at(p) for p in e.positions]).T
    first = int(round(e.main_start_s / T)) - 1          # the reading of the main phase's first cycle
    n = min(R.shape[1], res.y.shape[1] - first)
    return np.max(np.abs(res.y[:, first:first + n] - R[:, :n]), axis=1)


def test_dynamic_pacing_slows_every_channel_for_the_one_that_lags(rig):
    """Static pacing keeps the load cases but not the way between them: the channels that keep
    up run ahead of the slow one; dynamic slows the one clock so the distribution holds along
    the way too."""
    model = rig[0]
    slow = with_flow_limit(model, 2, 12.0)
    static, es = run(rig, slow, PacingOptions("static"))
    dynamic, ed = run(rig, slow, PacingOptions("dynamic"))
    assert static.abort is None and dynamic.abort is None
    way_static, way_dynamic = along_the_way_kgf(static, es), along_the_way_kgf(dynamic, ed)
    assert way_dynamic[2] < 0.4 * way_static[2], (way_static, way_dynamic)      # outer
    assert way_dynamic.max() < 100.0, way_dynamic
    p95, mx, ratio = figures(dynamic.report)
    assert max(mx) <= 0.5 and ratio <= 0.5, (mx, ratio)
    rec = ed.clock.record
    assert rec.slowed_s > 0.2 and rec.pacing_s > rec.wait_s
    # slowed positions are fractional, and the report reads the forces on the programme's clock
    assert any(p != int(p) for p in ed.positions)
    assert np.all(np.diff(dynamic.t) >= -1e-9)


def test_pacing_is_for_load_cases_only(rig):
    from core.errors import ParameterError
    from loading.programme import from_channel_programmes, from_levels
    model, _, design, programme = rig
    seqs = from_channel_programmes([from_levels([500, 1000 + 100 * i, 600], T, rate_kgf_s=1000)
                                    for i in range(4)], model.names)
    for mode in ("static", "dynamic"):
        with pytest.raises(ParameterError, match="per-channel sequences have none"):
            LoadProgramme(seqs, design, pacing=PacingOptions(mode))
