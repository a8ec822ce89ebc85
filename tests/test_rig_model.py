"""The rig's plant: the paper's model as a matrix (plant.rig), and the rig file (rig.config)."""
from __future__ import annotations

import numpy as np
import pytest

from plant import PlantModel
from plant.rig import RigModel, physical_check
from rig.config import RigError, rig_from_mapping

#: a chain of four attachment points, neighbours coupled (kgf/mm), and each actuator's c/A
K = np.array([[10.0, -3.0, 0, 0], [-3.0, 10.0, -3.0, 0], [0, -3.0, 10.0, -3.0], [0, 0, -3.0, 10.0]])
FLOW = np.array([12.0, 10.0, 14.0, 8.0])
G = K * FLOW[None, :]
DT = 0.002


def square(amplitude: float, period_s: float, n: int) -> np.ndarray:
    t = np.arange(n) * DT
    return np.where((t // (period_s / 2)) % 2 == 0, amplitude, -amplitude)


def test_a_rig_of_one_uncoupled_channel_is_the_one_channel_model_bit_for_bit():
    m = PlantModel.from_spec("base+reversal+stiffness+stiction",
                             {"delta": 8.0, "stiffness.k_abs": 1.5, "stiction.width": 80.0})
    u = square(10.0, 2.0, 3000)
    assert np.array_equal(RigModel([m]).simulate(u[None, :], DT)[0], m.simulate(u, DT))


def test_coupled_channels_follow_the_matrix_law():
    """With the base model, dy/dt = G·u(t − τ) + Δ exactly: the forces' increments over a
    held command are G times the commands (τ later)."""
    models = [PlantModel.from_spec("base", {"tau": 0.05, "delta": d}) for d in (0, 2, -3, 5)]
    rig = RigModel(models, G)
    u = np.zeros((4, 1000))
    u[1, 100:] = 5.0                                   # only channel 2 moves its valve
    y = rig.simulate(u, DT)
    late = slice(200, 999)
    rates = np.diff(y[:, late], axis=1).mean(axis=1) / DT
    expected = G[:, 1] * 5.0 + np.array([0, 2, -3, 5])
    assert np.allclose(rates, expected, rtol=1e-9, atol=1e-9)
    # the neighbour's force moves, the channel two away does not
    assert abs(y[0, -1] - y[0, 150]) > 200 and abs(y[3, -1] - y[3, 150] - 5 * 849 * DT) < 1e-6


@pytest.mark.parametrize("spec, values", [
    ("base+reversal", {}),
    ("base+reversal+leakage+oscillation+deadzone",
     {"leakage.rate": 0.3, "oscillation.amplitude": 40.0, "deadzone.width": 0.5}),
])
def test_coupled_channels_integrated_all_steps_at_once_are_the_step_by_step_law(spec, values):
    """No channel's rate depends on its force but through a decay: the coupled integration
    runs as one pass per channel, and gives what stepping y[k+1] = y[k] + dt·(G·w + a) does."""
    taus = (0.05, 0.045, 0.06, 0.055)
    models = [PlantModel.from_spec(spec, {"tau": t, "delta": d, **values})
              for t, d in zip(taus, (8.0, 5.0, -3.0, 0.0))]
    rig = RigModel(models, G)
    assert all(m.force_decay() is not None for m in rig.channels)
    u = np.stack([square(a, p, 2000) for a, p in ((5, 0.7), (-3, 1.1), (4, 0.9), (2, 1.3))])
    states = rig.new_state(DT, y0=[100.0, -50.0, 0.0, 20.0])
    drives = [m.drive(u[i:i + 1], DT, st) for i, (m, st) in enumerate(zip(rig.channels, states))]
    y0 = np.array([100.0, -50.0, 0.0, 20.0])
    fast = rig._integrate(drives, y0, DT)
    slow = rig._integrate_stepwise(drives, y0, DT)
    assert np.max(np.abs(fast - slow)) < 1e-9 * np.max(np.abs(slow))


def test_a_structure_with_a_symmetric_positive_stiffness_is_physical():
    check = physical_check(G)
    assert check.physical, check.reason
    assert np.allclose(check.scales, FLOW[0] / FLOW)      # A/c relative to the first actuator
    assert np.allclose(check.stiffness, K * FLOW[0])


@pytest.mark.parametrize("change, why", [
    (lambda g: g.__setitem__((0, 1), -g[0, 1]), "opposite signs"),
    (lambda g: g.__setitem__((2, 0), 5.0), "couples both ways or neither"),
    (lambda g: g.__setitem__((1, 1), -1.0), "G_ii <= 0"),
])
def test_a_structure_no_stiffness_can_give_is_refused_with_the_reason(change, why):
    g = G.copy()
    change(g)
    check = physical_check(g)
    assert not check.physical and why in check.reason


def test_three_coupled_channels_must_close_their_loop():
    """Around a loop of three coupled channels the flow-gain ratios must agree: a G whose
    products around the loop differ has no symmetric stiffness behind it."""
    g = np.array([[100.0, 30, 20], [30, 100, 25], [20, 25, 100]])
    assert physical_check(g).physical
    g[0, 1] *= 2.0
    check = physical_check(g)
    assert not check.physical and "asymmetric" in check.reason
    not_definite = np.array([[100.0, 90, 90], [90, 100, 90], [90, 90, 100]]) - np.diag([0, 0, 0])
    not_definite[2, 2] = 10.0
    assert "positive definite" in physical_check(not_definite).reason


RIG = {
    "name": "two buses",
    "bus": [{"name": "can0", "spec": "udp_loopback:r0"}, {"name": "can1", "spec": "udp_loopback:r1"}],
    "channel": [{"name": f"ch{i + 1}", "bus": "can0" if i < 2 else "can1", "valve_id": 1 + 2 * (i % 2),
                 "dynamometer_id": 2 + 2 * (i % 2), "plant": {"model": "base+reversal",
                                                              "base": {"tau": 0.05}}}
                for i in range(4)],
    "structure": {"G": G.tolist()},
}


def test_the_rig_file_gives_each_channel_its_own_gain_from_the_structure():
    rig = rig_from_mapping(RIG)
    assert rig.names == ["ch1", "ch2", "ch3", "ch4"] and rig.structure_from == "G"
    assert [c.plant.model.g for c in rig.channels] == list(np.diag(G))
    assert [c.name for c in rig.channels_on("can1")] == ["ch3", "ch4"]
    assert rig.channels[0].limit_kgf == 9500.0


@pytest.mark.parametrize("edit, says", [
    (lambda r: r["channel"][1].update(valve_id=1), "node id(s) 1 used twice"),
    (lambda r: r["channel"][0].update(bus="can9"), "not one of the rig's buses"),
    (lambda r: r["structure"].update(G=[[1.0]]), "the rig has 4 channel(s)"),
    (lambda r: r["channel"][0]["plant"]["base"].update(g=99.0), "leave g out of the plant"),
    (lambda r: r["bus"][0].update(spec=""), "empty bus specification"),
    (lambda r: r.update(colour="red"), "unknown key(s) colour"),
])
def test_a_mistake_in_the_rig_file_names_it(edit, says):
    import copy
    bad = copy.deepcopy(RIG)
    edit(bad)
    with pytest.raises(RigError) as err:
        rig_from_mapping(bad, "rig.toml")
    assert says in str(err.value) and "rig.toml" in str(err.value)
