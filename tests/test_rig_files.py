"""A rig written back as a rig file (rig.files), the same rig on private loopback buses, and
the chain rigs of N like channels the benchmarks use (rig.chain)."""
from __future__ import annotations

import tomllib

import numpy as np
import pytest

from rig.chain import chain_rig
from rig.check import check_rig
from rig.config import RigError, load_rig_file, rig_from_mapping
from rig.files import on_private_loopback, rig_to_toml
from tests.support.rig import EXAMPLE_RIG


def reread(rig, tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(rig_to_toml(rig, header="written by a test", path=path))
    return load_rig_file(path)


def test_the_example_rig_round_trips_through_its_file(tmp_path):
    rig = load_rig_file(EXAMPLE_RIG)
    again = reread(rig, tmp_path)
    assert again.structure_from == "K"
    np.testing.assert_array_equal(again.G, rig.G)
    np.testing.assert_array_equal(again.K, rig.K)
    assert (again.name, again.period_s, again.bus_load_limit, again.heartbeat_ms) == \
        (rig.name, rig.period_s, rig.bus_load_limit, rig.heartbeat_ms)
    assert again.buses == rig.buses
    for a, b in zip(again.channels, rig.channels):
        assert (a.name, a.bus, a.valve_id, a.dynamometer_id, a.range_kgf, a.limit_kgf) == \
            (b.name, b.bus, b.valve_id, b.dynamometer_id, b.range_kgf, b.limit_kgf)
        assert a.plant.model.spec == b.plant.model.spec
        assert a.plant.model.params() == b.plant.model.params()
        assert a.plant.sensor == b.plant.sensor
        assert a.plant.initial_force_kgf == b.plant.initial_force_kgf


def test_a_rig_given_by_G_or_by_its_plants_alone_round_trips(tmp_path):
    G = [[100.0, 20.0], [25.0, 80.0]]
    data = {"bus": [{"name": "a", "spec": "udp_loopback:files-a"}],
            "channel": [{"name": f"c{i}", "bus": "a", "valve_id": 2 * i + 1, "dynamometer_id": 2 * i + 2,
                         "plant": {"model": "base", "base": {"tau": 0.04},
                                   "initial": {"force_kgf": 250.0 * (i + 1)}}} for i in range(2)],
            "structure": {"G": G}}
    again = reread(rig_from_mapping(data), tmp_path)
    assert again.structure_from == "G" and again.G.tolist() == G
    assert [c.plant.initial_force_kgf for c in again.channels] == [250.0, 500.0]
    del data["structure"]
    plants = rig_from_mapping(data)
    again = reread(plants, tmp_path)
    assert again.structure_from == "plants"
    np.testing.assert_array_equal(again.G, plants.G)


def test_a_rig_on_private_loopback_changes_only_its_buses_specs():
    rig = load_rig_file(EXAMPLE_RIG)
    private = on_private_loopback(rig, "demo-42")
    assert [b.spec for b in private.buses] == ["udp_loopback:demo-42-can0", "udp_loopback:demo-42-can1"]
    assert [(b.name, b.bitrate) for b in private.buses] == [(b.name, b.bitrate) for b in rig.buses]
    assert private.channels is rig.channels and private.G is rig.G
    assert [b.spec for b in rig.buses] == ["udp_loopback:rig-can0", "udp_loopback:rig-can1"]


@pytest.mark.parametrize("channels,buses", [(1, 1), (4, 2), (5, 2), (8, 2), (16, 4)])
def test_a_chain_rig_has_the_templates_channels_spread_over_its_buses_neighbours_coupled(
        channels, buses, tmp_path):
    template = load_rig_file(EXAMPLE_RIG).channels[0]
    rig = reread(chain_rig(template, channels, buses, coupling=0.3, tag="files"), tmp_path)
    g = template.plant.model.g
    np.testing.assert_allclose(np.diag(rig.G), g)
    np.testing.assert_allclose(np.diag(rig.G, 1), 0.3 * g)
    np.testing.assert_allclose(np.diag(rig.G, -1), 0.3 * g)
    assert np.count_nonzero(rig.G) == channels + 2 * (channels - 1)
    on_bus = [len(rig.channels_on(b.name)) for b in rig.buses]
    assert sum(on_bus) == channels and max(on_bus) - min(on_bus) <= 1
    for b in rig.buses:                       # neighbours share a bus, ids 1, 2 / 3, 4 / ...
        ids = [(c.valve_id, c.dynamometer_id) for c in rig.channels_on(b.name)]
        assert ids == [(2 * k + 1, 2 * k + 2) for k in range(len(ids))]
    assert all(c.plant.model.params() == template.plant.model.params() for c in rig.channels)
    check = check_rig(rig)
    assert check.ok, check.problems            # physical, and 4 channels per bus at 2 ms fit
    assert check.structure.physical


def test_eight_on_two_and_sixteen_on_four_buses_fit_a_1_mbit_bus_at_2_ms():
    template = load_rig_file(EXAMPLE_RIG).channels[0]
    for channels, buses in ((8, 2), (16, 4)):
        budgets = check_rig(chain_rig(template, channels, buses)).budgets
        assert [round(b.load.load_pct, 1) for b in budgets] == [62.8] * buses
        assert all(b.fits for b in budgets)


@pytest.mark.parametrize("kwargs,words", [
    ({"channels": 0, "buses": 1}, "at least one channel"),
    ({"channels": 2, "buses": 3}, "1 to 2 buses"),
    ({"channels": 4, "buses": 2, "coupling": 0.5}, "below 0.5"),
    ({"channels": 128, "buses": 1}, "CANopen has 127"),
])
def test_a_chain_rig_that_cannot_be_is_refused_with_the_reason(kwargs, words):
    template = load_rig_file(EXAMPLE_RIG).channels[0]
    with pytest.raises(RigError, match=words):
        chain_rig(template, **kwargs)


def test_the_written_file_is_toml_a_person_can_read():
    text = rig_to_toml(load_rig_file(EXAMPLE_RIG), header="the example rig\nsecond line")
    assert text.startswith("# the example rig\n# second line\n")
    doc = tomllib.loads(text)
    assert [c["name"] for c in doc["channel"]] == ["root", "inner", "outer", "tip"]
    assert "g" not in doc["channel"][0]["plant"]["base"]        # the structure's diagonal gives it
    assert doc["structure"]["flow_gain_mm_per_pct_s"] == [12.0, 10.0, 14.0, 11.0]
