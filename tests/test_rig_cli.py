"""``stand estimate`` and ``stand diagnose --rig-model`` on rig runs written in the run format:
G with intervals, τ and Δ per channel, the physical check, the rig model file, and user
mistakes as one line."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from analysis.rig.periods import separating_periods
from analysis.rig.synthetic import rig_meander, rig_truth, write_rig_run
from plant.config import load_rig_model
from tests.support.rig_models import CHANNELS3, chain_rig


def stand(*args, timeout=300):
    res = subprocess.run([sys.executable, "-m", "stand", *map(str, args)], capture_output=True,
                         text=True, timeout=timeout)
    assert "Traceback" not in res.stderr + res.stdout, res.stderr
    return res


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A simultaneous run of the 3-channel chain (periods 8, 10, 12 s, 72 s) and one with two
    channels on the same period (in phase)."""
    rig = chain_rig()
    root = tmp_path_factory.mktemp("rig-runs")
    good = write_rig_run(rig_meander(rig, [5.0] * 3, separating_periods(3, 8.0), 72.0, seed=11),
                         root / "sim", rig_truth(rig))
    bad = write_rig_run(rig_meander(rig, [5.0] * 3, [8.0, 8.0, 12.0], 48.0, seed=12),
                        root / "same-periods")
    return rig, good, bad


def test_stand_estimate_prints_G_with_intervals_tau_delta_and_the_physical_check(runs):
    rig, good, _ = runs
    res = stand("estimate", good)
    assert res.returncode == 0, res.stderr
    out = res.stdout
    assert "rig estimate: 3 channels, simultaneous meanders" in out
    assert "±" in out and "left" in out and "right" in out
    assert "physical check: physical" in out and "smallest eigenvalue" in out
    assert "truth (truth.json, not used)" in out


def test_stand_estimate_json_gives_G_rows_their_intervals_channels_tau_delta_physical(runs):
    rig, good, _ = runs
    res = stand("estimate", good, "--json")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["channels"] == rig.names
    G = np.array(doc["G"])
    ci = np.array(doc["G_ci"])
    assert G.shape == (3, 3) and ci.shape == (3, 3, 2)
    assert np.all(np.abs(G - rig.G) <= 0.002 * np.diag(rig.G)[None, :])
    assert np.all((ci[..., 0] <= G) & (G <= ci[..., 1]))
    assert np.allclose(doc["tau_s"], [t for t, _, _ in CHANNELS3], atol=0.0011)
    assert np.allclose(doc["delta_kgf_s"], [d for _, d, _ in CHANNELS3], atol=0.2)
    assert doc["physical"]["physical"] is True and doc["physical"]["checked"] is True


@pytest.mark.slow
def test_estimate_save_then_diagnose_one_channel_writes_the_rig_model_it_arrives_at(runs, tmp_path):
    rig, good, _ = runs
    first, second = tmp_path / "rig.toml", tmp_path / "rig2.toml"
    assert stand("estimate", good, "--save", first).returncode == 0
    start = load_rig_model(first)
    assert start.names == rig.names and [m.spec for m in start.channels] == ["base+reversal"] * 3
    res = stand("diagnose", good, "--rig-model", first, "--channel", "mid", "--stepwise",
                "--candidates", "reversal,lag", "--save", second, "--jobs", "1", "--no-progress")
    assert res.returncode == 0, res.stderr
    assert "mid" in res.stdout and "adequate" in res.stdout
    arrived = load_rig_model(second)
    assert arrived.channels[1].spec == "base+reversal"
    assert arrived.G[1, 1] == pytest.approx(100.0, rel=0.002)
    assert np.array_equal(arrived.G[0], start.G[0])            # the other rows as they were


@pytest.mark.parametrize("args, message", [
    (["--rig-model", "{rig}", "--channel", "nosuch"], "--channel nosuch: the rig model"),
    pytest.param(["--rig-model", "{rig}", "--rounds", "0"], "--rounds 0 is out of range",
                 marks=pytest.mark.slow),
    pytest.param(["--rig-model", "{rig}", "--jobs", "2", "--scheduler", "tcp://127.0.0.1:9"],
                 "give one", marks=pytest.mark.slow),
])
def test_diagnose_mistakes_with_a_rig_are_one_line(runs, tmp_path, args, message):
    rig, good, _ = runs
    path = tmp_path / "rig.toml"
    from plant.config import rig_model_to_toml
    path.write_text(rig_model_to_toml(rig))
    res = stand("diagnose", good, *[a.format(rig=path) for a in args])
    assert res.returncode == 2 and message in res.stderr, res.stderr


@pytest.mark.slow
def test_diagnose_channel_without_a_rig_model_reads_that_channel_alone(runs):
    """Without --rig-model, --channel NAME reads one channel of a rig run as a one-channel run:
    the others' meanders move it through the structure and no effect of its own explains that
    (with the rig model the same channel is adequate: the tests above), and a name the run
    lacks is one line listing the channels."""
    _, good, _ = runs
    res = stand("diagnose", good, "--channel", "left", "--no-progress")
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("verdict: UNEXPLAINED"), res.stdout
    res = stand("diagnose", good, "--channel", "nosuch", "--no-progress")
    assert res.returncode == 2 and "nosuch" in res.stderr and "left" in res.stderr, res.stderr


def test_estimate_refuses_a_run_that_cannot_tell_two_columns_apart(runs):
    _, _, bad = runs
    res = stand("estimate", bad)
    assert res.returncode == 2
    assert "cannot tell column left of G apart" in res.stderr and "mid" in res.stderr


def test_estimate_refuses_rig_runs_mixed_with_one_channel_data(runs, tmp_path):
    _, good, _ = runs
    table = tmp_path / "one.csv"
    table.write_text("t,u,y\n" + "\n".join(f"{i * 0.002},5,{i}" for i in range(100)))
    res = stand("estimate", good, table)
    assert res.returncode == 2 and "give the runs of one rig together" in res.stderr
    res = stand("diagnose", table, "--rig-model", "x.toml")
    assert res.returncode == 2 and "--rig-model needs rig runs" in res.stderr
