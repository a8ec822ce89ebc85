"""``stand demo --rig``: the example rig end to end from a clone — ``stand emulate --rig`` as a
real separate process on private loopback buses, the rig gateway, a meander on one channel,
every channel recorded, the column of G estimated and printed beside the rig's truth."""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys

import numpy as np
import pytest

from core.errors import ParameterError
from rig.config import RigError, load_rig_file
from stand.commands.demo import demo_rig
from tests.support.rig import EXAMPLE_RIG

pytestmark = pytest.mark.e2e


def stand(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    res = subprocess.run([sys.executable, "-m", "stand", *args], capture_output=True, text=True,
                         timeout=timeout)
    assert "Traceback" not in res.stdout + res.stderr, res.stderr
    return res


def column(text: str, name: str) -> dict[str, tuple[float, float]]:
    """The printed column of G: row name -> (estimated, half-width of its interval)."""
    block = text.split(f"column {name}", 1)[1].split("τ", 1)[0]
    return {m[1]: (float(m[2]), float(m[3]))
            for m in re.finditer(r"^\s+(\w+)\s+(-?[\d.]+) ±([\d.]+)\s", block, re.M)}


def swings(text: str, name: str) -> dict[str, float]:
    """The printed force change per half period of the run driven on ``name``, kgf."""
    block = text.split(f"on {name}: how far each force moved", 1)[1].split("(peak to peak", 1)[0]
    return {m[1]: float(m[3]) for m in re.finditer(r"^\s+(\w+)\s+\w+\s+(\d+) kgf\s+(\d+) kgf", block, re.M)}


@pytest.mark.slow
def test_the_rig_demo_runs_the_example_rig_and_finds_the_driven_column_of_G(tmp_path):
    out = tmp_path / "demo"
    res = stand("demo", "--rig", "--out", str(out), "--cycles", "3")
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    run = out / "root"
    for f in ("run.json", "signals.parquet", "capture-can0.log", "capture-can1.log", "truth.json"):
        assert (run / f).stat().st_size > 0, f
    assert (out / "forces.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the demo ran on buses of its own, never the file's
    specs = [b.spec for b in load_rig_file(out / "rig.toml").buses]
    assert all(s.startswith("udp_loopback:demo-") for s in specs), specs
    meta = json.loads((run / "run.json").read_text())
    assert [b["spec"] for b in meta["rig"]["buses"]] == specs
    assert meta["rig"]["driven"] == ["root"] and meta["status"] == "complete"
    # every channel recorded, each bus captured at its own channels' nodes
    truth = json.loads((run / "truth.json").read_text())
    names = truth["channels"]
    G = np.array(truth["G"])
    assert names == ["root", "inner", "outer", "tip"]
    for bus in ("can0", "can1"):
        ids = {int(line.split()[2].split("#")[0], 16) for line in
               (run / f"capture-{bus}.log").read_text().splitlines()[:2000]}
        assert {0x182, 0x184, 0x201, 0x203} <= ids, (bus, sorted(map(hex, ids)))
    # the printed column against the rig's truth: within 3 % of root's own g, inside 4 intervals
    printed = column(res.stdout, "root")
    assert list(printed) == names
    for i, n in enumerate(names):
        est, half = printed[n]
        assert abs(est - G[i, 0]) <= 0.03 * G[0, 0], (n, est, G[i, 0])
        assert abs(est - G[i, 0]) <= 4 * half + 0.02, (n, est, half, G[i, 0])
    # the neighbour's force moved by its coupling, the far channels' did not
    moved = swings(res.stdout, "root")
    u0, period = 5.0, 4.0
    assert moved["inner"] >= 0.9 * G[1, 0] * u0 * period / 2, moved
    assert moved["outer"] < 20 and moved["tip"] < 20, moved
    assert "x real time" in res.stdout and "physical check" in res.stdout


def args(**given) -> argparse.Namespace:
    base = dict(rig="example", channel=None, every_channel=False, real_time=False, config=None,
                set=None, bus=None, amplitude_pct=5.0, period_s=4.0, cycles=5)
    return argparse.Namespace(**{**base, **given})


def test_the_demo_puts_a_rig_on_interfaces_of_its_own_never_the_files(tmp_path):
    text = EXAMPLE_RIG.read_text().replace('"udp_loopback:rig-can0"', '"socketcan:can0"') \
                                  .replace('"udp_loopback:rig-can1"', '"socketcan:can1"')
    path = tmp_path / "bench.toml"
    path.write_text(text)
    rig, driven = demo_rig(args(rig=str(path)))
    assert [b.spec.split(":")[0] for b in rig.buses] == ["udp_loopback"] * 2
    assert driven == ["root"]
    rig, driven = demo_rig(args(rig=str(path), every_channel=True))
    assert driven == ["root", "inner", "outer", "tip"]


@pytest.mark.parametrize("given,words", [
    ({"bus": "udp_loopback:x"}, "leave out --bus"),
    ({"set": ["g=100"]}, "leave out --set"),
    ({"channel": ["nope"]}, "no channel 'nope'; the rig has: root, inner, outer, tip"),
    ({"channel": ["tip", "tip"]}, "named twice"),
    ({"channel": ["tip"], "every_channel": True}, "not both"),
    ({"cycles": 0}, "1-1000 periods"),
])
def test_a_rig_demo_with_a_mistake_is_refused_before_anything_starts(given, words):
    with pytest.raises((ParameterError, RigError), match=re.escape(words)):
        demo_rig(args(**given))


def test_the_rig_options_without_rig_are_refused_on_the_command_line():
    res = stand("demo", "--channel", "root", timeout=60)
    assert res.returncode == 2
    assert "--channel is for a rig: add --rig" in res.stderr
    res = stand("demo", "--rig", str(EXAMPLE_RIG.parent / "missing.toml"), timeout=60)
    assert res.returncode == 2 and "missing.toml" in res.stderr
