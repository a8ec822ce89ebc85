"""The running endurance test (endurance.run, endurance.flights) offline: the example's short
flights played back to back by the session's own player, planner and journal writer on the
emulator's coupled lockstep plant of the example rig (no bus; tests/support/endurance_run.py).
Every flight is counted once with every load case in the journal and the turning-point log,
the flight boundaries (where one flight's piece takes over from the one before) are as accurate
as any load case, each flight type learns its own compensation, a stop at the end of a flight,
an inspection, a monitor's alarm and a cut mid-flight end the session where they should, and a
resume glides in along the ratio line and completes the interrupted flight. And what is refused
before anything moves (the command line, no bus)."""
from __future__ import annotations

import json
import subprocess
import sys
from collections import Counter

import numpy as np
import pytest

from endurance import run
from endurance.flights import glide_in, lead_in_samples, line_deviation
from endurance.journal import Journal
from endurance.monitors import MonitorAlarm
from endurance.report import accuracy, end_point_errors, report
from endurance.storage import read_turning_points
from endurance.testfile import load_test_file
from tests.support.endurance_run import EXAMPLE, OfflineStand, copy_short_test, fly

CASES = {"A": 10, "B": 8, "C": 6}


def stand(*args, timeout=120):
    res = subprocess.run([sys.executable, "-m", "stand", *map(str, args)], capture_output=True, text=True,
                         timeout=timeout)
    assert "Traceback" not in res.stderr + res.stdout, res.stderr
    return res


def log_of(testdir):
    t = read_turning_points(testdir)
    return {c: t.column(c).to_pylist() for c in t.column_names}


def load_cases_once(testdir, flights: int, test) -> None:
    """Every flight 1..flights has every load case of its type in the log, once per channel."""
    log = log_of(testdir)
    seen = Counter(zip(log["flight"], log["load_case"], log["channel"]))
    assert all(n == 1 for n in seen.values()), [k for k, n in seen.items() if n > 1][:5]
    for f in range(1, flights + 1):
        kind = test.sequence.slot(f).flight_type
        got = sorted({k for (ff, k, c) in seen if ff == f})
        assert got == list(range(CASES[kind])), (f, kind, got)
    assert max(log["flight"]) == flights


def test_the_geometry_of_a_hand_over_and_a_glide_in():
    y0, level = np.array([0.0, 100.0]), np.array([1000.0, 600.0])
    lead = glide_in(y0, level, 0.002, 30)
    assert lead.shape[0] == 2 and np.all(lead[:, 0] == y0) and np.all(lead[:, 49] == y0)   # held 0.1 s
    assert lead.shape[1] == 50 + round(np.pi * 1000 / 2000 / 0.002)                    # 1000 kgf/s peak
    assert np.allclose(lead[1] - 100, 0.5 * lead[0])                          # one straight line
    assert glide_in(y0, y0, 0.002, 30).shape[1] == 50 + 250                   # at least 0.5 s
    # the next flight's lead-in: the pre-roll's 0.6 s within the landing, at least a delay and a margin
    idx = np.array([0, 500, 1000])
    assert lead_in_samples(np.zeros((1, 1001)), idx, 30, 0.002) == 300
    assert lead_in_samples(np.zeros((1, 1001)), np.array([0, 990, 1000]), 30, 0.002) == 35
    # the deviation from a line: along it none; off it, as % of the channel's range
    Y = np.array([[0.0, 100.0], [500.0, 350.0], [1000.0, 600.0]])
    assert line_deviation(Y, y0, level, np.array([1000.0, 1000.0]))[0] == pytest.approx(0.0, abs=1e-9)
    Y[1, 1] += 20
    pct, i, kgf = line_deviation(Y, y0, level, np.array([1000.0, 1000.0]))
    assert i == 1 and 1.0 < pct < 2.0 and kgf > 0


def test_a_programme_taken_up_at_a_load_case_starts_there_on_a_clock_from_zero():
    p = load_test_file(EXAMPLE).flight_types["A"].programme
    q = p.from_case(3)
    assert q.levels_kgf.shape == (4, 7) and np.array_equal(q.levels_kgf, p.levels_kgf[:, 3:])
    assert q.t_s[0] == 0 and q.turning_idx[0] == 0 and np.array_equal(q.r_kgf, p.r_kgf[:, p.turning_idx[3]:])
    assert q.case_labels == p.case_labels[3:] and "from load case 4" in q.source
    with pytest.raises(Exception, match="load case 10"):
        p.from_case(9)


@pytest.mark.slow
def test_flights_fly_back_to_back_each_counted_once_each_type_learning_its_own_compensation(tmp_path):
    test_file = copy_short_test(tmp_path / "t")
    test = load_test_file(test_file)
    testdir = tmp_path / "T"
    flights = 24                                           # three blocks of 8
    result = fly(testdir, test_file, OfflineStand(), flights)
    assert result.state == "finished" and result.flights_done == flights and result.flights_flown == flights
    with Journal.open(testdir) as journal:
        assert journal.integrity_check() == []
        for t in "ABC":                                    # each type's own, learnt and stored
            tables = journal.compensation(t)
            assert set(tables) == set(test.station.names), t
            assert any('" = ' in text for text in tables.values()), t
        assert journal.events()[-1]["kind"] == "finished"
    load_cases_once(testdir, flights, test)
    # the flight boundaries: each ground level where a flight's piece took over from the one
    # before is reached like any load case (no bump at the hand-over)
    log = log_of(testdir)
    level, reached = np.array(log["level_kgf"]), np.array(log["reached_kgf"])
    ground = np.array([k == 0 and f > 1 for f, k in zip(log["flight"], log["load_case"])])
    assert ground.sum() == 4 * (flights - 1)
    assert np.abs(reached - level)[ground].max() < 25.0               # 0.5 % of the smallest range
    # learning: the last block's peaks and valleys within 0.5 % p95 on every channel, better than
    # the first block's worst channel
    errors = end_point_errors(read_turning_points(testdir))
    last, first = accuracy(errors, errors["block"] == 3), accuracy(errors, errors["block"] == 1)
    assert max(a["p95"] for a in last.values()) <= 0.5, last
    assert max(a["p95"] for a in last.values()) < max(a["p95"] for a in first.values())
    # prepared pieces of a flight type with the same programme are used again
    record = json.loads(result.path.read_text())
    assert record["pieces"]["built"] + record["pieces"]["reused"] == flights - 1
    assert record["loading"]["approach_deviation"]["pct_of_range"] < 1.0


def test_an_interrupted_flight_is_completed_from_its_load_case_counted_once(tmp_path):
    test_file = copy_short_test(tmp_path / "t")
    test = load_test_file(test_file)
    testdir = tmp_path / "T"
    plant = OfflineStand()
    cut = fly(testdir, test_file, plant, 10, max_s=9.0)        # cut in flight 3 or 4, not at its start
    with Journal.open(testdir) as journal:
        pos = journal.position()
        assert cut.state == "stopped" and journal.integrity_check() == []
    assert pos.attempt == 1 and pos.load_case >= 1, pos
    done_before = cut.flights_done
    resumed = fly(testdir, test_file, plant)
    assert resumed.state == "finished" and resumed.flights_done == 10
    assert resumed.flights_flown == 10 - done_before               # the interrupted one counted once
    info = resumed.loading
    assert info["flight"] == pos.flight and info["load_case"] == pos.load_case     # glided into the one before
    assert np.allclose(info["forces_found_kgf"], plant.runs[0].y[:, -1], atol=8.0)   # noise, 0.2 s of drift
    assert info["approach_deviation"]["pct_of_range"] < 2.0
    with Journal.open(testdir) as journal:
        assert journal.integrity_check() == []
        rec = journal.flight(pos.flight)
        assert rec.attempt == 1 and not rec.rerun and rec.interruptions == 0
        kinds = [e["kind"] for e in journal.events()]
    assert kinds.count("started") == 2 and kinds.count("loading") == 2
    load_cases_once(testdir, 10, test)
    r = report(testdir)
    assert r["flights_done"] == 10 and len(r["sessions"]) == 2 and r["sessions"][1]["kind"] == "resume"


def test_a_stop_at_the_end_of_a_flight_an_inspection_and_an_alarm_end_the_session_there(tmp_path):
    test_file = copy_short_test(tmp_path / "t")
    text = test_file.read_text().replace("at_flight = 100", "at_flight = 7")
    test_file.write_text(text)
    testdir = tmp_path / "T"
    plant = OfflineStand()

    def ask_to_stop(end, line):
        if end.number == 2:
            run.request_stop(testdir)                      # the writer thread polls the stop file
    first = fly(testdir, test_file, plant, 12, on_flight=ask_to_stop)
    assert first.state == "stopped" and first.reason.startswith("operator: stopped at the end of flight")
    n = first.flights_done
    assert 2 <= n < 7 and first.reason.endswith(f"flight {n}")
    with Journal.open(testdir) as journal:
        assert journal.position().attempt is None and journal.position().flight == n + 1
        assert not (testdir / run.STOP_FILE).exists()
    second = fly(testdir, test_file, plant)
    assert second.state == "stopped" and second.flights_done == 7
    assert second.reason == "inspection after flight 7: half way: look at the root joint"

    def alarm(end):
        return MonitorAlarm("script", "unload", ("root",), f"flight {end.number}: the flow to the end points rose") \
            if end.number == 9 else None
    third = fly(testdir, test_file, plant, hook=alarm)
    assert third.state == "stopped" and third.reason.startswith("monitor_alarm: flight 9")
    assert 9 <= third.flights_done < 12
    with Journal.open(testdir) as journal:
        events = journal.events()
        assert journal.integrity_check() == []
    assert any(e["kind"] == "script_alarm" and e["channel"] == "root" and e["flight"] == 9 for e in events)
    assert any(e["kind"] == "inspection" for e in events)
    assert any(e["kind"] == "stop_requested" for e in events)
    assert fly(testdir, test_file, plant).state == "finished"
    load_cases_once(testdir, 12, load_test_file(test_file))


@pytest.mark.slow
def test_a_stand_is_a_station_of_one_channel_its_flights_flown_the_same_way(tmp_path):
    from tests.support.endurance import write_stand_test
    test_file = write_stand_test(tmp_path / "t", flights=4, counts={"A": 1, "B": 1, "C": 2})
    test_file.write_text(test_file.read_text().replace("rate_kgf_s = 2500.0", "rate_kgf_s = 6000.0"))
    test = load_test_file(test_file)
    result = fly(tmp_path / "T", test_file, OfflineStand(stand=True))
    assert result.state == "finished" and result.flights_done == 4
    assert "approach_deviation" not in result.loading            # one channel: no ratios
    log = log_of(tmp_path / "T")
    assert set(log["channel"]) == {"stand"}
    cases = {t: ft.load_cases for t, ft in test.flight_types.items()}
    for f in range(1, 5):
        got = sorted(k for ff, k in zip(log["flight"], log["load_case"]) if ff == f)
        assert got == list(range(cases[test.sequence.slot(f).flight_type])), f
    with Journal.open(tmp_path / "T") as journal:
        assert journal.integrity_check() == [] and set(journal.compensation("C")) == {"stand"}


@pytest.mark.slow
def test_what_is_refused_before_anything_moves(tmp_path):
    test_file = copy_short_test(tmp_path / "t")
    testdir = tmp_path / "T"
    test = load_test_file(test_file)
    fp = test.fingerprint()
    Journal.create(testdir, test.name, 20, test.station.names, fp.digest, fp.to_json(), test_file.read_text()).close()
    (testdir / run.TEST_RECORD).write_text(json.dumps({"test_file": str(test_file)}))
    # a second start in a directory that holds a test
    res = stand("test", "start", test_file, "--out", testdir, "--lockstep")
    assert res.returncode == 2 and "already holds a test" in res.stderr
    # a resume of a test whose programme or station changed, naming what
    csv = test_file.parent / "test-flights" / "C.csv"
    csv.write_text(csv.read_text().replace("4058.3", "4158.3"))
    (test_file.parent / "rig.toml").write_text((test_file.parent / "rig.toml").read_text()
                                                .replace("force_limit_kgf = 9000", "force_limit_kgf = 8800", 1))
    res = stand("test", "resume", testdir, "--lockstep")
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert "flight type C's load cases changed" in res.stderr
    assert "the rig file's ranges or force limits changed" in res.stderr
    # a target that is not a whole number of flights, or fewer than one more
    for bad in ("+0", "ten", "+x"):
        res = stand("test", "resume", testdir, "--lockstep", "--flights", bad)
        assert res.returncode == 2 and f"--flights {bad}: give a whole number >= 1" in res.stderr, res.stderr
    # a stop of a test no session runs; a status and a report of a directory without a test
    res = stand("test", "stop", testdir)
    assert res.returncode == 2 and "no session runs the test" in res.stderr
    for action in ("status", "report"):
        res = stand("test", action, tmp_path / "nowhere")
        assert res.returncode == 2 and "holds no test" in res.stderr
    # a flight type the valves cannot follow, named, before any bus is opened
    test_file.write_text(test_file.read_text().replace("rate_kgf_s = 6000.0", "rate_kgf_s = 60000.0"))
    res = stand("test", "plan", test_file)
    assert res.returncode == 2 and "[flight.A]" in res.stderr and "cannot follow this rate" in res.stderr
    res = stand("test", "start", test_file, "--out", tmp_path / "T2", "--lockstep", "--bus", "udp_loopback:x")
    assert res.returncode == 2 and "--bus: the rig's buses are its file's" in res.stderr


def test_the_plan_gives_each_flight_types_time_beside_its_minimum_the_duration_and_the_storage():
    res = stand("test", "plan", EXAMPLE, "--json")
    assert res.returncode == 0, res.stderr
    plan = json.loads(res.stdout)
    assert plan["block_size"] == 8 and [t["name"] for t in plan["flight_types"]] == ["A", "B", "C"]
    for t in plan["flight_types"]:
        assert t["minimum_s"] < t["time_s"] and t["load_cases"] == CASES[t["name"]]
    per = sum(t["per_block"] * t["time_s"] for t in plan["flight_types"]) / 8
    assert plan["per_flight_s"] == pytest.approx(per) and plan["duration_s"] == pytest.approx(200 * per)
    assert plan["storage_bytes"]["total"] > 0
