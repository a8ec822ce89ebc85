"""The rig gateway on a coupled rig: the example rig (4 channels along a wing box on 2 buses,
neighbours coupled 30 %, each channel its own g, τ, Δ and reversal boost) served by
``stand emulate --rig`` in one process, lockstep. A meander on one channel moves its
neighbours by its column of G; a trip on one channel unloads all keeping the ratios through
the coupling, with G known to the unload."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from gateway import Gateway, GatewayConfig, SafetyLimits, load_run
from gateway.experiments import Meander
from rig.config import load_rig_file
from tests.support.faults import Const
from tests.support.rig import example_rig_text
from tests.support.rig_channels import ratio_deviation

pytestmark = pytest.mark.e2e

NAMES = ["root", "inner", "outer", "tip"]
#: the example rig's G: K·diag(c/A), K neighbours 30 %, c/A = 12, 10, 14, 11
G = np.array([[10, 3, 0, 0], [3, 10, 3, 0], [0, 3, 10, 3], [0, 0, 3, 10]], float) * \
    np.array([12.0, 10.0, 14.0, 11.0])[None, :]


def loaded(text: str, loads, root_limit: float | None = None) -> str:
    """The example rig with each channel's plant starting at its load, and root's force limit."""
    blocks = text.split("[[channel]]")
    for k, load in enumerate(loads):
        body = blocks[k + 1]
        cut = body.find("\n# The structure")
        cut = len(body) if cut < 0 else cut
        blocks[k + 1] = body[:cut].rstrip() + f"\n[channel.plant.initial]\nforce_kgf = {load}\n\n" + body[cut:]
    text = "[[channel]]".join(blocks)
    if root_limit is not None:
        text = text.replace("force_limit_kgf = 9000", f"force_limit_kgf = {root_limit}", 1)
    return text


@pytest.mark.slow
def test_a_meander_on_one_channel_of_a_coupled_rig_moves_its_neighbours_by_its_column_of_G(
        tmp_path, channel, start_rig_emulator):
    path = start_rig_emulator(example_rig_text(channel))
    rig = load_rig_file(path)
    np.testing.assert_allclose(rig.G, G)
    with Gateway(GatewayConfig(rig=rig, lockstep=True)) as gw:
        result = gw.run(Meander(5, 6, 3), tmp_path / "run", progress=False, channels=["root"])
    assert result.status == "complete", result.outcome.message
    run = load_run(tmp_path / "run")
    assert run.channels == NAMES
    y = {n: run.signals[f"y.{n}"] for n in NAMES}
    assert np.ptp(y["inner"]) > 100 and np.ptp(y["tip"]) < 60      # the neighbour moves, not the far end
    est = subprocess.run([sys.executable, "-m", "stand", "estimate", str(tmp_path / "run"), "--json"],
                         capture_output=True, text=True, timeout=300)
    assert est.returncode == 0, est.stderr
    column = np.array([row[0] for row in json.loads(est.stdout)["G"]])
    np.testing.assert_allclose(column, G[:, 0], atol=0.03 * G[0, 0])


def test_a_trip_on_one_channel_of_a_coupled_rig_unloads_all_keeping_the_ratios(
        tmp_path, channel, start_rig_emulator):
    loads = (2000.0, 1500.0, -1000.0, 500.0)
    path = start_rig_emulator(loaded(example_rig_text(channel), loads, root_limit=2300))
    rig = load_rig_file(path)
    config = GatewayConfig(rig=rig, lockstep=True, limits=SafetyLimits(force_action="unload"))
    with Gateway(config) as gw:
        result = gw.run(Const(5.0, 6.0), tmp_path / "run", progress=False, channels=["root"])
    assert (result.status, result.reason) == ("stopped", "force_limit"), result.outcome.message
    meta = json.loads((tmp_path / "run" / "run.json").read_text())
    unload = meta["safety"]["unload"]
    assert meta["safety"]["channel"] == "root" and unload["outcome"] == "unloaded", unload
    # G known: each channel's gain for the same bandwidth, the ramp's flow through G⁻¹
    gains = {n: c["gain_pct_per_kgf"] for n, c in unload["channels"].items()}
    assert gains == pytest.approx({n: 0.02 * 120 / G[i, i] for i, n in enumerate(NAMES)})
    assert any(abs(c["feedforward_pct"]) > 0.1 for c in unload["channels"].values())
    run = load_run(tmp_path / "run")
    y = np.column_stack([run.signals[f"y.{n}"] for n in NAMES])
    assert (np.abs(y[-1]) <= 50).all(), y[-1]
    y0 = np.array([c["from_kgf"] for c in unload["channels"].values()])
    trip = int(np.flatnonzero(np.all(np.isclose(y, y0), axis=1))[-1])
    largest = np.abs(ratio_deviation(y[trip + 1:], y0)).max()
    stated = unload["largest_deviation"]
    assert stated["kgf"] == pytest.approx(largest, rel=0.05, abs=1.0)
    print(f"coupled rig: unloaded in {unload['duration_s']:.2f} s, largest deviation "
          f"{largest:.1f} kgf on {stated['channel']} ({stated['pct_of_largest_load']:.2f} % of the "
          f"largest load) at {stated['at_s']:.2f} s")
    # stated bound: 2 % of the largest load (measured 31 kgf, 1.4 %: the tripping channel's
    # command in flight and its reversal boost in the first 0.4 s; 54 kgf with a sharp start)
    assert largest <= 0.02 * np.abs(y0).max(), largest
