"""A force held at a hydraulic limit is found where it is, at its level, and nothing else is
taken for one: not a ramp, a dead zone, a rod that sticks after a reversal, a hold at zero."""
from __future__ import annotations

import numpy as np

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
