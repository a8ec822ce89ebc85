"""The unload that keeps the load ratios (gateway/unload.py), offline against the rig's model
``dy/dt = G·u(t − τ)`` stepped at the loop's period: for one channel it is the supervisor's
unload; on a coupled rig it keeps the distribution, and knowing G is what keeps it when the
channels differ and couple."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gateway.supervisor import SafetyLimits, Unloader
from gateway.unload import RatioUnloader

T = 0.002
TAU = 0.05


def simulate(unloader, G: np.ndarray, y0, steps: int = 20000, noise: float = 0.0, seed: int = 1):
    """Run ``unloader`` against ``dy/dt = G·u(t − τ)``; returns the forces per cycle."""
    rng = np.random.default_rng(seed)
    G = np.atleast_2d(G)
    n = G.shape[0]
    y = np.array(y0, float)
    delay = round(TAU / T)
    queue = [np.zeros(n)] * delay
    out = []
    for _ in range(steps):
        read = y + noise * rng.standard_normal(n)
        us, _ = unloader.step(list(read))
        out.append(read)
        if unloader.done:
            break
        queue.append(np.array(us))
        y = y + T * (G @ queue.pop(0))
    return np.array(out)


@pytest.mark.parametrize("y0,g", [(2000.0, 120.0), (-3500.0, 300.0), (40.0, 120.0), (800.0, 40.0)])
def test_for_one_channel_the_ratio_unload_is_the_supervisors_unload(y0, g):
    limits = SafetyLimits()
    old, new = Unloader(y0, limits, T), RatioUnloader([y0], [True], [limits], T)
    y = y0
    delay = [0.0] * round(TAU / T)
    for _ in range(20000):
        u_old, r_old = old.step(y)
        (u_new,), (r_new,) = new.step([y])
        assert (u_new, r_new) == (u_old, r_old)
        assert (new.done, new.outcome) == (old.done, old.outcome)
        if old.done:
            break
        delay.append(u_old)
        y += T * g * delay.pop(0)
    assert old.outcome == "unloaded"
    assert new.record([y]) == old.record(y)


#: four channels along a wing box, neighbours coupled 30 % (as examples/rig.toml)
G4 = np.array([[120, 36, 0, 0], [36, 120, 36, 0], [0, 36, 120, 36], [0, 0, 36, 120]], float)
LOADS = [3000.0, 1500.0, -1000.0, 500.0]


def largest_deviation(y: np.ndarray, y0) -> float:
    y0 = np.asarray(y0, float)
    sigma = (y @ y0) / (y0 @ y0)
    return float(np.abs(y - sigma[:, None] * y0).max())


def test_a_coupled_rig_unloads_every_channel_together_keeping_the_ratios():
    limits = [SafetyLimits()] * 4
    un = RatioUnloader(LOADS, [True] * 4, limits, T, list("abcd"), G=G4)
    y = simulate(un, G4, LOADS, noise=2.0)
    assert un.outcome == "unloaded" and (np.abs(y[-1]) <= 50).all()
    # 1000 kgf/s on the most loaded channel would need 7.6 % of flow there: more than half the
    # unload's 10 % bound, so the ramp is slowed until it fits (room left for the feedback)
    assert un.slowest == 0 and un.rate < 1000.0 / 3000.0 and un.limited_by == "valve flow"
    assert max(abs(f) for f in un.feedforward) == pytest.approx(5.0)
    dev = largest_deviation(y[1:], LOADS)
    assert dev <= 0.01 * 3000, dev                       # within 1 % of the largest load
    assert un.record(list(y[-1]), [1e4] * 4)["largest_deviation"]["kgf"] == pytest.approx(dev, rel=1e-9)


def test_knowing_G_keeps_the_ratios_where_channels_differ_and_couple():
    G = G4 * np.array([0.5, 1.0, 2.0, 1.0])[None, :]    # actuators of different flow gains
    limits = [SafetyLimits()] * 4
    known = RatioUnloader(LOADS, [True] * 4, limits, T, list("abcd"), G=G)
    blind = RatioUnloader(LOADS, [True] * 4, limits, T, list("abcd"))
    d_known = largest_deviation(simulate(known, G, LOADS)[1:], LOADS)
    d_blind = largest_deviation(simulate(blind, G, LOADS)[1:], LOADS)
    assert known.outcome == blind.outcome == "unloaded"
    assert d_known <= 0.01 * 3000 and d_known < 0.5 * d_blind, (d_known, d_blind)
    assert known.gains[0] == pytest.approx(0.02 * 120 / 60) and known.gains[2] == pytest.approx(0.02 * 120 / 240)


def test_an_excluded_channel_holds_and_the_others_unload_keeping_their_ratios():
    limits = [SafetyLimits()] * 4
    active = [True, True, False, True]
    un = RatioUnloader(LOADS, active, limits, T, list("abcd"), G=G4)
    y = simulate(un, G4, LOADS)
    assert un.outcome == "unloaded"
    live = [0, 1, 3]
    assert (np.abs(y[-1, live]) <= 50).all()
    assert math.isnan(un.step(list(y[-1]))[1][2]), "no reference for the excluded channel"
    rec = un.record(list(y[-1]), [1e4] * 4)
    assert rec["channels"]["c"]["unloaded"] is False and rec["largest_deviation"]["channel"] != "c"
    assert largest_deviation(y[1:, live], [LOADS[i] for i in live]) <= 0.01 * 3000


def test_the_rate_is_lowered_until_the_flow_the_ramp_needs_fits_the_valves():
    limits = [SafetyLimits(unload_rate_kgf_per_s=20000.0)] * 4
    un = RatioUnloader(LOADS, [True] * 4, limits, T, list("abcd"), G=G4)
    assert un.limited_by == "valve flow"
    assert max(abs(f) for f in un.feedforward) == pytest.approx(0.5 * limits[0].unload_max_pct)


def test_a_force_that_rises_on_one_channel_ends_the_unload_naming_it():
    limits = [SafetyLimits()] * 2
    un = RatioUnloader([2000.0, 1000.0], [True, True], limits, T, ["a", "b"])
    y = [2000.0, 1000.0]
    for k in range(400):
        un.step(y)
        if un.done:
            break
        y = [y[0] - 1.0, y[1] + 2.0]                     # b goes the wrong way
    assert un.outcome == "force_rising" and un.record(y)["force_rising_channel"] == "b"
