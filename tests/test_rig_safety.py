"""A trip on one channel of a rig acts on every channel: hold all, or unload all keeping the load
ratios (4 channels on 2 real loopback buses, one emulator process per channel, lockstep). A
channel whose stand dies first is named and held apart while the others unload."""
from __future__ import annotations

import dataclasses
import json
import math
import signal
import time

import numpy as np
import pytest

from dbc import profile as P
from gateway import Gateway, GatewayConfig, SafetyLimits, load_run
from tests.support.faults import Const
from tests.support.rig_channels import FOUR, ratio_deviation, rpdo_words, start_channels, write_rig

pytestmark = pytest.mark.e2e

#: the loads at the start: a runs toward its limit, the others hold theirs
LOADS = (2000.0, 1500.0, -1000.0, 500.0)
#: the stated bound on the deviation from the ratios during an unload of these uncoupled,
#: equal channels, as a share of the largest load (measured 0.6 %: the command in flight on the
#: tripping channel when the others start down)
RATIO_BOUND = 0.02


def loaded_rig(tmp_path, start_emulator, limit_a: float = 2300.0):
    chans = [dataclasses.replace(c, initial_kgf=k) for c, k in zip(FOUR, LOADS)]
    chans[0] = dataclasses.replace(chans[0], force_limit_kgf=limit_a)
    rig = write_rig(tmp_path / "rig.toml", chans)
    return rig, chans, start_channels(start_emulator, rig, chans)


def forces(run) -> np.ndarray:
    return np.column_stack([run.signals[f"y.{n}"] for n in "abcd"])


def test_a_force_limit_trip_on_one_channel_unloads_every_channel_keeping_the_ratios(tmp_path, start_emulator):
    rig, _, _ = loaded_rig(tmp_path, start_emulator)
    config = GatewayConfig(rig=rig, lockstep=True, limits=SafetyLimits(force_action="unload"))
    with Gateway(config) as gw:
        result = gw.run(Const(5.0, 6.0), tmp_path / "run", progress=False, channels=["a"])
    assert (result.status, result.reason) == ("stopped", "force_limit")
    meta = json.loads((tmp_path / "run" / "run.json").read_text())
    safety = meta["safety"]
    assert safety["channel"] == "a" and safety["action"] == "unload"
    unload = safety["unload"]
    assert unload["outcome"] == "unloaded" and unload["slowest_channel"] == "a"
    assert set(unload["channels"]) == set("abcd") and all(c["unloaded"] for c in unload["channels"].values())
    run = load_run(tmp_path / "run")
    y = forces(run)
    assert (np.abs(y[-1]) <= 50).all(), y[-1]
    # every channel unloaded together: the ratios of the trip kept all the way down
    trip = int(np.flatnonzero(np.abs(y[:, 0]) > 2300)[0])
    y0 = y[trip]
    np.testing.assert_allclose([c["from_kgf"] for c in unload["channels"].values()], y0)
    dev = ratio_deviation(y[trip + 1:], y0)
    largest = np.abs(dev).max()
    assert largest <= RATIO_BOUND * np.abs(y0).max(), largest
    stated = unload["largest_deviation"]
    assert stated["channel"] in "abcd" and stated["kgf"] == pytest.approx(largest, rel=0.05, abs=1.0)
    assert stated["pct_of_largest_load"] <= 100 * RATIO_BOUND
    assert "keeping the load ratios" in result.outcome.message and "largest deviation" in result.outcome.message
    # at the same time: each channel's share of the load went down together, none alone first
    share = y[trip:, :] / y0
    half = [int(np.argmax(share[:, i] < 0.5)) for i in range(4)]
    assert max(half) - min(half) <= 0.1 / rig.period_s, half      # within 0.1 s of each other
    # the commands: every valve ACTIVE during the unload, then HOLD with zero setpoint
    for c in FOUR:
        words = rpdo_words(tmp_path / "run" / f"capture-{c.bus}.log", c.valve_id)
        assert words[-1][1:] == (int(P.CW_HOLD), 0)


@pytest.mark.slow
def test_a_force_limit_trip_on_one_channel_holds_every_channel(tmp_path, start_emulator):
    rig, _, _ = loaded_rig(tmp_path, start_emulator)
    with Gateway(GatewayConfig(rig=rig, lockstep=True)) as gw:
        result = gw.run(Const(5.0, 6.0), tmp_path / "run", progress=False, channels=["a"])
    assert (result.status, result.reason) == ("stopped", "force_limit")
    meta = json.loads((tmp_path / "run" / "run.json").read_text())
    assert meta["safety"]["channel"] == "a" and meta["safety"]["rig"]["action"] == "hold"
    assert "every channel held" in meta["end_message"]
    run = load_run(tmp_path / "run")
    last = len(run) - 1
    assert all(run.signals[f"u.{n}"][last] == 0 for n in "abcd")
    # the trip's cycle: every valve got HOLD with zero setpoint, the first one within a cycle
    # of the offending reading, and nothing but HOLD after
    sent = {c.name: rpdo_words(tmp_path / "run" / f"capture-{c.bus}.log", c.valve_id) for c in FOUR}
    first_hold = {}
    for name, words in sent.items():
        active = [k for k, (_, cw, _) in enumerate(words) if cw == int(P.CW_ACTIVE)]
        after = words[active[-1] + 1:]
        assert after and all((cw, sp) == (int(P.CW_HOLD), 0) for _, cw, sp in after), name
        first_hold[name] = after[0][0]
    assert max(first_hold.values()) - min(first_hold.values()) < 0.05
    y = forces(run)
    assert abs(y[-1, 0]) > 2300 and np.allclose(y[-1, 1:], LOADS[1:], atol=30)


@pytest.mark.slow
def test_a_channel_whose_stand_dies_is_named_and_held_while_the_others_unload(tmp_path, start_emulator):
    rig, _, emus = loaded_rig(tmp_path, start_emulator, limit_a=9000.0)
    killed: list[float] = []

    def kill_c(t: float) -> None:
        if t >= 0.5 and not killed:
            killed.append(time.time())
            emus["c"].signal(signal.SIGKILL)

    config = GatewayConfig(rig=rig, lockstep=True, fault_action="unload")
    with Gateway(config) as gw:
        result = gw.run(Const(0.0, 8.0), tmp_path / "run", progress=False, channels=["a"],
                        on_progress=kill_c)
    assert result.status == "stopped" and result.reason in ("heartbeat_lost", "no_answer_to_sync")
    meta = json.loads((tmp_path / "run" / "run.json").read_text())
    safety = meta["safety"]
    assert safety["channel"] == "c" and safety["action"] == "unload"
    assert [e["channel"] for e in safety["rig"]["excluded"]] == ["c"]
    unload = safety["unload"]
    assert unload["outcome"] == "unloaded", unload
    assert {n: c["unloaded"] for n, c in unload["channels"].items()} == \
        {"a": True, "b": True, "c": False, "d": True}
    assert unload["largest_deviation"]["channel"] in ("a", "b", "d")
    assert "c excluded" in result.outcome.message and "channel c" in result.outcome.message
    run = load_run(tmp_path / "run")
    y = forces(run)
    live = [0, 1, 3]
    assert (np.abs(y[-1, live]) <= 50).all(), y[-1]
    y0 = np.array([c["from_kgf"] for n, c in unload["channels"].items() if n != "c"])
    trip = int(np.flatnonzero(np.all(np.isclose(y[:, live], y0), axis=1))[-1])
    dev = ratio_deviation(y[trip + 1:, live], y0)
    assert np.abs(dev).max() <= RATIO_BOUND * np.abs(y0).max()
    assert unload["largest_deviation"]["kgf"] == pytest.approx(np.abs(dev).max(), rel=0.05, abs=1.0)
    # c's valve got HOLD (zero flow) from the trip on; it had no answer to give
    words = rpdo_words(tmp_path / "run" / "capture-can1.log", 1)
    assert words[-1][1:] == (int(P.CW_HOLD), 0)
    assert math.isfinite(killed[0])
