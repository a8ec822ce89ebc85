"""The station's gain monitor, offline (loading.gain_monitor on the emulator's coupled lockstep
plant, gateway.offline): one channel is the one-channel estimator, cycle for cycle; a softened row of G is
found on its channel only, the feedforward follows it, and the alarm acts on the whole rig.
Through the gateway, with the rig's unload: tests/test_rig_load_e2e.py."""
from __future__ import annotations

import numpy as np
import pytest

from gateway.load_experiment import LoadProgramme
from loading.design import design
from loading.gain_monitor import GAIN_ALARM, GainMonitor, MonitorOptions
from loading.programme import from_load_cases, random_load_cases
from plant import PlantModel
from plant.rig import RigModel
from tests.support.rig_offline import T, example_truth, run_offline_pass

LIMITS = [9000, 9000, 4500, 4500]
BANDS = [(500, 6000), (500, 6000), (300, 3200), (300, 3200)]


def test_a_one_channel_station_monitor_reads_its_channels_gain_and_its_alarm_in_its_own_words():
    """One channel through the station's monitor: the flows are its own commands (G = [g]),
    its estimates centre on the stand's gain (93 % of the model's here) with intervals that hold
    it, and the alarm, the channel's own, says so without a channel's name."""
    m = PlantModel.from_spec("base", {"g": 120.0, "tau": 0.046, "delta": 8.0})
    lag = 23                                       # τ in periods
    options = MonitorOptions(block_s=0.5, chunk_s=0.02, min_chunks=3, follow=False)
    rig = GainMonitor(RigModel([m], names=["only"]), T, options)
    rng = np.random.default_rng(4)
    for _ in range(2):
        rig.begin_pass()
        y, sent = 0.0, [(0.0, 1.0)] * lag
        for k in range(3000):
            u = 20 * np.sin(2 * np.pi * k / 700) + rng.normal(0, 0.5)
            factor = 1.0 if k % 350 > 20 else 1.3          # the model's FLOW factor: a boost
            rig.add([y + rng.normal(0, 2)], [u], [factor])   # the dynamometer's noise
            sent.append((u, factor))
            acting, boost = sent.pop(0)                      # what acts now: sent τ ago
            y += 0.93 * m.g * T * boost * acting + m.delta * T
        rig.end_pass()
    one = rig.channels[0]
    est = [b for b in one.blocks if b.g is not None]
    assert len(est) > 4 and all(abs(b.g - 0.93 * 120) < 0.03 * 120 for b in est), [b.g for b in est]
    assert np.mean([b.low <= 0.93 * 120 <= b.high for b in est]) >= 0.8
    assert one.alarm is not None and one.alarm[0] == "fall" and rig.alarm == one.alarm
    assert rig.summary()["alarm"] == "fall" and "channel only" not in rig.alarm[1]


@pytest.fixture(scope="module")
def rig():
    model, noise = example_truth()
    L = random_load_cases(16, BANDS, seed=7)
    return model, noise, design(model, T), from_load_cases(L, model.names, T, rate_kgf_s=2500)


def watched_pass(rig, crack: float, **options):
    """One pass of 16 load cases with root's row of G scaled by ``crack`` in the plant (the
    controller and the monitor keep the model's)."""
    model, noise, design, programme = rig
    G = model.G.copy()
    G[0, :] *= crack
    truth = RigModel(model.channels, G, names=model.names)
    monitor = GainMonitor(model, T, MonitorOptions(block_s=2.0, **options))
    experiment = LoadProgramme(programme, design, monitor=monitor)
    res = run_offline_pass(experiment, truth, 0.0, 1, noise, force_limits=LIMITS)
    monitor.end_pass()
    return res, monitor, experiment


def test_a_softened_row_is_found_on_its_channel_only_and_the_feedforward_follows_it(rig):
    model = rig[0]
    diag = np.diag(model.G)
    def honest(channel, g):
        """The block estimates centre on ``g`` and their 95 % intervals hold it (one may miss)."""
        est = [b for b in channel.blocks if b.g is not None]
        assert len(est) >= 8, len(est)
        assert abs(np.median([b.g for b in est]) / g - 1) < 0.005, [b.g for b in est]
        assert sum(not (b.low <= g <= b.high) for b in est) <= 1, [(b.low, b.high) for b in est]

    # the model's structure: every channel at its G_ii, no alarm
    res, monitor, _ = watched_pass(rig, 1.0, action="note", follow=False)
    assert res.abort is None and monitor.alarm is None
    for c, g in zip(monitor.channels, diag):
        honest(c, g)
    # root's row 10 % softer (a crack at its attachment): root falls, the others do not
    res, monitor, _ = watched_pass(rig, 0.9, action="note", follow=False)
    assert res.abort is None, "note: the test goes on"
    assert monitor.alarm[0] == "fall" and monitor.alarm_channel == 0
    assert monitor.alarm[1].startswith("channel root: block 2 ")
    honest(monitor.channels[0], 0.9 * diag[0])
    for c, g in zip(monitor.channels[1:], diag[1:]):
        assert c.alarm is None
        honest(c, g)
    unfollowed = res.report.channels[0].peak_valley_error_pct["p95"]
    # followed: the feedforward through G⁻¹·diag(G_ii/ĝ)·G, root tracks better
    res, monitor, _ = watched_pass(rig, 0.9, action="note", follow=True)
    assert monitor.channels[0].g_follow == pytest.approx(0.9 * diag[0], rel=0.015)
    assert [c.g_follow for c in monitor.channels[1:]] == pytest.approx(diag[1:], rel=0.02)
    M = monitor.ff_matrix
    scale = diag / np.array([c.g_follow for c in monitor.channels])
    expect = np.linalg.inv(model.G) @ (scale[:, None] * model.G)
    assert M == pytest.approx(expect)
    assert res.report.channels[0].peak_valley_error_pct["p95"] <= 0.75 * unfollowed
    summary = monitor.summary()
    assert summary["alarm_channel"] == "root" and set(summary["channels"]) == set(model.names)
    assert "gain root" in monitor.text() and "gain alarm (fall, action note): channel root" in monitor.text()


@pytest.mark.parametrize("action", ["hold", "unload"])
def test_a_gain_alarm_stops_the_whole_rig_and_asks_for_the_rigs_unload(rig, action):
    res, monitor, experiment = watched_pass(rig, 0.9, action=action, follow=False)
    assert res.abort is not None and res.abort[0] == GAIN_ALARM
    assert experiment.abort_channel == 0 and experiment.abort_action == action
    # the channel named once (by the loop, as here by the offline pass), then the alarm
    assert res.abort[1].startswith("channel root: block 2 ") and res.abort[1].count("root") == 1
    assert experiment.abort[1].startswith("block 2 ") and "fell" in res.abort[1]
    assert res.abort[1].endswith("every channel unloads keeping the load ratios" if action == "unload"
                                 else "every valve holds")
    # the pass ended at the alarm: block 2 closes 4 s into the main phase (pre-roll included)
    assert res.t[-1] - experiment.main_start_s == pytest.approx(4.0, abs=0.01)
