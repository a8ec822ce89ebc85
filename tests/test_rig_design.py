"""A station's controller (loading.design, loading.margins): at one channel the design is the
one-channel design, its loci's margins the one loop's; for a coupled rig they agree with the closed loop's
eigenvalues (python-control) for a coupled rig; decoupling keeps each loop's own margins where
independent loops lose them to the coupling; a coupling too strong is refused with the figure;
the controller file round-trips and is checked."""
from __future__ import annotations

import numpy as np
import pytest

from core.errors import ParameterError
from loading.controller_files import load_controller, read_rig_model
from loading.design import COUPLING_ERROR, design, design_channel, margin_cases
from loading.margins import StationLoop, closed_loop_poles, critical_scale, margins
from plant import PlantModel
from plant.rig import RigModel

from tests.support.rig import EXAMPLE_RIG

T = 0.002


def example():
    return read_rig_model(EXAMPLE_RIG)[0]


@pytest.fixture(scope="module")
def decoupled():
    return design(example(), T)


@pytest.fixture(scope="module")
def controller_file(tmp_path_factory, decoupled):
    path = tmp_path_factory.mktemp("rig-controller") / "controller.toml"
    path.write_text(decoupled.to_toml(path))
    return path


def loop_of(model: RigModel, decoupled: bool) -> StationLoop:
    ds = [design_channel(m, T, check=False) for m in model.channels]
    return StationLoop(model.G, np.array([m.tau for m in model.channels]), np.array([d.kp_pct_per_kgf for d in ds]),
                       np.array([d.ti_s for d in ds]), T, decoupled), ds


def test_the_design_of_a_station_of_one_channel_is_the_one_channel_design_with_its_margins():
    m = PlantModel.from_spec("base+reversal", {"g": 120.0, "tau": 0.05, "delta": 8.0})
    one = design_channel(m, T)
    for station in (design(m, T), design(RigModel([m], names=["root"]), T)):
        c = station.channels[0]
        assert (c.kp_pct_per_kgf, c.ti_s, c.lambda_s, c.boost) == (one.kp_pct_per_kgf, one.ti_s, one.lambda_s, one.boost)
        assert station.detuning == 1.0 and np.array_equal(station.M, [[1.0]])
        assert station.feedforward == "channel", "one channel: its own model's feedforward"
        # the loops together of one channel: its own loop's margins at the nominal and the boosted gain
        for label, want in (("nominal", one.nominal), ("boosted", one.boosted)):
            got = next(mm for mm in station.margins if mm.label == label)
            assert got.gain_margin == pytest.approx(want.gain_margin, rel=2e-3)
            assert got.phase_margin_deg == pytest.approx(want.phase_margin_deg, abs=0.1)
            assert got.stable
    assert design(m, T).text() == one.text(), "stand design prints the one-channel design"


def test_the_loci_of_one_channel_are_the_one_channel_design_margins():
    m = PlantModel.from_spec("base+reversal", {"g": 120.0, "tau": 0.05, "delta": 8.0})
    d = design_channel(m, T)
    loop = StationLoop(np.array([[120.0]]), np.array([0.05]), np.array([d.kp_pct_per_kgf]), np.array([d.ti_s]), T, True)
    for factor, one in ((1.0, d.nominal), (d.boost, d.boosted)):
        mm = loop.margins([factor], "x", check=True)
        assert mm.stable
        assert mm.gain_margin == pytest.approx(one.gain_margin, rel=2e-3)
        assert mm.phase_margin_deg == pytest.approx(one.phase_margin_deg, abs=0.1)
        assert mm.crossover_hz == pytest.approx(one.crossover_hz, rel=2e-3)
        assert mm.peak_sensitivity == pytest.approx(one.peak_sensitivity, rel=1e-3)


@pytest.mark.parametrize("decoupled", [False, True], ids=["independent", "decoupled"])
def test_the_loci_gain_margin_is_where_the_closed_loops_eigenvalues_leave_the_unit_circle(decoupled):
    loop, ds = loop_of(example(), decoupled)
    boosts = [d.boost for d in ds]
    mm = loop.margins(boosts, "boosted")
    brute = critical_scale(loop, boosts, steps=20)
    assert mm.gain_margin == pytest.approx(brute, rel=5e-3)
    assert np.max(np.abs(closed_loop_poles(loop, boosts, scale=0.98 * brute))) < 1.0
    assert np.max(np.abs(closed_loop_poles(loop, boosts, scale=1.02 * brute))) > 1.0


def test_decoupled_loops_see_their_own_g_and_independent_ones_the_coupling():
    model = example()
    # equal delays and gain factors: decoupling is exact, each loop is its own channel's loop
    same = RigModel([m.with_params({"tau": 0.05}) for m in model.channels], model.G, model.names)
    loop, ds = loop_of(same, True)
    for factor in (1.0, 3.0):
        mm = loop.margins([factor] * 4, "x")
        one = [margins(d.kp_pct_per_kgf, d.ti_s, m.g * factor, m.tau, T) for d, m in zip(ds, same.channels)]
        assert mm.gain_margin == pytest.approx(min(o.gain_margin for o in one), rel=5e-3)
        assert mm.phase_margin_deg == pytest.approx(min(o.phase_margin_deg for o in one), abs=0.2)
    # the example's delays differ (45-60 ms): decoupled stays near 45 degrees, independent loops
    # meet the coupling as a gain of up to 1.49 (an eigenvalue of G diag(1/g)) and lose 15 degrees
    dec, ds = loop_of(model, True)
    ind = StationLoop(dec.G, dec.taus_s, dec.kp, dec.ti_s, T, False)
    boosts = [d.boost for d in ds]
    assert dec.margins(boosts, "b").phase_margin_deg > 44.0
    independent = ind.margins(boosts, "b")
    assert independent.phase_margin_deg < 31.0 and independent.gain_margin < 1.7
    assert max(np.linalg.eigvals(model.G / np.diag(model.G)).real) == pytest.approx(1.4854, abs=1e-3)


def test_the_decoupled_design_meets_the_targets_in_every_case_with_the_coupling_off_by_20_percent(decoupled):
    c = decoupled
    assert c.feedback == "decoupled" and c.feedforward == "rig"
    cases = margin_cases(c.boosts, c.names, COUPLING_ERROR)
    assert len(c.margins) == len(cases) == 3 * (2 + 4)
    for m in c.margins:
        assert m.gain_margin >= 2.0 and m.phase_margin_deg >= 45.0 - 0.3, m.text()
    assert 1.0 < c.detuning < 1.3, "slightly slower than each channel's own design: the delays differ"
    assert all(m.stable for m in c.margins if m.stable is not None)
    assert "decoupled" in c.text() and "worst case" in c.text()


def test_the_independent_baseline_is_todays_design_per_channel_with_its_shortfall_stated():
    model = example()
    c = design(model, T, feedback="independent")
    assert c.feedforward == "channel" and c.detuning == 1.0
    for ch, m in zip(c.channels, model.channels):
        one = design_channel(m, T, check=False)
        assert ch.kp_pct_per_kgf == one.kp_pct_per_kgf and ch.ti_s == one.ti_s
    assert any("hold less than the one-channel targets" in n for n in c.notes)
    assert c.worst(True).phase_margin_deg < 30.0


def chain(k: float, n: int = 3) -> RigModel:
    """n channels, every pair coupled k of a channel's own stiffness, g = 100."""
    K = np.full((n, n), k) + (1 - k) * np.eye(n)
    ms = [PlantModel.from_spec("base+reversal", {"g": 100.0, "tau": 0.05, "delta": 0.0}) for _ in range(n)]
    return RigModel(ms, 100.0 * K, [f"c{i}" for i in range(n)])


def test_a_coupling_too_strong_for_independent_loops_is_refused_with_the_figure():
    # every pair 70 %: the load pattern of all three together has 2.4x the loop gain
    with pytest.raises(ParameterError, match=r"too strong for independent PI loops: at boosted.* unstable .*"
                                             r"self-oscillate.*eigenvalues from 0.3 to 2.4"):
        design(chain(0.7), T, feedback="independent", coupling_error=0.0)
    design(chain(0.7), T, coupling_error=0.0)          # decoupled: fine


def test_a_coupling_too_strong_for_decoupled_loops_with_its_error_is_refused_with_the_figure():
    # every pair 90 %: G is nearly singular, a 20 % error in the coupling turns a mode over
    with pytest.raises(ParameterError, match=r"too strong for decoupled PI feedback: .*coupling \+20 % off.*unstable"
                                             r".*inverse has eigenvalues from -0.8 to .*eigenvalues from 0.1 to 2.8"):
        design(chain(0.9), T)


def test_the_controller_file_round_trips_and_is_put_in_the_rigs_order(decoupled, controller_file):
    c, path = decoupled, controller_file
    back = load_controller(path, T)
    assert back.names == c.names and np.array_equal(back.G, c.G)
    assert [x.kp_pct_per_kgf for x in back.channels] == [x.kp_pct_per_kgf for x in c.channels]
    assert [m.phase_margin_deg for m in back.margins] == [m.phase_margin_deg for m in c.margins]
    assert np.allclose(back.M, c.M)
    order = ["tip", "outer", "inner", "root"]
    swapped = load_controller(path, T, order)
    assert swapped.names == order and swapped.G[0, 1] == c.G[3, 2]
    assert swapped.channels[0].model.g == c.G[3, 3]


@pytest.mark.parametrize("edit, match", [
    (lambda s: s.replace("period_s = 0.002", "period_s = 0.002\n", 1), None),
    (lambda s: s.replace('"tau" = 0.05\n', "", 1), "lacks tau"),
    (lambda s: s.replace("feedback = \"decoupled\"", "feedback = \"magic\""), "feedback is one of"),
    (lambda s: s.replace("[structure]", "[structure_]"), "no 'structure'"),
    (lambda s: s.replace("kp_pct_per_kgf = 0.0", "kp_pct_per_kgf = -0.0", 1), "must be a positive number"),
])
def test_a_broken_controller_file_is_refused_naming_what_to_do(tmp_path, controller_file, edit, match):
    path = tmp_path / "c.toml"
    path.write_text(edit(controller_file.read_text()))
    if match is None:
        load_controller(path, T)
        return
    with pytest.raises(ParameterError, match=match):
        load_controller(path, T)


def test_a_controller_for_another_period_or_other_channels_is_refused(tmp_path, controller_file):
    path = controller_file
    with pytest.raises(ParameterError, match="period of 2 ms but the loop runs at 5 ms"):
        load_controller(path, 0.005)
    with pytest.raises(ParameterError, match="the rig has root, inner"):
        load_controller(path, T, ["root", "inner"])
    one = tmp_path / "one.toml"
    one.write_text(design(example().channels[0], T).to_toml(one))
    with pytest.raises(ParameterError, match="not a rig controller file"):
        load_controller(one, T, example().names)


def test_a_rig_file_without_plants_is_no_model_to_design_from(tmp_path):
    text = EXAMPLE_RIG.read_text()
    head, _, _ = text.partition("[channel.plant]")
    rig = tmp_path / "rig.toml"
    rig.write_text(text.replace(text[text.index("[channel.plant]\nmodel = \"base+reversal\"\n[channel.plant.base]\ntau = 0.050"):
                                     text.index("[[channel]]\nname = \"inner\"")], ""))
    with pytest.raises(ParameterError, match="without plants for root"):
        read_rig_model(rig)
