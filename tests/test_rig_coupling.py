"""One channel of a rig as a one-channel record with the others' part of its force rate as a
known input (analysis.rig.coupling), and the rig model file that gives G and the channels'
models (plant.config)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from analysis import fit_model
from analysis.identification.windows import Piece, simulate_pieces
from analysis.rig.coupling import channel_records, coupling_rates
from analysis.rig.record import make_rig_record
from analysis.rig.synthetic import rig_meander
from plant import PlantModel
from plant.params import ModelError
from plant.config import load_rig_model, rig_model_from_mapping, rig_model_to_toml
from tests.support.rig_models import chain_rig, two_channel_rig

DT = 0.002


def test_a_channel_with_its_coupling_as_known_input_follows_the_rig_exactly():
    """The one-channel simulation of channel i plus c_i = Σ_{j≠i} G_ij·w_j (the others' flows
    through their own models, reversal boosts included) is the coupled rig's force."""
    rig = chain_rig()
    n = 6000
    t = np.arange(n) * DT
    u = np.vstack([np.where((t // p) % 2 == 0, 5.0, -5.0) for p in (2.0, 2.5, 3.0)])
    y = rig.simulate(u, DT)          # the commands before the run held at the first ones, as
    rec = make_rig_record(t, u, y, rig.names)       # the analysis takes them
    c = coupling_rates(rig, rec)
    for i, name in enumerate(rig.names):
        piece = Piece(u[i], y[i], DT, n, 0, known=c[i])
        yhat = simulate_pieces(rig.channels[i], [piece])[0]
        assert np.max(np.abs(yhat - y[i])) < 1e-6 * np.max(np.abs(y[i])), name
        alone = simulate_pieces(rig.channels[i], [replace(piece, known=None)])[0]
        assert np.max(np.abs(alone - y[i])) > 100.0          # the coupling is no small part


def test_pieces_with_and_without_a_known_rate_simulate_together_as_each_alone():
    """A per-column campaign gives a channel a coupling only in the runs where another valve
    moves: pieces with and without a known rate are integrated side by side, in either order."""
    m = PlantModel.from_spec("base+reversal", {"tau": 0.05, "delta": 3.0})
    n = 3000
    t = np.arange(n) * DT
    u = np.where((t // 1.5) % 2 == 0, 5.0, -5.0)
    known = 150.0 * np.where((t // 2.0) % 2 == 0, 1.0, -1.0)
    with_known = Piece(u, np.zeros(n), DT, 500, 100, known=known)
    without = Piece(u, np.zeros(n), DT, 500, 100)
    alone = [simulate_pieces(m, [p])[0] for p in (with_known, without)]
    assert np.max(np.abs(alone[0] - alone[1])) > 100.0
    for order in ([with_known, without], [without, with_known]):
        together = simulate_pieces(m, order)
        for p, y in zip(order, together):
            assert np.array_equal(y, alone[0 if p is with_known else 1])


def test_the_fit_of_a_channel_with_its_coupling_finds_its_own_parameters():
    a = PlantModel.from_spec("base+reversal", {"tau": 0.04, "delta": 5.0, "reversal.boost": 2.5})
    b = PlantModel.from_spec("base+reversal", {"tau": 0.06, "delta": -3.0, "reversal.boost": 1.5})
    rig = two_channel_rig(a, b)
    rec = rig_meander(rig, [5.0, 5.0], [4.0, 6.0], 36.0, seed=5)
    with_coupling = fit_model(channel_records(rig, [rec], "a"), "base+reversal").params
    assert with_coupling["g"] == pytest.approx(120.0, rel=0.002)
    assert with_coupling["tau"] == pytest.approx(0.04, abs=0.001)
    assert with_coupling["reversal.boost"] == pytest.approx(2.5, rel=0.1)
    without = fit_model([rec.channel("a")], "base+reversal").params
    assert abs(without["g"] - 120.0) > 5 * abs(with_coupling["g"] - 120.0)


def test_a_known_rate_stays_out_of_the_projected_gain_and_trend():
    """g and Δ are solved linearly (variable projection); a known rate is neither."""
    m = PlantModel.from_spec("base", {"g": 90.0, "tau": 0.05, "delta": 4.0})
    n = 20000
    t = np.arange(n) * DT
    u = np.where((t // 2.0) % 2 == 0, 8.0, -8.0)
    known = 300.0 * np.sin(2 * np.pi * 0.37 * t) + 150.0
    piece = Piece(u, np.zeros(n), DT, n, 0, known=known)
    y = simulate_pieces(m, [piece])[0] + np.random.default_rng(0).normal(0, 2.0, n)
    rec = replace(make_rig_record(t, u[None, :], y[None, :], ["x"]).channels[0],
                  known_rate_kgf_s=known)
    p = fit_model([rec], "base").params
    assert p["g"] == pytest.approx(90.0, rel=1e-3) and p["delta"] == pytest.approx(4.0, abs=0.3)
    assert p["tau"] == pytest.approx(0.05, abs=0.001)
    sliced = rec.slice(100, 5000)
    assert np.array_equal(sliced.known_rate_kgf_s, known[100:5000])


RIG_FILE = """\
channels = ["left", "right"]
[structure]
G = [[120.0, -30.0], [-36.0, 100.0]]
[channel.left]
model = "base+reversal"
[channel.left.base]
tau = 0.04
[channel.left.effects.reversal]
boost = 1.5
[channel.right]
[channel.right.base]
tau = 0.05
delta = 3.0
"""


def test_a_rig_model_file_loads_as_a_rig_model_and_round_trips(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(RIG_FILE)
    rig = load_rig_model(path)
    assert rig.names == ["left", "right"] and np.array_equal(rig.G, [[120, -30], [-36, 100]])
    assert rig.channels[0].spec == "base+reversal" and rig.channels[0].g == 120.0
    assert rig.channels[1].g == 100.0 and rig.channels[1].delta == 3.0
    again = tmp_path / "again.toml"
    again.write_text(rig_model_to_toml(rig, "a header", again))
    back = load_rig_model(again)
    assert np.array_equal(back.G, rig.G)
    assert [m.params() for m in back.channels] == [m.params() for m in rig.channels]


@pytest.mark.parametrize("change, message", [
    (lambda s: s.replace('channels = ["left", "right"]', 'channels = ["left"]'),
     "G is 2x2, the file has 1 channel"),
    (lambda s: s.replace("[channel.right]\n", "[channel.other]\n").replace(
        "[channel.right.base]", "[channel.other.base]"), "no [channel.right] table"),
    (lambda s: s.replace("[channel.left.base]\n", "[channel.left.base]\ng = 110.0\n"),
     "its base says g = 110 but G[1,1] = 120"),
    (lambda s: s.replace("[-36.0, 100.0]", "[-36.0, -100.0]"), "must be positive"),
    (lambda s: s.replace("boost = 1.5", "bost = 1.5"), "bost"),
    (lambda s: s.replace("[structure]\nG = [[120.0, -30.0], [-36.0, 100.0]]\n", ""),
     "no [structure] G"),
])
def test_a_rig_model_file_with_a_mistake_is_refused_saying_where_and_what(change, message):
    import tomllib
    with pytest.raises(ModelError, match=message.replace("[", r"\[").replace("]", r"\]")):
        rig_model_from_mapping(tomllib.loads(change(RIG_FILE)), "rig.toml")
