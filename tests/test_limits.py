"""A force held at a hydraulic limit is found where it is, at its level, and nothing else is
taken for one: not a ramp, a dead zone, a rod that sticks after a reversal, a hold at zero."""
from __future__ import annotations

import numpy as np
import pytest

from analysis import make_record
from analysis.identification.windows import pieces_from_records
from analysis.records.limits import held_stretches

DT = 0.002


def meander(levels_limit=None, u0=10.0, up=3.0, down=1.5, cycles=3, g=120.0, noise=2.0,
            deadzone=0.0, stick_kgf=0.0, seed=0):
    """An uneven meander (``up`` s up, ``down`` s down) through an integrator, optionally
    clipped at a relief valve's level, with a dead zone or a play on the force; noise on top."""
    n = int(cycles * (up + down) / DT)
    t = np.arange(n) * DT
    u = u0 * np.where((t % (up + down)) < up, 1.0, -1.0)
    q = np.sign(u) * np.maximum(np.abs(u) - deadzone, 0)
    y = np.zeros(n)
    p = 0.0
    for k in range(1, n):
        y[k] = y[k - 1] + g * q[k - 1] * DT
        if levels_limit is not None:
            y[k] = min(y[k], levels_limit)
    if stick_kgf:
        out = np.zeros(n)
        for k in range(n):
            p = min(max(p, y[k] - stick_kgf / 2), y[k] + stick_kgf / 2)
            out[k] = p
        y = out
    return t, u, y + np.random.default_rng(seed).normal(0, noise, n)


def test_a_relief_valve_is_found_at_its_level_each_time_it_holds():
    # up 3600 kgf in 3 s, down 1800 in 1.5 s: the first rise holds 1.33 s at 2000 kgf, the
    # next ones 1.5 s each
    t, u, y = meander(levels_limit=2000.0)
    found = held_stretches(u, y, DT)
    assert len(found) == 3
    for s in found:
        assert abs(s.level_kgf - 2000) < 2 and s.command_pct > 0
        assert 1.2 < s.t1_s - s.t0_s < 1.6
    rec = make_record(t, u, y)
    assert sum("hydraulic limit" in n and "2000 kgf" in n for n in rec.notes) == 3
    # the held samples are left out of the error: the pieces skip them
    pieces = pieces_from_records([rec])
    assert len(pieces) > 1


def test_ramps_a_dead_zone_a_sticking_rod_and_a_hold_at_zero_are_not_limits():
    # a rod stuck 400 kgf at 2 %: 1.7 s flat after each reversal, pushing, but it did not arrive
    # there moving that way; a dead zone wider than the command: flat, never moving
    for kw in ({}, {"deadzone": 12.0}, {"stick_kgf": 400.0, "u0": 2.0}):
        t, u, y = meander(**kw)
        assert held_stretches(u, y, DT) == [], kw
    y = np.random.default_rng(1).normal(1000, 2, 5000)
    assert held_stretches(np.zeros(5000), y, DT) == []


def test_the_dynamometers_flat_clip_is_not_called_a_hydraulic_limit():
    t, u, y = meander(levels_limit=2000.0, noise=0.0)
    y = np.minimum(y + np.random.default_rng(3).normal(0, 2, len(y)), 1990.0)   # clipped reading
    assert held_stretches(u, y, DT) == []


def delayed_meander(limit, u0=10.0, up=2.0, down=2.0, cycles=3, g=120.0, delay_s=0.05,
                    lag_s=0.015, start_kgf=0.0, osc_kgf=0.0, noise=2.0, seed=0):
    """A meander (``up`` s up, ``down`` s down) through a delay, a valve lag and an integrator,
    the force clipped at ``limit`` (None: no limit), an oscillation at 3 Hz on the force; noise
    on top."""
    n = int(cycles * (up + down) / DT)
    t = np.arange(n) * DT
    u = u0 * np.where((t % (up + down)) < up, 1.0, -1.0)
    d = int(round(delay_s / DT))
    v = np.r_[np.zeros(d), u[:-d]]
    q = 0.0
    y = np.full(n, start_kgf)
    for k in range(1, n):
        q += DT / lag_s * (v[k - 1] - q)
        y[k] = y[k - 1] + g * q * DT
        if limit is not None:
            y[k] = min(y[k], limit)
    y = y + osc_kgf * np.sin(2 * np.pi * 3.0 * t)
    return t, u, y + np.random.default_rng(seed).normal(0, noise, n)


def test_a_hold_that_begins_just_before_the_command_turns_is_found():
    # down shorter than up by 60 ms + the delay and the lag: the force reaches the limit
    # 60-75 ms before each turn, is held that long under the push, then for the delay and the
    # lag after the turn (before, holds under the push shorter than 0.1 s were missed, and the
    # windows around them bent the lag and the asymmetry of a fit)
    level, down = 120 * 10 * 1.875, 2.0 - 0.06 - 0.065
    t, u, y = delayed_meander(level, up=2.0, down=down)
    at = delayed_meander(level, up=2.0, down=down, noise=0.0)[2] >= level
    reached = t[np.flatnonzero(np.diff(at.astype(int)) == 1) + 1]
    turns = t[np.flatnonzero(np.diff(u) < 0) + 1]
    assert np.all((turns - reached > 0.055) & (turns - reached < 0.08))    # under 0.1 s pushed
    found = held_stretches(u, y, DT)
    assert len(found) == 3, [s.describe() for s in found]
    for s, t0 in zip(found, reached):
        assert abs(s.level_kgf - level) < 3 and s.command_pct == 10.0
        assert s.t0_s == pytest.approx(t0, abs=0.02), s.describe()  # the band: 15 ms of ramp
        assert 0.12 < s.t1_s - s.t0_s < 0.2, s.describe()     # 60 ms + delay + lag
    # the same meander without the limit: its corners are never flat while the command pushes
    t, u, y = delayed_meander(None, up=2.0, down=down)
    assert held_stretches(u, y, DT) == []
    for u0 in (3.0, 5.0, 20.0):
        t, u, y = delayed_meander(None, u0=u0, delay_s=0.004)
        assert held_stretches(u, y, DT) == [], u0


def test_a_force_that_pauses_or_a_command_that_eases_is_not_a_limit():
    # an oscillation of 50 kgf at 3 Hz on a ramp of 600 kgf/s pauses the force now and then,
    # then it goes on past the level under the same push, or turns back while pushed (a pause
    # that ends as the command turns looks like a short hold, and may be taken for one)
    t, u, y = delayed_meander(None, u0=5.0, up=1.5, down=1.5, osc_kgf=50.0)
    assert [s for s in held_stretches(u, y, DT) if (s.t1_s % 1.5) > 0.2] == []
    # the command steps from 10 % down to 0.8 %, inside a 1 % dead zone: the force stops there
    # while the command still points up, but it no longer pushes
    t = np.arange(9000) * DT
    u = np.where(t % 4.5 < 3.0, np.where(t % 4.5 < 1.0, 10.0, 0.8), -10.0)
    y = np.zeros_like(u)
    q = np.sign(u) * np.maximum(np.abs(u) - 1.0, 0)
    for k in range(1, len(u)):
        y[k] = y[k - 1] + 120.0 * q[k - 1] * DT
    y += np.random.default_rng(0).normal(0, 2, len(y))
    assert held_stretches(u, y, DT) == []
