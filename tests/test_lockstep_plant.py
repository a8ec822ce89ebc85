"""The emulator's lockstep plant computes the periods within the transport delay ahead in one
block; it must give what advancing period by period gives, and the dynamometer's per-SYNC
reading must be what the array path gives."""
from __future__ import annotations

import math

import numpy as np
import pytest

from plant import Dynamometer, PlantModel
from plant_emulator.lockstep_plant import REBASE_BLOCKS, LockstepPlant

STEP = 0.0005


def period_by_period(model: PlantModel, commands, periods, y0: float) -> np.ndarray:
    state, dt, out = model.new_state(1, STEP, y0=y0), STEP, []
    for c, p in zip(commands, periods):
        sub = max(1, math.ceil(p / STEP - 1e-9))
        if p / sub != dt:
            state, dt = model.new_state(1, p / sub, y0=state.y, u0=c, t0=state.t), p / sub
        out.append(model.advance(state, np.full((1, sub), c), dt)[0, -1])
    return np.array(out)


@pytest.mark.parametrize("spec", ["base", "base+reversal", "base+lag+deadzone+backlash",
                                  "base+load_pressure+reversal+leakage+oscillation",
                                  "base+saturation+asymmetry+flow_curve",
                                  "base+command_reversal+sensor_lag"])
@pytest.mark.parametrize("tau", [0.0, 0.001, 0.0031, 0.05, 0.0777])
def test_blocks_ahead_equal_period_by_period_even_across_a_period_change(spec, tau):
    rng = np.random.default_rng(int(tau * 1e4))
    model = PlantModel.from_spec(spec, {"tau": tau, "g": 110.0})
    commands = np.repeat(rng.normal(0, 10, 400), rng.integers(1, 8, 400))[:1500]
    periods = [0.002] * 700 + [0.001] * 101 + [0.002] * 699   # changes inside a block
    plant = LockstepPlant(model, 50.0, STEP)
    got = np.array([plant.step(p, c) for c, p in zip(commands, periods)])
    want = period_by_period(model, commands, periods, 50.0)
    assert np.max(np.abs(got - want)) < 1e-9 * max(1.0, np.abs(want).max())
    m = model.delay_steps(STEP)      # 0 with command_reversal: its boost reads the command
    if m >= 4:   # τ spans several 2 ms periods: they were computed together
        assert not any(e.reads_command for e in model.effects)
        assert plant.periods_per_block > 0.8 * (m // 4 + 1)


def test_one_reading_at_a_time_is_the_array_path():
    rng = np.random.default_rng(3)
    y = rng.normal(0, 3000, 5000)
    y[::97] = 12000.0                       # over range
    whole, whole_over = Dynamometer(seed=4).measure(y)
    one = Dynamometer(seed=4)
    single = [one.read(v) for v in y]
    assert np.array_equal(whole, [r for r, _ in single])
    assert np.array_equal(whole_over, [o for _, o in single])
    mixed, i, out = Dynamometer(seed=4), 0, []   # the noise stream does not depend on the calls
    while i < len(y):
        if i % 3 == 0:
            r, _ = mixed.measure(y[i:i + 7])
            out += r.tolist()
            i += 7
        else:
            out.append(mixed.read(y[i])[0])
            i += 1
    assert np.array_equal(whole, out)


def test_a_restarted_clock_starts_the_drift_again_even_with_periods_computed_ahead():
    """A run begins (NMT start): the periods computed ahead carry the old time, so they are
    dropped, and the plant goes on from its force with its time at zero."""
    model = PlantModel.from_spec("base+gain_drift", {"tau": 0.05, "g": 110.0,
                                                     "gain_drift.rate": 0.04,
                                                     "gain_drift.time_constant": 3.0})
    rng = np.random.default_rng(7)
    commands = np.repeat(rng.normal(0, 10, 200), 5)[:900]
    plant = LockstepPlant(model, 0.0, STEP)
    got = [plant.step(0.002, c) for c in commands[:450]]
    assert plant._ahead                     # mid-block: periods were computed ahead
    ended = len(plant._commands)
    calls = []
    advance = plant.model.advance
    plant.model.advance = lambda *a, **k: calls.append(a[1].shape) or advance(*a, **k)
    plant.restart_clock()
    del plant.model.advance
    # the ended periods are replayed in one call: one per period made a real-time emulator's
    # start (every block's 100 steps replayed one by one) take 90 ms for 8 channels
    assert ended > 1 and calls == [(1, ended * 4)]
    got += [plant.step(0.002, c) for c in commands[450:]]
    state, want = model.new_state(1, STEP), []
    for i, c in enumerate(commands):
        if i == 450:
            state.t[:] = 0.0
        want.append(model.advance(state, np.full((1, 4), c), STEP)[0, -1])
    assert np.max(np.abs(np.array(got) - want)) < 1e-9 * np.abs(want).max()
    # without the restart the gain goes on from 1 + r·T·(1 − e^(−0.9 s/T)) ≈ 1.03: the force
    # at the end differs by far more than rounding
    going_on = LockstepPlant(model, 0.0, STEP)
    last = [going_on.step(0.002, c) for c in commands][-1]
    assert abs(last - want[-1]) > 1e-3 * np.abs(want).max()


@pytest.mark.parametrize("spec", ["base", "base+reversal", "base+lag+deadzone+backlash"])
@pytest.mark.parametrize("tau", [0.0, 0.0031, 0.05])
def test_holding_a_command_over_several_steps_is_stepping_them_one_by_one(spec, tau):
    """The real-time emulator catches up on the wall clock with ``hold``: a few steps at a
    SYNC or a command, now and then a long gap; the forces are those of stepping each step."""
    rng = np.random.default_rng(int(tau * 1e4) + 1)
    model = PlantModel.from_spec(spec, {"tau": tau, "g": 110.0})
    gaps = np.concatenate([rng.integers(0, 5, 300), [400], rng.integers(0, 5, 100), [3000]])
    commands = np.repeat(rng.normal(0, 10, 80), 6)[:len(gaps)]
    held, stepped = LockstepPlant(model, 50.0, STEP), LockstepPlant(model, 50.0, STEP)
    got, want = [], []
    for k, c in zip(gaps, commands):
        got.append(held.hold(int(k), STEP, [c])[0])
        for _ in range(int(k)):
            stepped.step(STEP, c)
        want.append(stepped.force)
    got, want = np.array(got), np.array(want)
    assert np.max(np.abs(got - want)) < 1e-9 * max(1.0, np.abs(want).max())
    if model.delay_steps(STEP) >= 8:          # the steps inside τ were computed together
        assert held.periods_per_block > 5


@pytest.mark.parametrize("spec", ["base", "base+reversal", "base+lag+deadzone+backlash",
                                  "base+gain_drift"])
@pytest.mark.parametrize("tau", [0.0, 0.0031, 0.05])
def test_a_block_prefetched_at_a_quiet_moment_changes_no_force(spec, tau):
    """The real-time emulator computes the next block between a cycle's commands and its next
    SYNC (``prefetch``), from the present, with the present command standing in: the forces
    are those of stepping each step, whatever commands follow, a restart and a long gap
    included; and the steps after a prefetch compute nothing."""
    rng = np.random.default_rng(int(tau * 1e4) + 2)
    drift = {"gain_drift.rate": 0.04, "gain_drift.time_constant": 3.0} if "drift" in spec else {}
    model = PlantModel.from_spec(spec, {"tau": tau, "g": 110.0, **drift})
    gaps = np.concatenate([rng.integers(0, 5, 300), [400], rng.integers(0, 5, 100)])
    commands = np.repeat(rng.normal(0, 10, 80), 6)[:len(gaps)]
    ahead, stepped = LockstepPlant(model, 50.0, STEP), LockstepPlant(model, 50.0, STEP)
    got, want, fetched = [], [], 0
    for j, (k, c) in enumerate(zip(gaps, commands)):
        if j == 350:
            ahead.restart_clock()
            stepped.restart_clock()
        got.append(ahead.hold(int(k), STEP, [c])[0])
        for _ in range(int(k)):
            stepped.step(STEP, c)
        want.append(stepped.force)
        if rng.random() < 0.3:      # at some quiet moments: some blocks run out to their end
            fetched += ahead.prefetch([c], 12)
        # what an undo would replay stays bounded, however long the blocks are extended
        assert len(ahead._commands) <= (REBASE_BLOCKS + 1) * (model.delay_steps(STEP) + 1)
        assert ahead.stand_time_s == pytest.approx(stepped.stand_time_s, abs=1e-12)
    got, want = np.array(got), np.array(want)
    assert np.max(np.abs(got - want)) < 1e-9 * max(1.0, np.abs(want).max())
    B = model.delay_steps(STEP) + 1
    if B - 1 > 12:
        assert fetched >= 3
        ahead.prefetch([1.0], 12)
        calls = []
        advance = ahead.model.advance
        ahead.model.advance = lambda *a, **kw: calls.append(1) or advance(*a, **kw)
        ahead.hold(12, STEP, [1.0])
        del ahead.model.advance
        assert calls == []
    else:
        assert fetched == 0          # a block no longer than the margin is not worth it


def test_a_prefetched_block_of_a_coupled_rig_takes_each_channels_own_commands():
    """Three coupled channels, each its own τ and commands changing at different steps: with
    prefetches the forces are those of stepping the rig step by step."""
    from plant.rig import RigModel
    from plant_emulator.lockstep_plant import LockstepRig
    models = [PlantModel.from_spec("base+reversal", {"tau": tau, "g": 110.0})
              for tau in (0.02, 0.035, 0.05)]
    G = np.array([[110.0, -20.0, 0.0], [-20.0, 110.0, -20.0], [0.0, -20.0, 110.0]])
    rig = RigModel(models, G)
    rng = np.random.default_rng(11)
    gaps = rng.integers(0, 6, 500)
    commands = rng.normal(0, 10, (len(gaps), 3))
    commands[rng.random(commands.shape) < 0.7] = 0.0      # most channels hold between steps
    ahead = LockstepRig(rig, [0.0, 100.0, -50.0], STEP)
    stepped = LockstepRig(rig, [0.0, 100.0, -50.0], STEP)
    got, want, fetched = [], [], 0
    for k, c in zip(gaps, commands.tolist()):
        got.append(ahead.hold(int(k), STEP, c))
        for _ in range(int(k)):
            stepped.step(STEP, c)
        want.append(stepped.forces)
        if rng.random() < 0.3:
            fetched += ahead.prefetch(c, 8)
    got, want = np.array(got), np.array(want)
    assert fetched >= 5
    assert np.max(np.abs(got - want)) < 1e-9 * np.abs(want).max()
