"""Each flight type's timing in a running test (endurance.timing): its durations searched flight
after flight of the type as stand load --accuracy does pass after pass, the landing judged as
the valley it is between two flights, the search's state journalled per type and taken up again
by the next session, a type's own schedule replayed."""
from __future__ import annotations

import tomllib

import numpy as np
import pytest

from endurance.journal import Journal
from endurance.testfile import load_test_file
from endurance.timing import FOUND, RATE, SCHEDULE, SEARCH, FlightTiming
from loading.report import tracking_report
from loading.time_scaling import Schedule
from tests.support.endurance_run import copy_short_test


@pytest.fixture
def scaled(tmp_path):
    path = copy_short_test(tmp_path / "t")
    path.write_text(path.read_text() + "\n[time_scaling]\naccuracy_pct = 0.5\nsearch_flights = 4\n")
    return path


def flown(programme, error_kgf: float = 0.0):
    """A pass of ``programme`` tracked exactly, every peak and valley ``error_kgf`` off."""
    t = np.arange(programme.r_kgf.shape[1]) * programme.period_s
    Y = programme.r_kgf.copy()
    for j, kinds in enumerate(zip(*programme.kinds())):
        Y[:, programme.turning_idx[j]] += [error_kgf if k in ("peak", "valley") else 0.0 for k in kinds]
    return tracking_report(programme, t, Y), t, Y


def test_a_types_durations_are_searched_flight_by_flight_and_the_journal_text_takes_it_up_again(scaled):
    test = load_test_file(scaled)
    timing = FlightTiming(test)
    assert {t: timing.types[t].mode for t in "ABC"} == {"A": SEARCH, "B": SEARCH, "C": SEARCH}
    base = test.flight_types["C"].programme
    assert timing.programme("C") is base and not timing.final("C")      # its first flight: at its rate
    text = timing.learn("C", base, *flown(base), 0.0)                    # every segment lands
    d1 = timing.programme("C").segment_durations_s
    assert np.all(d1 <= base.segment_durations_s + 1e-9) and d1.sum() < 0.8 * base.duration_s
    assert np.all(d1 >= timing.minimum("C") - 0.002)                    # floored at the valves' minimum
    # a flight prepared before the durations changed teaches nothing
    assert timing.learn("C", base, *flown(base), 0.0) is None
    # the journal's text: a schedule stand load --schedule replays, and the search's state
    again = FlightTiming(test, {"C": text})
    assert again.types["C"].mode == SEARCH and again.types["C"].flights == 1
    assert np.allclose(again.programme("C").segment_durations_s, d1)
    assert np.array_equal(again.types["C"].scaler.landed, timing.types["C"].scaler.landed)
    path = scaled.parent / "C-schedule.toml"
    path.write_text(text)
    assert np.allclose(Schedule.load(path).apply(base).segment_durations_s, d1)
    # the search ends after search_flights (4) flights on the fastest that met the accuracy
    for _ in range(3):
        ran = again.programme("C")
        text = again.learn("C", ran, *flown(ran), 0.0)
    tt = again.types["C"]
    assert tt.mode == FOUND and again.final("C") and tt.flights == 4
    assert np.allclose(tt.durations, tt.best) and tomllib.loads(text)["verified"] is True


def test_a_landing_that_misses_its_ground_level_is_lengthened_and_does_not_meet_the_accuracy(scaled):
    test = load_test_file(scaled)
    timing = FlightTiming(test)
    base = test.flight_types["B"].programme
    timing.learn("B", base, *flown(base), 0.45)             # beyond 0.8 of 0.5 %: it misses
    d = timing.programme("B").segment_durations_s
    assert d[-1] > base.segment_durations_s[-1] and np.all(d[:-1] < base.segment_durations_s[:-1])
    assert timing.types["B"].best is None                    # not met
    timing = FlightTiming(test)
    timing.learn("B", base, *flown(base), 0.1)
    assert timing.types["B"].best is not None


def test_a_type_with_its_own_schedule_replays_it_and_a_type_without_time_scaling_keeps_its_rate(scaled):
    d = np.array([1.0, 0.15, 0.3, 0.05, 1.0])
    Schedule.of(load_test_file(scaled).flight_types["C"].programme, d, 0.5, 0.0, True, []).save(
        scaled.parent / "C.toml")
    scaled.write_text(scaled.read_text().replace('load_cases = "test-flights/C.csv"',
                                                 'load_cases = "test-flights/C.csv"\nschedule = "C.toml"'))
    timing = FlightTiming(load_test_file(scaled))
    assert timing.types["C"].mode == SCHEDULE and timing.final("C")
    assert np.allclose(timing.programme("C").segment_durations_s, d)
    plain = FlightTiming(load_test_file(copy_short_test(scaled.parent.parent / "plain")))
    assert all(tt.mode == RATE for tt in plain.types.values()) and plain.final("A")


@pytest.mark.slow
def test_each_types_search_goes_on_after_a_cut_session_from_where_the_journal_has_it(scaled, tmp_path):
    from endurance.offline import fly
    from tests.support.endurance_run import OfflineStand
    testdir = tmp_path / "T"
    station = OfflineStand()
    fly(testdir, scaled, station, 24, max_s=30.0)
    with Journal.open(testdir) as j:
        texts = {t: j.schedule(t) for t in "ABC"}
        cut_at = j.position().flight
    assert texts["C"] is not None
    c = tomllib.loads(texts["C"])
    test = load_test_file(scaled)
    assert sum(c["durations_s"]) < test.flight_types["C"].duration_s
    # the next session's pieces are made with the journal's durations
    assert np.allclose(FlightTiming(test, texts).programme("C").segment_durations_s, c["durations_s"])
    result = fly(testdir, scaled, station)
    assert result.state == "finished" and result.flights_done == 24 and cut_at <= 24
    with Journal.open(testdir) as j:
        after = tomllib.loads(j.schedule("C"))
    assert after["search"]["flights"] >= c["search"]["flights"]
    assert after["search"]["mode"] == FOUND or after["search"]["flights"] > c["search"]["flights"]
