"""Device files: roles resolved against a maker's EDS, the configuration planned as CiA 301
asks, and every mistake one clear error naming the file and what to do (devices/)."""
from __future__ import annotations

import re
import shutil
from pathlib import Path

import cantools
import pytest
from canopen.objectdictionary import INTEGER16, INTEGER32, REAL32

from devices import DeviceError, default_devices, load_device_set, plan_node
from devices.dbcfile import stand_dbc
from devices.device import RevisionRange
from devices.units import SetpointScale, kgf_per_count
from dbc import profile as P
from rig.budget import ChannelFrames
from rig.config import RigError, rig_from_mapping

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "devices"
SETS = ("servotek", "hydronix", "fluxa")


def example(name: str):
    return load_device_set(EXAMPLES / name / "devices.toml")


def plans(devices, valve_id=1, dyn_id=2, **kw):
    kw = {"period_s": 0.002, "heartbeat_ms": 100, "rpdo_timeout_ms": 100, **kw}
    return plan_node(devices.valve, valve_id, **kw), plan_node(devices.dynamometer, dyn_id, **kw)


def test_the_example_sets_differ_where_real_devices_differ():
    sets = {name: example(name) for name in SETS}
    vendors = {(d.valve.identity.vendor, d.valve.identity.product) for d in sets.values()}
    vendors.add((default_devices().valve.identity.vendor, default_devices().valve.identity.product))
    assert len(vendors) == 4                                   # four makers' valve drives
    pv = {name: d.dynamometer.types["process_value"] for name, d in sets.items()}
    assert pv == {"servotek": INTEGER32, "hydronix": REAL32, "fluxa": INTEGER16}
    assert [d.valve.error_control for d in sets.values()] == ["heartbeat", "guarding", "heartbeat"]
    valve_plans = {name: plans(d)[0] for name, d in sets.items()}
    assert {n: (p.rpdo.number, p.tpdo.number) for n, p in valve_plans.items()} == \
        {"servotek": (2, 2), "hydronix": (1, 1), "fluxa": (3, 4)}
    assert {n: p.tpdo.dynamic for n, p in valve_plans.items()} == \
        {"servotek": True, "hydronix": False, "fluxa": True}


def test_a_dynamic_pdo_is_written_in_the_order_cia_301_asks():
    valve, _ = plans(example("servotek"))
    writes = [(w.index, w.sub, w.value) for w in valve.rpdo.writes]
    com, mapping = 0x1401, 0x1601
    assert writes[0] == (com, 1, 0x80000301)                  # invalid first
    assert writes[-1] == (com, 1, 0x301)                      # valid last
    entries = [w for w in writes if w[0] == mapping]
    assert entries == [(mapping, 0, 0), (mapping, 1, 0x60400010), (mapping, 2, 0x63000110),
                       (mapping, 0, 2)]
    assert (com, 2, 255) in writes and (com, 5, 100) in writes  # asynchronous, RPDO timeout
    disabled = [w for w in valve.disable]
    assert [(w.index, w.sub, w.value) for w in disabled] == [(0x1800, 1, 0x80000181)]
    assert any(w.index == 0x6042 and w.value == 1 for w in valve.settings)


def test_a_static_pdo_is_used_as_it_is_and_what_it_lacks_is_said():
    valve, dyn = plans(example("hydronix"))
    assert not any(w.index in (0x1600, 0x1A00) for w in valve.writes())    # mapping untouched
    assert valve.tpdo.keys == ((0x6041, 0),)
    notes = " ".join(valve.notes)
    assert "spool position is not recorded" in notes and "no RPDO timeout" in notes
    assert any(w.index == 0x100C for w in valve.settings) and any(w.index == 0x100D for w in valve.settings)
    assert not any(w.index == 0x1017 for w in valve.settings)          # guarded, no heartbeat
    assert dyn.tpdo.number == 2 and dyn.tpdo.keys == ((0x6130, 1),)
    assert [(w.index, w.value) for w in dyn.disable] == [(0x1800, 0x80000182)]


def test_the_guarded_life_time_is_the_masters_timeout():
    valve, _ = plans(example("hydronix"), life_time_factor=10)
    assert any(w.index == 0x100D and w.value == 10 for w in valve.settings)


def test_the_emulated_pair_plans_the_mapping_it_always_had():
    valve, dyn = plans(default_devices())
    assert valve.rpdo.keys == ((0x6040, 0), (0x6300, 1)) and valve.rpdo.cob_id == 0x201
    assert valve.tpdo.keys == ((0x6041, 0), (0x6301, 1)) and valve.tpdo.cob_id == 0x181
    assert dyn.tpdo.keys == ((0x9130, 1), (0x6150, 1)) and dyn.tpdo.cob_id == 0x182
    assert ChannelFrames.of(default_devices()).pdo_bytes == (
        ("valve command", 4), ("valve status", 4), ("force", 5))


def test_the_bus_budget_counts_each_channels_own_pdos_and_guarding():
    frames = {name: ChannelFrames.of(example(name)) for name in SETS}
    assert dict(frames["fluxa"].pdo_bytes)["force"] == 2              # INTEGER16
    assert dict(frames["hydronix"].pdo_bytes) == {"valve command": 4, "valve status": 2, "force": 4}
    assert frames["hydronix"].error_control_frames == 4               # request and answer, 2 nodes
    assert frames["servotek"].error_control_frames == 2


def test_force_units_scale_as_the_amplifiers_say():
    assert kgf_per_count("N", 1, True) == P.force_scale_kgf(P.UNIT_N_DEFAULT, 1)
    assert kgf_per_count("kgf", 1, True) == pytest.approx(0.1)
    assert kgf_per_count("kN", 2, True) == pytest.approx(10 / 9.80665)
    assert kgf_per_count("kN", 3, False) == pytest.approx(1000 / 9.80665)   # REAL32: no decimals
    with pytest.raises(ValueError, match="not a force unit"):
        kgf_per_count("bar", 0, True)


def test_the_setpoint_scale_is_the_profiles_counts_at_its_reference():
    default = SetpointScale()
    assert [default.counts(u) for u in (100, -100, 150, 50.0, float("nan"))] == \
        [16384, -16384, 16384, 8192, 0]
    other = SetpointScale(10000, 16)
    assert other.counts(100) == 10000 and other.percent(5000) == 50.0


def test_revision_ranges():
    r = RevisionRange.parse("2.0-2.9", "x")
    assert (2 << 16 | 3) in r and (3 << 16) not in r and (1 << 16 | 9) not in r
    assert (1 << 16 | 77) in RevisionRange.parse("1", "x")
    with pytest.raises(DeviceError, match="MAJOR.MINOR"):
        RevisionRange.parse("v2", "x")


def test_the_stand_dbc_of_a_device_set_decodes_its_frames():
    valve, dyn = plans(example("hydronix"))
    db = cantools.database.load_string(stand_dbc(valve, dyn, kgf_per_count("kN", 0, False), 16384))
    force = db.get_message_by_frame_id(0x282)
    data = force.encode({"Force": 1000.0})            # kgf, carried as REAL32 kN
    import struct
    assert struct.unpack("<f", data)[0] == pytest.approx(1000 / 101.97162129779284)
    assert db.get_message_by_frame_id(0x201).decode(b"\x07\x00\x00\x20")["Command"] == pytest.approx(50.0)
    assert db.get_message_by_frame_id(0x181).signal_tree == ["StatusWord"]


# -- mistakes: one clear error each --------------------------------------------------------------
@pytest.fixture
def device_dir(tmp_path):
    for name in ("svd40.eds", "lca4.eds"):
        shutil.copy(EXAMPLES / "servotek" / name, tmp_path / name)
    return tmp_path


def write(dir_: Path, valve: str, dyn: str = 'eds = "lca4.eds"\nunit = "kgf"\ndecimals = 1') -> Path:
    path = dir_ / "devices.toml"
    path.write_text(f"[valve]\n{valve}\n\n[dynamometer]\n{dyn}\n")
    return path


@pytest.mark.parametrize("valve, words", [
    ('eds = "nowhere.eds"', ["nowhere.eds does not exist"]),
    ('eds = "svd40.eds"\nsetpoint = "0x6999:01"', ["setpoint", "no such object"]),
    ('eds = "svd40.eds"\nsetpoint = "0x6041"', ["UNSIGNED16", "cannot carry the spool setpoint", "INTEGER16"]),
    ('eds = "svd40.eds"\nsetpoint = "0x6314"', ["cannot be mapped to a PDO"]),
    ('eds = "svd40.eds"\nstatus_word = "none"', ["cannot run without the status word"]),
    ('eds = "svd40.eds"\nspeed = 3', ["unknown key(s) speed"]),
    ('eds = "svd40.eds"\nerror_control = "guarding"', ["lacks 0x100C or 0x100D"]),
    ('eds = "svd40.eds"\nrpdo = 9', ["has no RPDO9", "RPDOs 1, 2, 3, 4"]),
    ('eds = "svd40.eds"\nrevision = "two"', ["revision", "MAJOR.MINOR"]),
    ('eds = "svd40.eds"\nsetpoint = "63:00:1"', ["is not an object", "0xINDEX:SUB"]),
])
def test_a_wrong_device_file_is_refused_naming_the_file_and_what_to_do(device_dir, valve, words):
    path = write(device_dir, valve)
    with pytest.raises(DeviceError) as err:
        load_device_set(path)
    text = str(err.value)
    assert str(path) in text and "[valve]" in text
    for word in words:
        assert word in text, text
    assert "\n" not in text


def test_an_amplifier_without_a_unit_needs_one_in_its_file(device_dir):
    path = write(device_dir, 'eds = "svd40.eds"', 'eds = "lca4.eds"')
    with pytest.raises(DeviceError, match=re.escape('has no unit object (0x6131): give the process '
                                                    'value\'s unit in the device file, e.g. unit = "kN"')):
        load_device_set(path)


def test_an_eds_that_does_not_parse_is_refused(device_dir):
    (device_dir / "broken.eds").write_text("[DeviceInfo]\nVendorNumber=1\n[1000]\nParameterName=x\n")
    with pytest.raises(DeviceError, match="cannot be read .*CiA 306"):
        load_device_set(write(device_dir, 'eds = "broken.eds"'))


def test_a_static_mapping_without_the_objects_needed_is_refused_at_planning():
    from devices import device_set_from_mapping
    devices = example("hydronix")
    data = {"valve": {"eds": "hv2.eds"}, "dynamometer": {"eds": "dms8.eds", "tpdo": 1}}
    wrong = device_set_from_mapping(data, "x.toml", EXAMPLES / "hydronix")
    with pytest.raises(DeviceError, match=r"TPDO1's mapping is static .* does not map 0x6130:01"):
        plan_node(wrong.dynamometer, 2, period_s=0.002, heartbeat_ms=100)
    assert devices.dynamometer.tpdo == 2


def test_a_rig_names_devices_for_the_rig_and_per_channel(tmp_path):
    shutil.copytree(EXAMPLES / "hydronix", tmp_path / "hydronix")
    shutil.copytree(EXAMPLES / "fluxa", tmp_path / "fluxa")
    data = {"devices": "hydronix/devices.toml",
            "bus": [{"name": "can0", "spec": "udp_loopback:x"}],
            "channel": [{"name": "a", "bus": "can0", "valve_id": 1, "dynamometer_id": 2},
                        {"name": "b", "bus": "can0", "valve_id": 3, "dynamometer_id": 4,
                         "devices": "fluxa/devices.toml"}]}
    rig = rig_from_mapping(data, str(tmp_path / "rig.toml"), tmp_path)
    assert [c.devices.name for c in rig.channels] == ["Hydronix HV-2 with DMS-8", "Fluxa FX-408 with FX-404"]
    data["channel"][1]["devices"] = "nowhere.toml"
    with pytest.raises(RigError, match=r"\[\[channel\]\] #2 \(b\): devices: file .*nowhere.toml does not exist"):
        rig_from_mapping(data, str(tmp_path / "rig.toml"), tmp_path)
