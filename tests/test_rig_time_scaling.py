"""Time scaling of a rig's load cases, offline: the valve-limited minimum through G
(loading.minimum_time), a segment's verdict the worst of its channels'
(loading.time_scaling.TimeScaler.station_verdicts), a rig's schedule file
(loading.time_scaling.Schedule). The passes
on the emulated rig: tests/test_rig_load_e2e.py."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.errors import ParameterError
from gateway.load_experiment import LoadProgramme
from loading.design import design
from loading.feedforward import feedforward
from loading.minimum_time import FEEDFORWARD_SHARE, programme_timing
from loading.programme import Programme, from_channel_programmes, from_levels, from_load_cases, random_load_cases
from loading.report import tracking_report
from loading.time_scaling import HOLD, LAND, MISS, ScalingOptions, Schedule, TimeScaler, meets
from plant import PlantModel
from plant.rig import RigModel
from tests.support.rig_offline import T, example_truth, run_offline_pass

NAMES = ["a", "b", "c"]
BANDS = [(500, 6000), (500, 6000), (300, 3200)]


def channels():
    return [PlantModel.from_spec("base", {"g": g, "tau": 0.05, "delta": d})
            for g, d in ((120.0, 8.0), (90.0, -5.0), (150.0, 3.0))]


def test_an_uncoupled_rigs_minimum_is_its_slowest_channels_own_minimum_per_segment():
    L = random_load_cases(7, BANDS, seed=3)
    p = from_load_cases(L, NAMES, T, rate_kgf_s=2500)
    timing = programme_timing(p, RigModel(channels(), names=NAMES), 100.0)
    # each channel alone: every segment a haversine at its valve's largest rate, π·|ΔL|/(2R)
    own = []
    for m, row in zip(channels(), L):
        span = np.diff(row)
        rate = m.g * FEEDFORWARD_SHARE * 100 + np.where(span > 0, m.delta, -m.delta)
        own.append(np.pi * np.abs(span) / (2 * rate))
    own = np.array(own)
    assert timing.minimum_s == pytest.approx(own.max(axis=0), rel=1e-9)
    assert list(timing.binding) == list(own.argmax(axis=0))
    assert timing.programme_time_s == pytest.approx(p.duration_s)
    assert timing.ratio == pytest.approx(p.duration_s / own.max(axis=0).sum())


def test_at_a_coupled_rigs_minimum_the_binding_valve_just_reaches_its_share_of_the_command():
    """The neighbours' flows through G are counted: at the minimum the feedforward through the
    rig model's inverse asks the binding valve for the feedforward's 90 % of the command (to
    the σ grid and the whole periods), and 10 % faster it asks for more."""
    G = np.array([[120.0, 36.0, 0.0], [27.0, 90.0, 27.0], [0.0, 45.0, 150.0]])
    model = RigModel(channels(), G, names=NAMES)
    L = random_load_cases(6, BANDS, seed=4)
    L[2, 2] = L[2, 1]                      # c holds from case 2 to 3; its valve still moves
    p = from_load_cases(L, NAMES, T, rate_kgf_s=2500)
    timing = programme_timing(p, model, 100.0)
    uncoupled = programme_timing(p, RigModel(channels(), names=NAMES), 100.0)
    assert not np.allclose(timing.minimum_s, uncoupled.minimum_s, rtol=0.02), "G counted"
    for scale, low, high in ((1.0, 88.0, 91.5), (0.9, 98.0, 101.5)):
        q = p.with_durations(timing.minimum_s * scale)
        ff = feedforward(model, q.r_kgf, T, directions=[1.0] * 3, resolution_pct=0.0)
        idx = q.turning_idx - int(round(0.05 / T))           # each command sent τ ahead
        for k, i in enumerate(timing.binding):
            peak = np.abs(ff.channels[i].u_pct[max(idx[k], 0):idx[k + 1] + 1]).max()
            assert low <= peak <= high, (scale, k, NAMES[i], peak)
        # no valve anywhere beyond the binding one's
        assert ff.peak_pct.max() <= high


def test_a_valve_that_cannot_hold_its_force_against_the_trends_is_named():
    weak = [PlantModel.from_spec("base", {"g": 120.0, "tau": 0.05, "delta": 8.0}),
            PlantModel.from_spec("base", {"g": 1.0, "tau": 0.05, "delta": 200.0})]
    p = from_load_cases([[100, 900, 200], [100, 300, 500]], ["x", "y"], T, rate_kgf_s=1000)
    with pytest.raises(ParameterError, match="channel y cannot hold its force against the trends "
                                             "between load cases 1 and 2"):
        programme_timing(p, RigModel(weak, names=["x", "y"]), 100.0)


def test_per_channel_sequences_have_no_common_segments_to_time():
    seqs = [from_levels([0, 1000, 200], T, rate_kgf_s=1000), from_levels([0, 500, 100, 600], T, rate_kgf_s=1000)]
    p = from_channel_programmes(seqs, ["x", "y"])
    with pytest.raises(ParameterError, match="per-channel sequences"):
        programme_timing(p, RigModel(channels()[:2], names=["x", "y"]), 100.0)
    with pytest.raises(ParameterError, match="per-channel sequences"):
        p.with_durations([1.0, 1.0])


def test_a_rigs_schedule_round_trips_and_refuses_what_it_was_not_made_for(tmp_path):
    L = random_load_cases(5, BANDS, seed=1)
    p = from_load_cases(L, NAMES, T, rate_kgf_s=2500)
    d = np.array([0.4, 0.5, 0.3, 0.6])
    s = Schedule(p.levels_kgf, d, T, 0.5, 1.2, p.source, True, ["pass 3"], channels=NAMES)
    back = Schedule.load(s.save(tmp_path / "schedule.toml"))
    assert back.channels == NAMES and np.array_equal(back.levels_kgf, p.levels_kgf)
    assert np.allclose(back.durations_s, d) and back.verified
    timed = back.apply(p)
    assert timed.segment_durations_s == pytest.approx(d, abs=T / 2)
    assert all(np.array_equal(c.t_s, timed.t_s) for c in timed.channels)
    assert np.array_equal(timed.levels_kgf, p.levels_kgf) and timed.load_cases
    other = L.copy()
    other[1, 2] += 300
    with pytest.raises(ParameterError, match="load case 3 differs"):
        back.apply(from_load_cases(other, NAMES, T, rate_kgf_s=2500))
    with pytest.raises(ParameterError, match="for the channels a, b, c, the rig has a, b, d"):
        back.apply(from_load_cases(L, ["a", "b", "d"], T, rate_kgf_s=2500))
    with pytest.raises(ParameterError, match="a rig's .*replay it with --rig"):
        back.apply(Programme.of(from_levels(L[0], T, rate_kgf_s=2500)))
    one = Schedule(L[0], d, T, 0.5, 1.2, "one channel")
    with pytest.raises(ParameterError, match="one channel's: it cannot time a rig's load cases"):
        Schedule.load(one.save(tmp_path / "one.toml")).apply(p)
    (tmp_path / "bad.toml").write_text(s.to_toml().replace('channels = ["a", "b", "c"]',
                                                           'channels = ["a", "b"]'))
    with pytest.raises(ParameterError, match="a row of levels_kgf per channel"):
        Schedule.load(tmp_path / "bad.toml")


@pytest.fixture(scope="module")
def example():
    model, noise = example_truth()
    return model, noise, design(model, T)


def test_a_segment_misses_when_one_channel_misses_and_lands_only_when_all_land(example):
    model, noise, design = example
    L = random_load_cases(6, [(500, 6000), (500, 6000), (300, 3200), (300, 3200)], seed=2)
    p = from_load_cases(L, model.names, T, rate_kgf_s=2500)
    res = run_offline_pass(LoadProgramme(p, design), model, 0.0, 1, noise, force_limits=[9000, 9000, 4500, 4500])
    assert res.abort is None
    report = res.report
    options = ScalingOptions(accuracy_pct=0.5)
    verdicts = TimeScaler(p, np.full(5, 0.1), p.segment_durations_s, options).station_verdicts(p, report, res.t, res.y)
    assert verdicts == [LAND] * 5, report.text()          # 0.3 % on every channel offline
    assert meets(report, 0.5)
    # one channel off at one load case: that segment misses (or holds), the others stay
    ch = report.channels[2]
    tp = ch.turning_points[1]
    j = list(p.turning_idx).index(tp.index) - 1
    for error, verdict in ((0.45, MISS), (0.3, HOLD)):
        bad = dataclasses.replace(ch, turning_points=[dataclasses.replace(tp, error_pct=error)
                                                      if q is tp else q for q in ch.turning_points])
        worse = dataclasses.replace(report, channels=[bad if r is ch else r for r in report.channels])
        scaler = TimeScaler(p, np.full(5, 0.1), p.segment_durations_s, options)
        got = scaler.station_verdicts(p, worse, res.t, res.y)
        assert got[j] == verdict and got[:j] + got[j + 1:] == [LAND] * 4, got
        assert scaler.last[verdict] == 1
    # the tracking report on another channel's bad pass: a pass meets only when every channel does
    far = tracking_report(p, res.t, res.y + np.array([0, 0, 0, 40.0])[:, None])
    assert not meets(far, 0.5) and meets(far, 5.0)
