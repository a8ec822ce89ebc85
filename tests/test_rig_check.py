"""``stand rig check``: the rig, its buses' load and its structure, and every problem found
before anything moves (rig.check); the example rig passes."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from rig.check import check_rig
from rig.config import load_rig_file, rig_from_mapping
from tests.support.rig import EXAMPLE_RIG


def stand(*args: str) -> subprocess.CompletedProcess:
    res = subprocess.run([sys.executable, "-m", "stand", *args], capture_output=True, text=True,
                         timeout=60)
    assert "Traceback" not in res.stdout + res.stderr, res.stderr
    return res


def rig(channels: int = 2, buses: int = 1, **extra) -> dict:
    return {"bus": [{"name": f"can{b}", "spec": f"udp_loopback:chk{b}"} for b in range(buses)],
            "channel": [{"name": f"c{i}", "bus": f"can{i % buses}", "valve_id": 2 * i + 1,
                         "dynamometer_id": 2 * i + 2} for i in range(channels)], **extra}


def test_the_example_rig_passes_with_its_two_buses_and_a_physical_structure():
    result = check_rig(load_rig_file(EXAMPLE_RIG))
    assert result.ok, result.problems
    assert [b.channels for b in result.budgets] == [["root", "inner"], ["outer", "tip"]]
    assert result.structure.physical and result.rig.structure_from == "K"
    assert result.to_dict()["structure"]["K"][0] == [10.0, 3.0, 0.0, 0.0]
    G = result.rig.G
    # neighbours coupled 30 % of the driving channel's own gain, two away not at all
    assert np.allclose(G[[0, 1, 2], [1, 2, 3]], 0.3 * np.diag(G)[[1, 2, 3]])
    assert G[0, 2] == G[0, 3] == G[1, 3] == 0.0
    assert len(set(np.diag(G))) == 4                     # each channel its own g


def test_the_example_rig_check_command_prints_the_rig_and_exits_0():
    res = stand("rig", "check", str(EXAMPLE_RIG))
    assert res.returncode == 0, res.stdout
    for line in ("can0  udp_loopback:rig-can0  1 Mbit/s  classic  33.0 %  root, inner",
                 "problems: none", "physical (asymmetry"):
        assert line in res.stdout
    doc = json.loads(stand("rig", "check", str(EXAMPLE_RIG), "--json").stdout)
    assert doc["rig"] == "wing box, 4 channels" and doc["problems"] == []
    assert [(b["name"], b["bitrate"], b["channels"]) for b in doc["buses"]] == [
        ("can0", 1_000_000, ["root", "inner"]), ("can1", 1_000_000, ["outer", "tip"])]
    assert doc["buses"][0]["load_pct"] == pytest.approx(33.01, abs=0.01)


def test_a_bus_over_its_budget_fails_the_check_with_what_would_fit(tmp_path):
    path = tmp_path / "big.toml"
    lines = ['[[bus]]\nname = "can0"\nspec = "udp_loopback:big0"\n']
    lines += [f'[[channel]]\nname = "c{i}"\nbus = "can0"\nvalve_id = {2 * i + 1}\n'
              f'dynamometer_id = {2 * i + 2}\n' for i in range(6)]
    path.write_text("\n".join(lines))
    res = stand("rig", "check", str(path))
    assert res.returncode == 1
    assert ("bus can0: 6 channel(s) at 500 Hz need 0.93 Mbit/s of 1.00 Mbit/s (classic CAN, 93 %, "
            "the limit is 70 %); at most 4 channel(s) per bus at 500 Hz, or a period of 2.7 ms"
            in res.stdout)
    doc = json.loads(stand("rig", "check", str(path), "--json").stdout)
    assert doc["buses"][0]["load_pct"] > 90 and len(doc["problems"]) == 1


def test_a_structure_no_stiffness_can_give_fails_the_check_with_the_reason(tmp_path):
    text = EXAMPLE_RIG.read_text()
    bad = text.replace("[ 3.0, 10.0,  3.0,  0.0]", "[-3.0, 10.0,  3.0,  0.0]")   # K not symmetric
    assert bad != text
    path = tmp_path / "bad.toml"
    path.write_text(bad)
    res = stand("rig", "check", str(path))
    assert res.returncode == 1
    assert "is not one a structure can give" in res.stdout and "opposite signs" in res.stdout


def test_a_given_stiffness_that_is_not_symmetric_is_a_problem_though_some_stiffness_gives_its_G(tmp_path):
    """A chain of channels: other flow gains could make any G of the chain symmetric, so G
    alone passes; but the file states K, and a stiffness is symmetric."""
    bad = EXAMPLE_RIG.read_text().replace("[ 0.0,  0.0,  3.0, 10.0]", "[ 0.0,  0.0, 30.0, 10.0]")
    path = tmp_path / "asym.toml"
    path.write_text(bad)
    result = check_rig(load_rig_file(path))
    assert result.structure.check.physical and not result.ok
    assert result.problems == ["the structure (from K) is not one a structure can give: K is not "
                               "symmetric: K[3,4] = 3 but K[4,3] = 30 (outer, tip): a stiffness is"]
    assert "  but K is not symmetric" in result.text()
    assert result.to_dict()["structure"]["physical"] is False


def test_a_stiffness_that_is_not_positive_definite_is_a_problem():
    G = [[100.0, 120.0], [120.0, 100.0]]                 # symmetric, eigenvalue -20
    result = check_rig(rig_from_mapping(rig(structure={"G": G})))
    assert not result.ok and "not positive definite" in result.problems[0]


def test_two_buses_on_one_python_can_bus_are_a_problem():
    data = rig(channels=2, buses=2)
    data["bus"][1]["spec"] = "udp_loopback:chk0,drop=0.1"     # the same bus, other options
    (problem,) = check_rig(rig_from_mapping(data)).problems
    assert problem.startswith("buses can0 and can1 are the same python-can bus (udp_loopback:chk0)")


@pytest.mark.parametrize("bus, says", [
    ({"spec": "socketcn:can0"}, "python-can knows no interface 'socketcn'"),
    ({"spec": "pcan:PCAN_USBBUS1,bitrate=500000"}, "opens it with bitrate=500000 but the rig file "
                                                   "says bitrate = 1000000"),
])
def test_a_bus_that_cannot_be_opened_as_the_file_says_is_a_problem(bus, says):
    data = rig()
    data["bus"][0].update(bus)
    problems = check_rig(rig_from_mapping(data)).problems
    assert len(problems) == 1 and says in problems[0]


def test_an_emulated_plant_that_disagrees_with_its_channel_is_a_problem():
    data = rig(channels=1)
    data["channel"][0].update(range_kgf=5000, force_limit_kgf=4000,
                              plant={"sensor": {"range_kgf": 10000}, "initial": {"force_kgf": 4500}})
    problems = check_rig(rig_from_mapping(data)).problems
    assert any("range_kgf = 10000 but the channel's range_kgf = 5000" in p for p in problems)
    assert any("starts at 4500 kgf, beyond its force limit 4000 kgf" in p for p in problems)


def test_what_is_not_wrong_but_worth_knowing_is_a_note_not_a_problem():
    data = rig(channels=2, buses=2, structure={"G": [[100.0, 120.0], [120.0, 150.0]]})
    data["bus"].append({"name": "spare", "spec": "udp_loopback:spare"})
    data["channel"][0]["plant"] = {"model": "base"}
    result = check_rig(rig_from_mapping(data))
    assert result.ok, result.problems
    notes = "\n".join(result.notes)
    assert "bus spare carries no channel" in notes
    assert "not diagonally dominant for c0" in notes
    assert "c1 have no emulated plant" in notes
    assert "no structure given" in "\n".join(check_rig(rig_from_mapping(rig())).notes)


def test_a_rig_file_that_cannot_be_read_is_exit_2_with_one_line(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text('[[bus]]\nname = "can0"\n')
    res = stand("rig", "check", str(path))
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.startswith("stand rig: error: ") and res.stderr.count("\n") == 1
