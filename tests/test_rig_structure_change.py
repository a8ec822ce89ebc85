"""A scheduled change of the emulated structure (a crack at one attachment point): what it does
to K and G, when it acts (at its stand time, exactly, whatever blocks the lockstep plant
computes ahead), the rig file's [[structure.change]] and ``stand emulate --change``, the truth
and ``stand rig check``; and the emulator process serving one through the gateway."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from gateway.offline import emulated_truth
from plant import PlantModel
from plant.rig import RigModel, StructureChange, changed_structure, physical_check
from plant_emulator.lockstep_plant import LockstepRig
from rig.check import check_rig
from rig.config import RigError, load_rig_file, parse_change, rig_from_mapping, with_changes
from rig.emulated import emulated_plant, rig_truth
from rig.files import rig_to_toml
from tests.support.rig import EXAMPLE_RIG, example_rig_text

K = np.array([[10, 3, 0, 0], [3, 10, 3, 0], [0, 3, 10, 3], [0, 0, 3, 10]], float)
FLOW = np.array([12.0, 10.0, 14.0, 11.0])
G = K * FLOW[None, :]
INNER = 1
DT = 0.0005
T = 0.002

CHANGE = """
[[structure.change]]
channel = "inner"
stiffness_factor = 0.97
from_s = 600.0
"""


def quiet_truth(changes=()) -> RigModel:
    """The example rig's coupled plant (reversal boosts, trends, delays), with ``changes``."""
    model, _ = emulated_truth(EXAMPLE_RIG)
    return RigModel(model.channels, model.G, model.names, changes)


# -- what a crack does to the structure ------------------------------------------------------
def test_a_crack_is_a_compliance_at_its_point_its_row_and_column_of_K_and_G_fall_by_the_factor():
    f = 0.97
    after = changed_structure(G, [1.0, f, 1.0, 1.0])
    # the structure: a compliance δ in series at inner, δ·K_ii = 1/f − 1
    delta = np.zeros(4)
    delta[INNER] = (1 / f - 1) / K[INNER, INNER]
    K_after = np.linalg.inv(np.linalg.inv(K) + np.diag(delta))
    np.testing.assert_allclose(after, K_after * FLOW[None, :], rtol=1e-12, atol=1e-12)
    # its row and column times f, the rest loses (1 − f)·G_ji·G_ik/G_ii
    np.testing.assert_allclose(after[INNER], f * G[INNER], rtol=1e-13)
    np.testing.assert_allclose(after[:, INNER], f * G[:, INNER], rtol=1e-13)
    rest = G - (1 - f) * np.outer(G[:, INNER], G[INNER]) / G[INNER, INNER]
    keep = np.arange(4) != INNER
    np.testing.assert_allclose(after[np.ix_(keep, keep)], rest[np.ix_(keep, keep)], rtol=1e-13,
                               atol=1e-13)
    assert physical_check(after).physical
    # the flows that make any force change: only inner's valve needs more, 1/f − 1 of its share
    dy = np.array([300.0, -200.0, 150.0, 80.0])
    extra = np.linalg.solve(after, dy) - np.linalg.solve(G, dy)
    np.testing.assert_allclose(extra, [0, (1 / f - 1) * dy[INNER] / G[INNER, INNER], 0, 0],
                               atol=1e-12)
    # two changes at two points: their compliances add
    both = changed_structure(G, [0.9, f, 1.0, 1.0])
    added = (1 / np.array([0.9, f, 1.0, 1.0]) - 1) / np.diag(G)
    np.testing.assert_allclose(both, np.linalg.inv(np.linalg.inv(G) + np.diag(added)), rtol=1e-12,
                               atol=1e-12)


def test_a_change_acts_from_its_stand_time_at_once_or_along_its_ramp():
    model = quiet_truth([StructureChange(INNER, 0.97, 600.0),
                         StructureChange(0, 0.9, 100.0, ramp_s=60.0)])
    assert model.structure_at(99.9) is model.G            # intact: the very same G
    assert model.factors(130.0) == pytest.approx([0.95, 1, 1, 1])   # half way along the ramp
    assert model.factors(599.9999) == pytest.approx([0.9, 1, 1, 1])
    assert model.factors(600.0) == pytest.approx([0.9, 0.97, 1, 1])
    np.testing.assert_allclose(model.G_changed, changed_structure(model.G, [0.9, 0.97, 1, 1]))
    # a change twice at one point: the factors multiply
    twice = quiet_truth([StructureChange(INNER, 0.97, 1.0), StructureChange(INNER, 0.97, 2.0)])
    assert twice.G_changed[INNER, INNER] == pytest.approx(0.97 ** 2 * model.G[INNER, INNER])


@pytest.mark.parametrize("bad, says", [
    (StructureChange(4, 0.97, 1.0), "channel index 4"),
    (StructureChange(1, 0.0, 1.0), "stiffness_factor = 0.0"),
    (StructureChange(1, 0.97, -1.0), "from_s = -1.0"),
    (StructureChange(1, 0.97, 1.0, float("nan")), "ramp_s = nan"),
])
def test_a_change_the_plant_cannot_make_is_refused_naming_what(bad, says):
    from plant.params import ModelError
    with pytest.raises(ModelError, match=says):
        quiet_truth([bad])
    with pytest.raises(ModelError, match="stand time"):
        quiet_truth([StructureChange(1, 0.97, 1.0)]).advance(
            quiet_truth().new_state(DT), np.zeros((4, 4)), DT)


# -- when it acts, in lockstep ---------------------------------------------------------------
def commands(periods: int, seed: int = 2) -> np.ndarray:
    """(4, periods): a command per channel and period, a new one every 7 periods."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-6, 6, (4, periods // 7 + 1))
    return np.repeat(u, 7, axis=1)[:, :periods]


def reference_forces(u: np.ndarray, change_step: int, factors) -> np.ndarray:
    """The forces at each period's end, one period per advance call, the intact plant's model
    before step ``change_step`` and a plant with the changed G from it on (the same channels:
    the coupled integration takes each channel's flow from its own model, g from G)."""
    intact = quiet_truth()
    changed = RigModel(intact.channels, changed_structure(intact.G, factors), intact.names)
    states = intact.new_state(DT)
    sub = round(T / DT)
    out = []
    for k in range(u.shape[1]):
        block = np.repeat(u[:, k:k + 1], sub, axis=1)
        first = k * sub
        if first + sub <= change_step:
            y = intact.advance(states, block, DT)
        elif first >= change_step:
            y = changed.advance(states, block, DT)
        else:                         # the change inside the period: its steps on each side
            a = change_step - first
            intact.advance(states, block[:, :a], DT)
            y = changed.advance(states, block[:, a:], DT)
        out.append(y[:, -1])
    return np.array(out).T


@pytest.mark.parametrize("from_s", [0.3, 0.3005])     # on a period's start; inside a period
def test_in_lockstep_the_change_acts_from_the_step_at_its_time_whatever_the_blocks_ahead(from_s):
    factors = [1.0, 0.97, 1.0, 1.0]
    model = quiet_truth([StructureChange(INNER, 0.97, from_s)])
    u = commands(400)
    plant = LockstepRig(model, 0.0, DT)
    got = np.array([plant.step(T, list(u[:, k])) for k in range(u.shape[1])]).T
    assert plant.periods_per_block > 20           # computed ahead, across the change
    assert plant.stand_time_s == pytest.approx(400 * T)
    expect = reference_forces(u, round(from_s / DT), factors)
    np.testing.assert_allclose(got, expect, rtol=0, atol=1e-9 * np.abs(expect).max())
    # and not a step off: one step earlier or later is another trajectory
    for off in (-1, 1):
        other = reference_forces(u, round(from_s / DT) + off, factors)
        assert np.abs(other - got).max() > 1e-6
    # the same run again is the same bit for bit
    again = LockstepRig(model, 0.0, DT)
    assert np.array_equal(np.array([again.step(T, list(u[:, k])) for k in range(u.shape[1])]).T, got)


def test_a_held_command_shows_the_force_rate_fall_by_the_factor_at_the_period_of_the_change():
    """inner's valve held open: its force rate is G_ii·u + Δ, then 0.97·G_ii·u + Δ from the
    period that starts at the change (the example's delays are long past)."""
    model = quiet_truth([StructureChange(INNER, 0.97, 0.5)])
    plant = LockstepRig(model, 0.0, DT)
    u = [0.0, 4.0, 0.0, 0.0]
    y = np.array([plant.step(T, u) for _ in range(500)])
    rate = np.diff(y[:, INNER]) / T                 # rate[k]: the period ending at (k + 2)·T
    delta = model.channels[INNER].delta
    g = model.G[INNER, INNER]
    ends = (np.arange(len(rate)) + 2) * T
    before = (ends > 0.1 + T) & (ends <= 0.5 + 1e-9)
    after = ends > 0.5 + T / 2
    assert rate[before] == pytest.approx(g * 4 + delta, rel=1e-9)
    assert rate[after] == pytest.approx(0.97 * g * 4 + delta, rel=1e-9)


def test_an_uncoupled_rig_runs_as_before_until_its_change_then_with_the_changed_gain():
    models = [PlantModel.from_spec("base+reversal", {"g": g, "tau": 0.05, "delta": 3.0})
              for g in (120.0, 100.0)]
    plain = LockstepRig(RigModel(models), 0.0, DT)
    changing = LockstepRig(RigModel(models, changes=[StructureChange(1, 0.9, 1.0)]), 0.0, DT)
    u = commands(1000)[:2]
    a = np.array([plain.step(T, list(u[:, k])) for k in range(1000)]).T
    b = np.array([changing.step(T, list(u[:, k])) for k in range(1000)]).T
    n = round(1.0 / T)
    # the channel's own path, bit for bit until the block computed ahead across the change
    # (that takes the coupled path: the same to rounding)
    assert np.array_equal(a[:, :n - 30], b[:, :n - 30])
    np.testing.assert_allclose(a[:, :n], b[:, :n], rtol=1e-12)
    np.testing.assert_allclose(a[0], b[0], rtol=1e-12)  # the other channel never changes
    assert abs(b[1, -1] - a[1, -1]) > 1.0


# -- the rig file, the command line, the truth, the check ------------------------------------
def example_with(text: str) -> str:
    return example_rig_text("chg") + text


def test_the_rig_file_schedules_changes_and_every_tool_says_so(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(example_with(CHANGE + '\n[[structure.change]]\nchannel = "root"\n'
                                 'stiffness_factor = 0.9\nfrom_s = 100\nramp_s = 60\n'))
    rig = load_rig_file(path)
    assert rig.changes == [StructureChange(1, 0.97, 600.0, 0.0), StructureChange(0, 0.9, 100.0, 60.0)]
    np.testing.assert_allclose(rig.G, G)                # G is the intact structure
    plant = emulated_plant(rig)
    assert plant.model.changes == tuple(rig.changes)
    truth = rig_truth(rig)
    assert truth["changes"] == [
        {"channel": "inner", "stiffness_factor": 0.97, "from_s": 600.0, "ramp_s": 0.0},
        {"channel": "root", "stiffness_factor": 0.9, "from_s": 100.0, "ramp_s": 60.0}]
    np.testing.assert_allclose(truth["G_changed"], changed_structure(G, [0.9, 0.97, 1, 1]))
    json.dumps(truth)
    # written back, read back
    again = tmp_path / "again.toml"
    again.write_text(rig_to_toml(rig))
    assert load_rig_file(again).changes == rig.changes
    # stand rig check prints the schedule and G after it
    check = check_rig(rig)
    assert check.ok
    text = check.text()
    assert "inner: stiffness × 0.97 from 600 s of stand time, at once" in text
    assert "root: stiffness × 0.9 from 100 s of stand time, over 60 s (complete at 160 s)" in text
    assert "G once every change is complete" in text
    doc = check.to_dict()["structure"]
    assert doc["changes"] == truth["changes"] and doc["G_changed"] == truth["G_changed"]
    # the command line's changes come after the file's
    more = with_changes(rig, [parse_change("tip:0.95@3+2", rig)])
    assert more.changes[-1] == StructureChange(3, 0.95, 3.0, 2.0)
    assert rig.changes[-1] == StructureChange(0, 0.9, 100.0, 60.0)   # the rig itself unchanged


def test_a_change_on_a_rig_given_by_G_alone_is_the_same_change():
    text = example_with(CHANGE)
    head, _, rest = text.partition("[structure]")
    rest = rest.split("\n[[structure.change]]", 1)[1]
    rows = ", ".join("[" + ", ".join(f"{v:g}" for v in row) + "]" for row in G)
    by_G = head + f"[structure]\nG = [{rows}]\n\n[[structure.change]]" + rest
    import tomllib
    a = emulated_plant(rig_from_mapping(tomllib.loads(text)))
    b = emulated_plant(rig_from_mapping(tomllib.loads(by_G)))
    assert b.model.changes == a.model.changes
    np.testing.assert_allclose(b.model.G_changed, a.model.G_changed, rtol=1e-12)


@pytest.mark.parametrize("table, says", [
    ('channel = "wing"\nstiffness_factor = 0.97\nfrom_s = 1', "channel = 'wing' is not a channel of the rig; it has root, inner, outer, tip"),
    ('channel = "inner"\nstiffness_factor = 0.97', "#1 (inner): 'from_s' is missing"),
    ('channel = "inner"\nfrom_s = 1', "'stiffness_factor' is missing"),
    ('channel = "inner"\nstiffness_factor = 0\nfrom_s = 1', "stiffness_factor = 0 must be a number in [0.01, 10]"),
    ('channel = "inner"\nstiffness_factor = 0.97\nfrom_s = -5', "from_s = -5 must be a number in [0"),
    ('channel = "inner"\nstiffness_factor = 0.97\nfrom_s = 1\nramp_s = "slow"', "ramp_s = 'slow' must be a number"),
    ('channel = "inner"\nstiffness_factor = 0.97\nfrom_s = 1\nwhen = 3', "unknown key(s) when"),
])
def test_a_wrong_change_table_is_refused_naming_its_key(tmp_path, table, says):
    path = tmp_path / "rig.toml"
    path.write_text(example_with(f"\n[[structure.change]]\n{table}\n"))
    with pytest.raises(RigError) as err:
        load_rig_file(path)
    assert "[[structure.change]] #1" in str(err.value) and says in str(err.value), str(err.value)


def test_a_change_needs_a_structure_to_change(tmp_path):
    """No [structure] and a channel without a plant: nothing gives G, nothing to soften."""
    text = example_rig_text("chg")
    text = text[:text.index("[structure]")]
    text = text[:text.rindex("[channel.plant]")]
    path = tmp_path / "rig.toml"
    path.write_text(text + CHANGE)
    with pytest.raises(RigError, match=r"a change of the structure needs the structure: give "
                                       r"\[structure\] G"):
        load_rig_file(path)


@pytest.mark.parametrize("arg, says", [
    ("inner:0.97", "give it as CHANNEL:FACTOR@FROM_S[+RAMP_S]"),
    ("inner:x@3", "'x' is not a number"),
    ("wing:0.97@3", "channel = 'wing' is not a channel of the rig"),
    ("inner:0.97@3+-1", "ramp_s = -1.0 must be a number in [0"),
])
def test_a_wrong_change_on_the_command_line_is_refused_naming_what(tmp_path, arg, says):
    path = tmp_path / "rig.toml"
    path.write_text(example_rig_text("chg"))
    with pytest.raises(RigError) as err:
        parse_change(arg, load_rig_file(path))
    assert says in str(err.value) and f"--change {arg!r}" in str(err.value)


def test_stand_emulate_refuses_a_wrong_change_before_any_bus_opens(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(example_rig_text("chg"))
    res = subprocess.run([sys.executable, "-m", "stand", "emulate", "--rig", str(path), "--change",
                          "wing:0.97@3"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "channel = 'wing' is not a channel" in res.stderr, res.stderr
    alone = subprocess.run([sys.executable, "-m", "stand", "emulate", "--change", "inner:0.97@3"],
                           capture_output=True, text=True, timeout=60)
    assert alone.returncode == 2 and "give it with --rig" in alone.stderr, alone.stderr


# -- the emulator process serving a change -----------------------------------------------------
@pytest.mark.e2e
@pytest.mark.slow
def test_the_emulator_process_softens_the_structure_at_its_stand_time_through_the_gateway(
        tmp_path, channel):
    """``stand emulate --rig --lockstep --change inner:0.97@8``: an 8 s meander on inner (its
    4000 cycles end at 7.998 s of stand time, before the change) gives inner's column of G;
    the next run (from 8.0 s on) gives that column 0.97 times."""
    from gateway import Gateway, GatewayConfig
    from gateway.experiments import Meander
    from plant_emulator.process import RigEmulatorProcess
    path = tmp_path / "rig.toml"
    path.write_text(example_rig_text(channel))
    rig = load_rig_file(path)
    columns = []
    with RigEmulatorProcess(path, lockstep=True, seed=5, changes=["inner:0.97@8"]) as emu:
        truth = emu.truth()
        assert "change inner: stiffness × 0.97 from 8 s" in "\n".join(emu.output)
        with Gateway(GatewayConfig(rig=rig, lockstep=True)) as gw:
            for k in range(2):
                result = gw.run(Meander(5, 4, 2), tmp_path / f"run{k}", progress=False,
                                channels=["inner"])
                assert result.status == "complete", result.outcome.message
    for k in range(2):
        est = subprocess.run([sys.executable, "-m", "stand", "estimate", str(tmp_path / f"run{k}"),
                              "--json"], capture_output=True, text=True, timeout=300)
        assert est.returncode == 0, est.stderr
        columns.append(np.array([row[INNER] for row in json.loads(est.stdout)["G"]]))
    before, after = columns
    assert truth["changes"] == [{"channel": "inner", "stiffness_factor": 0.97, "from_s": 8.0,
                                 "ramp_s": 0.0}]
    G_after = np.array(truth["G_changed"])
    np.testing.assert_allclose(G_after[:, INNER], 0.97 * G[:, INNER], rtol=1e-12)
    np.testing.assert_allclose(before, G[:, INNER], atol=0.003 * G[INNER, INNER])
    np.testing.assert_allclose(after, G_after[:, INNER], atol=0.003 * G[INNER, INNER])
    ratio = after[INNER] / before[INNER]
    print(f"inner's column before {np.round(before, 2)}, after {np.round(after, 2)}: "
          f"G_ii ratio {ratio:.4f}")
    assert ratio == pytest.approx(0.97, abs=0.002)
