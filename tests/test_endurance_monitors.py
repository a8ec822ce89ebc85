"""The monitors of a running test (endurance.monitors): their states go into the journal and come
back so that the statistics go on exactly; a flight interrupted and completed is not fed to the
trend; an alarm is one concept the session acts on, naming the channels."""
from __future__ import annotations

import json
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from core.errors import ParameterError
from endurance.journal import Journal, MonitorStep
from endurance.monitors import (GAIN, TREND, GainWatch, MonitorAlarm, TrendWatch, after_inspection,
                                detector_from_rows, detector_rows, fed)
from endurance.testfile import load_test_file
from endurance.trends import TrendDetector, TrendOptions
from loading.gain_monitor import GainMonitor, MonitorOptions
from plant import PlantModel
from plant.rig import RigModel
from tests.support.endurance_run import copy_short_test

NAMES = ["root", "inner", "outer", "tip"]
G = np.array([[120.0, 36, 0, 0], [30, 100, 30, 0], [0, 42, 140, 42], [0, 0, 33, 110]])


def flights(rng, n, types=("A", "B"), cases=6, crack_from=None):
    """Synthetic flights (number, type, E, F, P): each type's end points and flows, a little noise,
    inner 3 % more flow from ``crack_from``."""
    base = {t: rng.uniform(500, 3000, (4, cases)) for t in types}
    for k in range(1, n + 1):
        t = types[k % len(types)]
        E = base[t] + rng.normal(0, 1.0, (4, cases))
        steps = np.diff(np.concatenate([E[:, :1], E], axis=1), axis=1)
        F = np.linalg.solve(G, steps) * (1 + rng.normal(0, 0.002, (4, 1)))
        if crack_from is not None and k >= crack_from:
            F[1] += 0.03 * steps[1] / G[1, 1]
        yield k, t, E, F, F.copy()


def test_the_trends_journal_rows_give_back_the_same_statistic_bit_for_bit():
    rng = np.random.default_rng(4)
    options = TrendOptions(learn_flights=12)
    a = TrendDetector(NAMES, G, options)
    data = list(flights(rng, 90, crack_from=70))
    for f in data[:40]:                      # both types learnt and tested a while
        a.add_flight(*f)
    rows = detector_rows(a)
    assert set(rows) == {TREND, "trend.type.A", "trend.type.B"}
    b = detector_from_rows(json.loads(json.dumps(rows)))
    alarms = {}
    for d, name in ((a, "a"), (b, "b")):
        alarms[name] = [d.add_flight(*f) for f in data[40:]]
    assert [x and x.to_dict() for x in alarms["a"]] == [x and x.to_dict() for x in alarms["b"]]
    assert any(alarms["a"]) and detector_rows(a) == detector_rows(b)
    assert json.loads(detector_rows(a)[TREND])["type_order"] == ["B", "A"]   # first flown first


@pytest.fixture
def trend_test(tmp_path):
    path = copy_short_test(tmp_path / "t")
    path.write_text(path.read_text() + '\n[monitor.trend]\naction = "hold"\nlearn_flights = 9\n')
    return load_test_file(path)


def new_journal(testdir, test):
    fp = test.fingerprint()
    return Journal.create(testdir, test.name, 100, test.station.names, fp.digest, fp.to_json(), "")


def test_a_session_takes_the_trend_up_from_the_journal_and_only_the_parts_that_changed_are_written(tmp_path, trend_test):
    journal = new_journal(tmp_path / "T", trend_test)
    watch = TrendWatch.for_session(trend_test, journal)
    assert watch.detector.names == NAMES and watch.detector.options.learn_flights == 9
    assert np.array_equal(watch.detector.G, trend_test.controller.G)
    det = watch.detector
    rng = np.random.default_rng(1)
    written = []
    for k, t, E, F, P in flights(rng, 20, cases=6):
        det.add_flight(k, t, E, F, P)
        det.history.clear()
        changed = watch._changed()
        written.append(set(changed))
        journal.record_monitors(MonitorStep(changed), k)
    assert written[0] == {TREND, "trend.type.B"} and written[1] == {TREND, "trend.type.A"}
    again = TrendWatch.for_session(trend_test, journal)
    assert detector_rows(again.detector) == detector_rows(det)
    assert again._changed() == {}                           # nothing new to write
    # the action may change between sessions; another option goes on as it began, noted
    from dataclasses import replace
    changed = replace(trend_test, trend=replace(trend_test.trend, action="unload", shift_pct=2.0))
    later = TrendWatch.for_session(changed, journal)
    assert later.detector.options.action == "unload" and later.detector.options.shift_pct == 1.0
    assert "shift_pct = 2.0 changed since the trend began; it goes on as it began (shift_pct = 1.0)" in \
        journal.events()[-1]["message"]
    journal.close()


def test_a_flight_interrupted_and_completed_a_sessions_first_or_of_a_timing_still_searched_is_not_fed(
        tmp_path, trend_test):
    journal = new_journal(tmp_path / "T", trend_test)
    watch = TrendWatch.for_session(trend_test, journal)
    record = SimpleNamespace(whole=False, number=3, piece=SimpleNamespace(start_ways=None))
    assert watch.flight(record, True) == (MonitorStep(), None)            # interrupted, completed
    record.whole = True
    assert watch.flight(record, False) == (MonitorStep(), None)           # its type's timing searched
    record.piece.start_ways = np.ones(4)
    assert watch.flight(record, True) == (MonitorStep(), None)            # a session's first: glided in
    assert watch.detector.last_flight is None and watch.detector.history == []
    assert fed(SimpleNamespace(whole=True, piece=SimpleNamespace(start_ways=None)), True)
    journal.close()


def test_an_alarm_is_an_event_naming_its_channels():
    alarm = MonitorAlarm("trend", "unload", ("inner", "tip"), "channel inner needs 3.0 % more flow")
    assert alarm.event() == ("trend_alarm", "inner,tip", "channel inner needs 3.0 % more flow")
    assert MonitorAlarm("gain", "note", (), "x").channel is None


def gain_monitor(follow: bool = True) -> GainMonitor:
    model = RigModel([PlantModel.from_spec("base") for _ in NAMES], G, NAMES)
    return GainMonitor(model, 0.002, MonitorOptions(block_s=1.0, follow=follow, fall_pct=2.0))


def drive_gain(monitor: GainMonitor, seconds: float, seed: int, softer: float = 1.0) -> None:
    """A pass of square-wave commands on the model's G (inner's row ``softer``), a little noise."""
    rng = np.random.default_rng(seed)
    n = int(seconds / 0.002)
    Gt = G.copy()
    Gt[1] *= softer
    y = np.zeros(4)
    sent = [np.zeros(4)] * 40
    monitor.begin_pass()
    for k in range(n):
        u = np.where((k // 200 + np.arange(4)) % 2, 10.0, -10.0)
        sent.append(u)
        y = y + 0.002 * Gt @ sent[-26] + rng.normal(0, 0.5, 4)
        monitor.add(y, u, np.ones(4))
    monitor.end_pass()


def test_the_gain_monitors_state_goes_on_after_a_stop_as_if_none_had_been():
    whole, cut = gain_monitor(), gain_monitor()
    for m in (whole, cut):
        drive_gain(m, 6.0, 1)
    restored = gain_monitor()
    restored.restore(json.loads(json.dumps(cut.state())))
    for m in (whole, restored):
        drive_gain(m, 6.0, 2, softer=0.9)             # inner's row 10 % softer: a fall
    assert whole.state() == restored.state() and whole.alarm is not None and whole.alarm_channel == 1
    blocks = [b.to_dict() for b in whole.channels[1].blocks if b.pass_index == 2]
    assert blocks == [b.to_dict() for b in restored.channels[1].blocks]
    assert blocks[-1]["index"] == whole.channels[1].closed_blocks


def test_the_gain_watch_writes_its_blocks_once_and_its_alarm_once(tmp_path, trend_test):
    journal = new_journal(tmp_path / "T", trend_test)
    watch = GainWatch(gain_monitor())
    drive_gain(watch.monitor, 4.0, 1)
    step, alarm = watch.step(7)
    assert alarm is None and json.loads(step.states[GAIN])["alarm"] is None
    assert len(step.rows) == 4 * watch.monitor.channels[0].closed_blocks
    assert {r[1] for r in step.rows} == {7} and len({(r[1], r[2]) for r in step.rows}) == len(step.rows)
    assert all(not c.blocks for c in watch.monitor.channels)        # written: not kept in memory
    drive_gain(watch.monitor, 6.0, 2, softer=0.9)
    step, alarm = watch.step(8)
    assert alarm is not None and alarm.channels == ("inner",) and alarm.kind == "gain_alarm"
    assert step.events == [alarm.event()] and "every valve holds" not in alarm.message
    assert watch.step(9)[1] is None                              # once
    journal.record_monitors(step, 8)
    assert GainWatch.for_session(trend_test, journal) is None      # [monitor.gain] is off in this file
    journal.close()


# -- in the running test (offline: endurance.offline, the example rig's plant without a bus) ------------
def history(testdir, monitor="trend"):
    with Journal.open(testdir) as j:
        return [json.loads(r) for _, _, r in j.monitor_history(monitor)]


@pytest.mark.slow
def test_the_trends_alarm_unloads_naming_the_channel_its_state_going_on_across_sessions(tmp_path):
    from endurance.offline import fly
    from plant.rig import StructureChange
    from tests.support.endurance_run import OfflineStand
    test_file = copy_short_test(tmp_path / "t")
    test_file.write_text(test_file.read_text().replace("at_flight = 100", "at_flight = 26")
                         + '\n[monitor.trend]\naction = "unload"\nlearn_flights = 9\n')
    testdir = tmp_path / "T"
    station = OfflineStand()
    cut = fly(testdir, test_file, station, 40, max_s=40.0)         # a session cut in its 12th flight or so
    with Journal.open(testdir) as j:
        interrupted = j.position().flight
        assert j.position().load_case > 0 and cut.state == "stopped"
        before = j.monitor_states(TREND)
    assert fly(testdir, test_file, station).reason.startswith("inspection after flight 26")
    rows = history(testdir)
    fed_flights = [r["flight"] for r in rows]
    # every flight handed over from the one before, run whole, once; not the first (it glided in)
    # nor the interrupted one (completed in the next session)
    assert fed_flights == sorted(set(range(2, 27)) - {interrupted})
    with Journal.open(testdir) as j:
        state = detector_from_rows(j.monitor_states(TREND))
    assert state.last_flight == 26 and state.alarms == []
    assert {t: b.count for t, b in state._types.items()} == {
        t: sum(r["flight_type"] == t for r in rows) for t in "ABC"}
    assert detector_from_rows(before).last_flight == max(f for f in fed_flights if f < interrupted)
    assert "C" in state.armed_types() and any(r["tested"] for r in rows)
    # inner's attachment 3 % softer from here: the alarm unloads, naming inner
    m = station.truth
    station.truth = RigModel(m.channels, m.G, m.names, [StructureChange(1, 0.97, station.stand_time_s)])
    cracked = fly(testdir, test_file, station)
    assert cracked.state == "stopped" and cracked.reason.startswith("monitor_alarm: flight ")
    with Journal.open(testdir) as j:
        alarm = [e for e in j.events() if e["kind"] == "trend_alarm"]
        last = detector_from_rows(j.monitor_states(TREND))
    assert len(alarm) == 1 and alarm[0]["channel"].split(",")[0] == "inner", alarm
    assert 28 <= alarm[0]["flight"] <= 34 and "channel inner needs" in alarm[0]["message"]
    assert alarm[0]["message"].endswith("every channel unloads keeping the load ratios")
    assert last.latched[0, 1] and last.alarms[0].flight == alarm[0]["flight"]
    status = json.loads(subprocess.run([sys.executable, "-m", "stand", "test", "status", str(testdir), "--json"],
                                       capture_output=True, text=True, timeout=120).stdout)
    assert any(e["kind"] == "trend_alarm" and e["channel"].startswith("inner") for e in status["events"])
    # not resumed before the operator says what the inspection found
    with pytest.raises(ParameterError, match=r"stopped for the trend's alarm on inner.*--inspected.*--repaired"):
        fly(testdir, test_file, station)
    # inspected, nothing repaired: inner is watched again and, still softer, alarms again
    again = fly(testdir, test_file, station, found="inspected")
    assert again.inspection.startswith("inspected after the alarm on inner: nothing to repair")
    assert again.state == "stopped" and again.reason.startswith("monitor_alarm: flight ")
    with Journal.open(testdir) as j:
        alarms = [e for e in j.events() if e["kind"] == "trend_alarm"]
        said = [e for e in j.events() if e["kind"] == "trend_acknowledged"]
    assert len(alarms) == 2 and alarms[1]["channel"].split(",")[0] == "inner", alarms
    assert said[0]["channel"] == "inner" and alarms[1]["flight"] > alarm[0]["flight"]
    # repaired: the structure is a new one, its baselines learnt again; no alarm to the end
    fixed = fly(testdir, test_file, station, found="repaired")
    assert fixed.state == "finished" and fixed.inspection.startswith("repaired after the alarm on inner")
    with Journal.open(testdir) as j:
        assert [e["kind"] for e in j.events()].count("trend_alarm") == 2 and j.integrity_check() == []
        relearnt = detector_from_rows(j.monitor_states(TREND))
    assert not relearnt.latched.any() and relearnt.last_flight > alarms[1]["flight"]
    with Journal.open(testdir, write=True) as j, pytest.raises(ParameterError, match="no trend alarm is on"):
        after_inspection(load_test_file(test_file), j, "inspected")


@pytest.mark.slow
def test_the_gain_monitors_alarm_holds_naming_the_channel_and_is_not_raised_again_after_the_resume(tmp_path):
    from endurance.offline import fly
    from tests.support.endurance_run import OfflineStand
    test_file = copy_short_test(tmp_path / "t")
    test_file.write_text(test_file.read_text() + '\n[monitor.gain]\nmode = "watch"\naction = "hold"\n'
                                                 'block_s = 4.0\nfall_pct = 4.0\n')
    testdir = tmp_path / "T"
    station = OfflineStand()
    first = fly(testdir, test_file, station, 30, max_s=25.0)
    assert first.reason.startswith("cut")
    blocks = history(testdir, GAIN)
    assert blocks and all(b["alarm"] is None for b in blocks)
    assert len({(b["channel"], b["index"]) for b in blocks}) == len(blocks)
    with Journal.open(testdir) as j:
        state = json.loads(j.monitor_states(GAIN)[GAIN])
    assert state["alarm"] is None and state["channels"]["root"]["closed_blocks"] == \
        max(b["index"] for b in blocks if b["channel"] == "root")
    # root's valve gives 15 % less flow from here
    m = station.truth
    G = m.G.copy()
    G[:, 0] *= 0.85
    station.truth = RigModel(m.channels, G, m.names)
    held = fly(testdir, test_file, station)
    assert held.state == "stopped" and held.reason.startswith("gain_alarm: channel root"), held.reason
    with Journal.open(testdir) as j:
        events = [e for e in j.events() if e["kind"] == "gain_alarm"]
        state = json.loads(j.monitor_states(GAIN)[GAIN])
    assert [e["channel"] for e in events] == ["root"] and events[0]["message"].endswith("every valve holds")
    assert state["alarm"][0] == "fall" and state["alarm_channel"] == 0
    later = history(testdir, GAIN)
    assert all(b in later for b in blocks) and len(later) > len(blocks)        # kept, and more
    assert fly(testdir, test_file, station).state == "finished"            # latched: not raised again
    with Journal.open(testdir) as j:
        assert [e["kind"] for e in j.events()].count("gain_alarm") == 1
