"""The endurance test file (endurance.testfile): the example reads whole, a stand is a station of
one channel, every mistake is one error naming the file and the key, and the fingerprint says
what changed between a start and a resume (and nothing when only the target, inspections,
monitors or storage changed)."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from core.errors import DataError, ParameterError, StandError
from endurance.testfile import Fingerprint, load_test_file

from tests.support.endurance import EXAMPLE_TEST, copy_example, edit, write_stand_test


@pytest.fixture
def example(tmp_path):
    return copy_example(tmp_path)


def test_the_example_test_reads_with_its_rig_flight_types_block_and_policies():
    t = load_test_file(EXAMPLE_TEST)
    assert t.station.kind == "rig" and t.station.names == ["root", "inner", "outer", "tip"]
    assert t.station.force_limits_kgf == [9000.0, 9000.0, 4500.0, 4500.0]
    assert list(t.flight_types) == list("ABCDEFGHIJ")
    a = t.flight_types["A"]
    assert a.rate_kgf_s == 2000.0 and t.flight_types["B"].rate_kgf_s == 2500.0
    assert a.levels_kgf.shape == (4, 20) and a.load_cases == 20
    assert a.levels_kgf[0, 0] == -540.0 and a.labels[0] == "1"
    assert t.block.size == 4529 and t.block.counts["A"] == 1 and t.block.seed == 1
    assert t.flights == 100_000 and t.blocks == 23
    assert [i.at_flight for i in t.inspections] == [25000, 50000]
    assert t.trend.action == "hold" and t.trend.learn_flights == 30 and t.trend.false_alarm_flights == 1e5
    assert t.gain.mode == "watch" and t.gain.options().fall_pct == 2.0 and t.time_scaling is None
    assert t.storage.rolling_window_s == 600 and t.storage.event_window_s == 30
    assert t.controller.names == t.station.names           # the rig controller, checked


def test_a_stand_is_a_station_of_one_channel_its_csv_column_named_level(tmp_path):
    path = write_stand_test(tmp_path / "stand", flights=500)
    t = load_test_file(path)
    assert t.station.kind == "stand" and t.station.names == ["stand"] and t.station.n == 1
    assert t.station.force_limits_kgf == [9500.0] and t.station.period_s == 0.002
    assert t.flight_types["A"].levels_kgf.shape[0] == 1
    assert t.controller.stand and t.controller.channels[0].kp_pct_per_kgf > 0   # a one-channel controller
    # a plain turning-point CSV (header `level` only) is a stand's flight type too
    (tmp_path / "stand" / "flights" / "B.csv").write_text("level\n0\n3000\n1000\n3000\n0\n")
    assert load_test_file(path).flight_types["B"].levels_kgf.tolist() == [[0, 3000, 1000, 3000, 0]]
    # its own range and limit: a [stand] table
    path.write_text(path.read_text() + "\n[stand]\nforce_limit_kgf = 6000\nrange_kgf = 8000\n")
    t = load_test_file(path)
    assert t.station.force_limits_kgf == [6000.0] and t.station.ranges_kgf == [8000.0]
    path.write_text(path.read_text().replace("force_limit_kgf = 6000", "force_limit_kgf = 9000"))
    with pytest.raises(ParameterError, match=r"\[stand\] force_limit_kgf = 9000: it must be at most 8000"):
        load_test_file(path)


#: (what the file says, what is put instead, what the message must say)
MISTAKES = [
    ('[flight.C]\nload_cases = "flights/C.csv"',
     '[flight.C]\nload_cases = "flights/C.csv"\nrate_kgf_s = -5',
     "test.toml: [flight.C] rate_kgf_s = -5: it must be a positive number"),
    ('flights = 100000', 'flights = 100000\ncolour = "blue"', "unknown key(s) colour"),
    ('[flight.B]\nload_cases = "flights/B.csv"', '[flight.B]\nload_cases = "flights/B.csv"\nrate = 3',
     "[flight.B] unknown key(s) rate"),
    ('[flight.B]\nload_cases = "flights/B.csv"', '[flight.B]\nload_cases = "flights/B.csv"\n'
     'frequency_hz = 1\nrate_kgf_s = 1000', "[flight.B] give rate_kgf_s or frequency_hz, not both"),
    ('load_cases = "flights/D.csv"', 'load_cases = "flights/nowhere.csv"',
     '[flight.D] load_cases = "flights/nowhere.csv": no such file'),
    ("A = 1, B = 2,", "A = 1, B = 0,", "[block] flights: B = 0: it must be a whole number >= 1"),
    ("A = 1, B = 2,", "A = 1, Z = 2, B = 2,", "[block] flights: Z is not a flight type"),
    ("A = 1, B = 2,", "A = 1,", "[block] flights: no count for flight type(s) B"),
    ("seed = 1", "seed = -3", "[block] seed = -3: it must be a whole number >= 0"),
    ("flights = 100000", "flights = 100000\nblocks = 3", "flights = N or blocks = N (one of them)"),
    ("flights = 100000", "flights = 0", "flights = 0: it must be a whole number >= 1"),
    ("at_flight = 50000", "at_flight = 150000", "[[inspection]] #2 at_flight = 150000: the test has 100000 flights"),
    ("at_flight = 50000", "at_flight = 25000", "[[inspection]] at_flight = 25000 is given twice"),
    ('action = "hold"', 'action = "explode"', "[monitor.trend] action = \"explode\": choose one of note, hold, unload"),
    ("learn_flights = 30", "learn_flights = 5", "[monitor.trend] learn_flights = 5: give at least 9"),
    ("learn_flights = 30", "learn_flights = 30\nflow_rise_pct = 5.0", "[monitor.trend] unknown key(s) flow_rise_pct"),
    ("learn_flights = 30", "learn_flights = 30\ncommon_mode = 1", "[monitor.trend] common_mode = 1: give true or false"),
    ("[block]", "[time_scaling]\naccuracy_pct = 20\n\n[block]", "[time_scaling] accuracy_pct = 20: it must be from 0.01 to 10"),
    ('load_cases = "flights/C.csv"', 'load_cases = "flights/C.csv"\nschedule = "flights/A.csv"',
     '[flight.C] schedule = "flights/A.csv": '),
    ('mode = "watch"', 'mode = "watching"', "[monitor.gain] mode = \"watching\": choose one of off, watch, adapt"),
    ("fall_pct = 2.0", "fall_pct = 95.0", "[monitor.gain] fall_pct = 95: it must be from 0.01 to 90"),
    ("event_window_s = 30", "event_window_s = 900", "[storage] event_window_s = 900 is longer than rolling_window_s = 600"),
    ("chunk_s = 60", "chunk_s = 60\nkeep_everything = true", "[storage] unknown key(s) keep_everything"),
    ('station = "../rig.toml"', 'station = "../rigs.toml"', 'station = "../rigs.toml": no such file'),
    ('station = "../rig.toml"', "", "station is missing"),
    ('controller = "controller.toml"', 'controller = "test.toml"', 'controller = "test.toml":'),
    ("[block]", "[stand]\nperiod_ms = 2\n\n[block]", "[stand] is for station = \"stand\""),
    ('name = "wing box, 100,000 flights"', 'name = "wing box', "test.toml: "),   # not TOML
]


@pytest.mark.parametrize("old,new,message", MISTAKES, ids=[m[2][:40] for m in MISTAKES])
def test_a_mistake_is_one_error_naming_the_file_and_the_key(example, old, new, message):
    edit(example, old, new)
    with pytest.raises(StandError) as err:
        load_test_file(example)
    assert isinstance(err.value, (ParameterError, DataError))
    assert message in str(err.value)
    assert str(example) in str(err.value)


def test_a_load_case_file_with_a_mistake_is_named_with_its_flight_type(example):
    flights = example.parent / "flights"
    edit(flights / "E.csv", "case,root,inner,outer,tip", "case,root,inner,outer,wingtip")
    with pytest.raises(DataError, match=r"\[flight.E\] load_cases = \"flights/E.csv\": .*column "
                                        r"'wingtip' is not a channel of the rig"):
        load_test_file(example)
    shutil.copy(flights / "F.csv", flights / "E.csv")
    edit(flights / "E.csv", "\n2,3600.0,3600.0,1800.0,1800.0", "\n2,3600.0,3600.0,4600.0,1800.0")
    with pytest.raises(ParameterError, match=r"\[flight.E\] .*channel outer: .*4600 kgf\) is at or "
                                             r"beyond the force limit"):
        load_test_file(example)


def test_a_controller_for_other_channels_is_refused(example, tmp_path):
    edit(example.parent / "controller.toml", '"tip"]', '"wingtip"]')
    with pytest.raises(ParameterError, match=r'test.toml: controller = "controller.toml": '):
        load_test_file(example)
    assert load_test_file(example, check_controller=False).controller is None


def test_the_fingerprint_is_the_same_for_the_same_test_and_survives_json(example):
    a, b = load_test_file(example).fingerprint(), load_test_file(example).fingerprint()
    assert a == b and a.digest == b.digest and a.changes(b) == []
    assert Fingerprint.from_json(a.to_json()) == a
    assert len(a.digest) == 64 and set(a.parts) >= {"station.channels", "controller", "block.seed",
                                                    "flight.A.load_cases", "flight.J.rate"}


def test_what_may_change_between_stop_and_resume_leaves_the_fingerprint_alone(example):
    before = load_test_file(example).fingerprint()
    edit(example, "flights = 100000", "flights = 120000")
    edit(example, "at_flight = 50000", "at_flight = 60000")
    edit(example, 'action = "hold"', 'action = "unload"')
    edit(example, "rolling_window_s = 600", "rolling_window_s = 1200")
    edit(example, "# An endurance test", "# Renamed comments do not matter either; an endurance test")
    # the same levels written another way (1000 and 1000.0 agree)
    edit(example.parent / "flights" / "J.csv", "\n1,-540.0,", "\n1,-540,")
    after = load_test_file(example).fingerprint()
    assert after.digest == before.digest and after.changes(before) == []


@pytest.mark.parametrize("change,expected", [
    (lambda d: edit(d / "flights" / "C.csv", "3600.0,3600.0,1800.0,1800.0", "3600.0,3600.0,1800.0,1801.0"),
     ["flight type C's load cases changed"]),
    (lambda d: edit(d / "test.toml", '[flight.C]\nload_cases = "flights/C.csv"',
                    '[flight.C]\nload_cases = "flights/C.csv"\nrate_kgf_s = 2400'),
     ["flight type C's rate or frequency changed"]),
    (lambda d: edit(d / "test.toml", "seed = 1", "seed = 2"),
     ["the block's seed changed (the order of the flights)"]),
    (lambda d: edit(d / "test.toml", "I = 1101", "I = 1100"), ["the block's flights per type changed"]),
    (lambda d: edit(d / "controller.toml", "[loop]", "# retuned\n[loop]"),
     ["the controller file's content changed"]),
    (lambda d: edit(d.parent / "rig.toml", "force_limit_kgf = 4500", "force_limit_kgf = 4400"),
     ["the rig file's ranges or force limits changed"]),
    (lambda d: [edit(d / "test.toml", '[flight.J]                         # the mildest: 2,642 '
                     'times per block\nload_cases = "flights/J.csv"\n', ""),
                edit(d / "test.toml", ", J = 2642", "")],
     ["the block's flights per type changed", "flight type J was removed"]),
])
def test_a_change_of_the_test_is_named(example, change, expected):
    before = load_test_file(example, check_controller=False).fingerprint()
    change(example.parent)
    after = load_test_file(example, check_controller=False).fingerprint()
    assert after.digest != before.digest
    assert after.changes(before) == expected


def test_a_rig_file_whose_channels_changed_is_named(example):
    before = load_test_file(example, check_controller=False).fingerprint()
    rig = example.parent.parent / "rig.toml"
    edit(rig, 'name = "tip"', 'name = "wingtip"')
    for csv in (example.parent / "flights").glob("*.csv"):
        edit(csv, "outer,tip", "outer,wingtip")
    after = load_test_file(example, check_controller=False).fingerprint()
    assert after.changes(before) == ["the rig file's channels changed (their names or order)"]
    # a stand where a rig was
    stand = Fingerprint({**after.parts}, "stand")
    assert stand.changes(after)[0] == "the station was a rig and is a one-channel stand now"


def test_the_block_order_of_the_file_is_its_flight_types_order(example):
    t = load_test_file(example, check_controller=False)
    order = t.block.order(1)
    assert len(order) == 4529 and order.count("A") == 1 and order.count("J") == 2642
    assert np.all([t.sequence.slot(n).flight_type == order[n - 1] for n in (1, 2, 4529)])
    assert t.sequence.slot(4530).block == 2
