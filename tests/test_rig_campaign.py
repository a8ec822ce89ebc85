"""``stand campaign --rig``: the rig's identification run through the rig gateway against ``stand
emulate --rig --lockstep`` (the example rig: 4 channels, neighbours coupled 30 %), written so
that ``stand estimate DIR`` reads it; and the plans the rig's G says would swing a force too far
are refused before anything is opened."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from rig.config import load_rig_file
from tests.support.rig import EXAMPLE_RIG

NAMES = ["root", "inner", "outer", "tip"]


def stand(*args, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "stand", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)


@pytest.mark.e2e
@pytest.mark.slow
def test_a_per_column_rig_campaign_gives_every_column_of_G(tmp_path, start_rig_emulator):
    rig = start_rig_emulator()
    out = tmp_path / "campaign"
    done = stand("campaign", "--rig", rig, "--lockstep", "--meander-period-s", 4, "--cycles", 2,
                 "--emulated", "--no-progress", "--out", out)
    assert done.returncode == 0, done.stderr + done.stdout
    doc = json.loads((out / "rig-campaign.json").read_text())
    assert doc["status"] == "complete" and [r["driven"] for r in doc["runs"]] == [[n] for n in NAMES]
    for k, name in enumerate(NAMES, start=1):
        meta = json.loads((out / f"{k:02d}-column-{name}" / "run.json").read_text())
        assert meta["rig"]["driven"] == [name] and meta["experiment"]["name"] == "meander"
        assert (out / f"{k:02d}-column-{name}" / "truth.json").is_file()
    est = stand("estimate", out, "--json")
    assert est.returncode == 0, est.stderr
    G = np.array(json.loads(est.stdout)["G"], float)
    truth = load_rig_file(rig).G
    # the columns of a 2-reversal meander each: within 1 % of the diagonal (measured 0.05 %)
    assert np.max(np.abs(G - truth) / np.diag(truth)[None, :]) < 0.01, np.round(G, 2)


@pytest.mark.e2e
def test_a_rig_campaign_with_its_own_emulator_runs_on_private_buses_and_stops_it(tmp_path):
    from tests.support.rig_channels import sniff
    out = tmp_path / "campaign"
    done = stand("campaign", "--rig", EXAMPLE_RIG, "--with-emulator", "--meander-period-s", 4,
                 "--cycles", 2, "--no-progress", "--out", out)
    assert done.returncode == 0, done.stderr + done.stdout
    ran = load_rig_file(out / "rig.toml")          # the rig as run: the example on private buses
    example = load_rig_file(EXAMPLE_RIG)
    assert [b.spec for b in ran.buses] != [b.spec for b in example.buses]
    assert all(b.spec.startswith("udp_loopback:campaign-") for b in ran.buses)
    np.testing.assert_array_equal(ran.G, example.G)
    assert all((out / f"{k:02d}-column-{n}" / "truth.json").is_file() for k, n in enumerate(NAMES, 1))
    est = stand("estimate", out, "--json")
    assert est.returncode == 0, est.stderr
    G = np.array(json.loads(est.stdout)["G"], float)
    assert np.max(np.abs(G - example.G) / np.diag(example.G)[None, :]) < 0.01, np.round(G, 2)
    for bus in ran.buses:                           # the campaign stopped its emulator
        listener = sniff(bus.spec)
        try:
            assert listener.recv(0.5) is None, f"{bus.name}: something still sends"
        finally:
            listener.shutdown()


def test_a_rig_campaign_that_would_swing_a_force_too_far_is_refused_before_anything_opens(tmp_path, capsys):
    from stand.cli import main
    rig = tmp_path / "rig.toml"
    rig.write_text(EXAMPLE_RIG.read_text().replace("udp_loopback:rig-", "udp_loopback:nobody-"))
    out = tmp_path / "never"
    rc = main(["campaign", "--rig", str(rig), "--simultaneous", "--lockstep", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "channel outer would swing ±4641 kgf" in err and "Lower --amplitude-pct to 2.9" in err, err
    rc = main(["campaign", "--rig", str(rig), "--force-limit", "5000", "--out", str(out)])
    assert rc == 2 and "--force-limit: not with --rig" in capsys.readouterr().err
    rc = main(["campaign", "--simultaneous", "--out", str(out)])
    assert rc == 2 and "give --rig RIG.toml too" in capsys.readouterr().err
    rc = main(["campaign", "--rig", str(rig), "--cycles", "1", "--out", str(out)])
    assert rc == 2 and "needs two reversals" in capsys.readouterr().err   # stand estimate would
    assert not out.exists()
