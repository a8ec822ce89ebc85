"""The rig gateway runs a rig experiment: every channel's force in, every channel's command and
reference out per cycle (:class:`gateway.experiments.rig.RigExperiment`), on the example rig
served by ``stand emulate --rig --lockstep`` in its own process. Recorded as any rig run (r.NAME
the reference per channel); each channel's supervisor and the rig's safety act as for
per-channel drivers; an experiment for other channels is refused before anything moves."""
from __future__ import annotations

import json

import numpy as np
import pytest

from gateway import Gateway, GatewayConfig, SafetyLimits, load_run
from gateway.errors import ParameterError
from gateway.experiments import Meander
from gateway.experiments.rig import RigExperiment
from rig.config import load_rig_file

pytestmark = pytest.mark.e2e

NAMES = ["root", "inner", "outer", "tip"]


class HoldAt(RigExperiment):
    """Every channel to its own set point by P feedback through the structure's inverse:
    u = G⁻¹·k·(r − y)."""

    name = "hold-at"

    def __init__(self, names, G, targets_kgf, duration_s: float, k_per_s: float = 4.0) -> None:
        self.names = list(names)
        self.Ginv = np.linalg.inv(np.asarray(G, float))
        self.r = np.asarray(targets_kgf, float)
        self.k = k_per_s
        self._duration = duration_s
        self.begun_with = None

    @property
    def duration_s(self) -> float:
        return self._duration

    def params(self):
        return {"targets_kgf": self.r.tolist(), "k_per_s": self.k}

    def begin_rig(self, y0):
        self.begun_with = list(y0)

    def step_rig(self, t, ys):
        u = self.Ginv @ (self.k * (self.r - np.asarray(ys, float)))
        return np.clip(u, -20, 20).tolist(), self.r.tolist()


def test_a_rig_experiment_drives_every_channel_at_once_and_is_recorded_per_channel(
        tmp_path, start_rig_emulator):
    rig = load_rig_file(start_rig_emulator())
    targets = [1500.0, -800.0, 600.0, 1000.0]
    e = HoldAt(rig.names, rig.G, targets, 3.0)
    with Gateway(GatewayConfig(rig=rig, lockstep=True)) as gw:
        res = gw.run(e, tmp_path / "run", progress=False)
    assert res.status == "complete", res.outcome.message
    assert e.begun_with is not None and len(e.begun_with) == 4
    run = load_run(tmp_path / "run")
    meta = json.loads((tmp_path / "run" / "run.json").read_text())
    assert meta["experiment"]["name"] == "hold-at" and meta["rig"]["driven"] == NAMES
    assert all(c["driven"] for c in meta["rig"]["channels"])
    for name, r in zip(NAMES, targets):
        assert np.all(run.signals[f"r.{name}"] == r), name
        # at its set point (a P loop: the reversal boosts keep it wandering a few tens of kgf)
        assert abs(np.mean(run.signals[f"y.{name}"][-500:]) - r) < 60, name
        assert np.any(run.signals[f"u.{name}"] != 0), name
    # one channel of it reads as a one-channel run with its own reference
    one = load_run(tmp_path / "run", channel="outer")
    assert np.all(one.r == 600.0)


def test_a_channel_of_a_rig_experiment_trips_its_own_supervisor_and_the_whole_rig_holds(
        tmp_path, start_rig_emulator):
    rig = load_rig_file(start_rig_emulator())
    # tip cannot reach its reference (a too-low gain): its error detector trips, every channel holds
    e = HoldAt(rig.names, rig.G, [0.0, 0.0, 0.0, 3000.0], 5.0, k_per_s=0.05)
    limits = SafetyLimits(error_limit_kgf=2000.0, error_time_s=0.1)
    with Gateway(GatewayConfig(rig=rig, lockstep=True, limits=limits)) as gw:
        res = gw.run(e, tmp_path / "run", progress=False)
    assert res.status == "stopped" and res.reason == "error_limit", res.outcome.message
    assert res.outcome.message.startswith("channel tip:") and "every channel held" in res.outcome.message
    run = load_run(tmp_path / "run")
    assert len(run) < 0.2 / 0.002 + 5
    for name in NAMES:
        assert run.signals[f"u.{name}"][-1] == 0.0, name
    meta = json.loads((tmp_path / "run" / "run.json").read_text())
    assert meta["safety"]["rig"]["acted_on"] == "every channel"


def test_a_rig_experiment_for_other_channels_or_with_channel_is_refused_before_anything_moves(
        tmp_path, start_rig_emulator):
    rig = load_rig_file(start_rig_emulator())
    swapped = ["inner", "root", "outer", "tip"]
    with Gateway(GatewayConfig(rig=rig, lockstep=True)) as gw:
        with pytest.raises(ParameterError, match="the experiment is for the channels inner, root"):
            gw.run(HoldAt(swapped, rig.G, [0] * 4, 1.0), tmp_path / "a", progress=False)
        with pytest.raises(ParameterError, match="leave --channel out"):
            gw.run(HoldAt(rig.names, rig.G, [0] * 4, 1.0), tmp_path / "b", progress=False,
                   channels=["root"])
        # nothing was recorded, and a per-channel experiment still runs after the refusals
        assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
        res = gw.run(Meander(5, 1, 1), tmp_path / "c", progress=False, channels=["tip"])
    assert res.status == "complete", res.outcome.message
