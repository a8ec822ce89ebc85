"""The whole rig workflow on a second rig, each step a ``stand`` command in its own process
against ``stand emulate --rig --lockstep`` (tests/support/rig3.toml: 3 channels on one bus, the
middle one coupled against its neighbours 25 % and 20 %, the outer two 10 %, each its own g, τ,
trend, one channel without a reversal boost):

campaign --rig --simultaneous → estimate --save → diagnose --rig-model --stepwise --save →
design → load --rig.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rig.config import load_rig_file

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

RIG3 = Path(__file__).resolve().parent / "support" / "rig3.toml"
CASES = """case,left,centre,right
1,800,1500,600
2,4000,3000,3500
3,1200,4500,900
4,5000,1000,4200
5,700,3800,1500
6,3000,1200,4800
"""


def stand(*args, timeout: float = 900) -> str:
    done = subprocess.run([sys.executable, "-m", "stand", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)
    assert done.returncode == 0, f"stand {' '.join(map(str, args))}:\n{done.stderr}\n{done.stdout}"
    return done.stdout


def test_the_whole_workflow_on_a_second_rig_identifies_G_and_loads_every_channel(
        tmp_path, channel, start_rig_emulator):
    rig = start_rig_emulator(RIG3.read_text().replace("udp_loopback:rig3-", f"udp_loopback:{channel}-"))
    truth = load_rig_file(rig).G
    camp = tmp_path / "campaign"
    stand("campaign", "--rig", rig, "--lockstep", "--simultaneous", "--duration-s", 90, "--emulated",
          "--no-progress", "--out", camp)
    # G within 5 % of the truth's diagonal (the goal), every entry
    doc = json.loads(stand("estimate", camp, "--json", "--save", tmp_path / "rig-model.toml"))
    G = np.array(doc["G"], float)
    rel = np.abs(G - truth) / np.minimum.outer(np.diag(truth), np.diag(truth))
    assert rel.max() < 0.05, np.round(G, 2)
    stand("diagnose", camp / "01-simultaneous", "--rig-model", tmp_path / "rig-model.toml", "--stepwise",
          "--candidates", "reversal,lag", "--save", tmp_path / "model.toml", "--no-progress")
    stand("design", tmp_path / "model.toml", "-o", tmp_path / "decoupled.toml")
    (tmp_path / "cases.csv").write_text(CASES)
    report = json.loads(stand("load", tmp_path / "cases.csv", "--rig", rig, "--controller",
                              tmp_path / "decoupled.toml", "--rate", 2500, "--repeat", 2, "--lockstep",
                              "--json", "--no-progress", "--out", tmp_path / "load"))
    assert report["end_reason"] == "complete" and set(report["channels"]) == {"left", "centre", "right"}
    # the worst channel of the last pass within the figures, no extra cycle on any
    pv = report["peak_valley_error_pct"]
    assert pv["p95"] <= 0.5 and pv["max"] <= 1.0, report
    assert all(f["extra_cycles"] == 0 for f in report["channels"].values()), report
    assert report["ratio_error_pct"] <= 1.0, report
