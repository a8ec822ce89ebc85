"""The gain monitor's estimate, offline against the emulator's own lockstep plant: it reads the
stand's g where the model says the stand is steady, so a wrong reversal boost in the model does
not bend it; the feedforward follows within its limit; bad settings are refused."""
from __future__ import annotations

import numpy as np
import pytest

from core.errors import ParameterError
from gateway.load_experiment import LoadProgramme
from loading.design import design
from loading.gain_monitor import ChannelGainMonitor, GainMonitor, MonitorOptions
from loading.programme import from_levels, random_sequence
from plant import PlantModel
from plant_emulator.lockstep_plant import LockstepPlant
from tests.support.station_step import stepper

T = 0.002
MODEL = {"g": 120.0, "tau": 0.05, "delta": 8.0, "reversal.boost": 2.0}


def watched(truth: PlantModel, options: MonitorOptions, seed: int = 1) -> ChannelGainMonitor:
    """A pass of 40 random turning points at 5000 kgf/s against ``truth``, 2 kgf of noise; the
    stand's one channel's monitor."""
    model = PlantModel.from_spec("base+reversal", MODEL)
    c = design(model, T)
    monitor = GainMonitor.for_controller(c, T, options)
    e = LoadProgramme(from_levels(random_sequence(40, 400, 6200, seed=3), T, rate_kgf_s=5000), c, monitor=monitor)
    plant = LockstepPlant(truth, 0.0, 0.0005)
    rng = np.random.default_rng(seed)
    begin, finished, step, _aborted = stepper(e, T, 10000.0)
    y, t = 0.0, 0.0
    begin(y)
    while not finished(t, y) and e.abort is None:
        u, _ = step(t, y)
        y = plant.step(T, u) + rng.normal(0.0, 2.0)
        t += T
    monitor.end_pass()
    return monitor.channels[0]


def test_a_lower_g_is_read_within_its_interval_and_a_wrong_boost_does_not_bend_it():
    for boost in (2.0, 3.0):                      # the model says 2
        truth = PlantModel.from_spec("base+reversal", {**MODEL, "g": 114.0, "reversal.boost": boost})
        m = watched(truth, MonitorOptions(block_s=4.0, fall_pct=10.0, follow=False))
        est = [b for b in m.blocks if b.g is not None]
        assert len(est) >= 4
        assert all(abs(b.g - 114.0) < 0.015 * 114 for b in est), (boost, [round(b.g, 2) for b in est])
        if boost == 2.0:                          # the model right but for g: the intervals hold it
            assert np.mean([b.low <= 114.0 <= b.high for b in est]) >= 0.8
        assert m.g_follow == 120.0, "watch only: the feedforward keeps the model's g"


def test_the_feedforward_follows_within_its_limit_and_the_alarm_names_the_fall():
    truth = PlantModel.from_spec("base+reversal", {**MODEL, "g": 108.0})      # 10 % lower
    m = watched(truth, MonitorOptions(block_s=4.0, fall_pct=5.0, follow_limit_pct=5.0))
    assert m.g_follow == pytest.approx(0.95 * 120.0) and m.ff_scale == pytest.approx(1 / 0.95)
    assert m.alarm is not None and m.alarm[0] == "fall" and "beyond 5 %" in m.alarm[1]
    first = next(b for b in m.blocks if b.alarm)
    assert -first.change_pct == pytest.approx(10.0, abs=1.0)
    assert sum(1 for b in m.blocks[:first.index] if b.g is not None) == 2, "two estimated blocks in a row"
    assert first.gain_margin == pytest.approx(m.margins.gain_margin_boosted / first.g * 120.0)


@pytest.mark.parametrize("options, match", [
    (MonitorOptions(action="explode"), "choose one of note, hold, unload"),
    (MonitorOptions(block_s=0.05, chunk_s=0.05), "must hold several chunks"),
    (MonitorOptions(fall_pct=-1.0), "fall_pct = -1.0 is out of range"),
])
def test_bad_monitor_settings_are_refused(options, match):
    with pytest.raises(ParameterError, match=match):
        options.check()
