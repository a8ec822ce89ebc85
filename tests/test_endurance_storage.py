"""An endurance test's data, bounded (endurance.storage): the turning-point log holds every end
point once, partitioned by block and read whole by pyarrow.dataset, a finished block compacted
and its end points pruned from the journal; what a kill leaves is never read twice; a failed
write leaves no file; the rolling window keeps its length; an event window is a run directory
the analysis reads (rig and stand); the estimate's figures are measured ones."""
from __future__ import annotations

import dataclasses
import errno
import json

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest

from core.errors import DataError
from endurance.journal import EndPoint, Journal
from endurance.storage import (CALIBRATION, TURNING_POINT_SCHEMA, Calibration, SignalWindow,
                               TurningPointLog, calibrate, continuous_time, event_windows, read_turning_points,
                               rig_meta, storage_estimate, turning_point_files,
                               write_parquet_atomic)
from endurance.testfile import load_test_file

from tests.support.endurance import EXAMPLE_TEST, write_stand_test

CHANNELS = ["root", "inner", "outer", "tip"]
BLOCK = 5


def journal_with_flights(testdir, flights: int, load_cases: int = 4) -> Journal:
    j = Journal.create(testdir, "t", 1000, CHANNELS, "fp")
    j.start()
    for n in range(1, flights + 1):
        fly(j, n, load_cases)
    return j


def fly(j: Journal, n: int, load_cases: int = 4, first: int = 0) -> None:
    if first == 0:
        j.begin_flight(n, "AB"[n % 2], (n - 1) // BLOCK + 1, (n - 1) % BLOCK + 1, load_cases)
    for k in range(first, load_cases):
        j.commit_load_case(n, k, [EndPoint(c, 1000.0 * i + 10 * k, 1000.0 * i + 10 * k + 0.25 * i,
                                           5.0 + i, time_s=1.8e9 + 100 * n + k)
                                  for i, c in enumerate(CHANNELS)])


def test_the_log_holds_every_end_point_once_partitioned_by_block(tmp_path):
    j = journal_with_flights(tmp_path, 7)
    log = TurningPointLog(tmp_path, BLOCK)
    assert log.export(j) == 7 and log.exported_through == 7
    fly(j, 8)
    assert log.export(j) == 1 and log.export(j) == 0
    names = sorted(p.relative_to(tmp_path / "turning_points").as_posix() for p in turning_point_files(tmp_path))
    assert names == ["block=000001/part-000000001-000000005.parquet",
                     "block=000002/part-000000006-000000007.parquet",
                     "block=000002/part-000000008-000000008.parquet"]
    whole = ds.dataset(tmp_path / "turning_points", partitioning="hive").to_table()
    assert whole.num_rows == 8 * 4 * 4
    assert sorted(set(whole.column("block").to_pylist())) == [1, 2]
    t = read_turning_points(tmp_path).sort_by([("flight", "ascending"), ("load_case", "ascending"),
                                               ("channel", "ascending")])
    assert t.schema == TURNING_POINT_SCHEMA
    row = t.filter(pa.compute.equal(t["channel"], "outer")).slice(0, 1).to_pylist()[0]
    assert row["flight"] == 1 and row["flight_type"] == "B" and row["level_kgf"] == 2000.0
    assert row["reached_kgf"] == 2000.5 and row["error_kgf"] == pytest.approx(0.5)
    assert row["flow_pct"] == 7.0 and row["time"] == 1.8e9 + 100 and row["rerun"] is False
    # the finished block's end points left the journal; the others stay until their block ends
    assert j.end_points(1, 5) == [] and len(j.end_points(6, 8)) == 3 * 4 * 4
    fly(j, 9)
    fly(j, 10)
    log.export(j)
    assert [p.name for p in turning_point_files(tmp_path)] == [
        "part-000000001-000000005.parquet", "part-000000006-000000010.parquet"]
    assert read_turning_points(tmp_path).num_rows == 10 * 4 * 4 and j.end_points(1, 10) == []


def test_a_rerun_flight_keeps_both_attempts_the_second_marked(tmp_path):
    j = journal_with_flights(tmp_path, 1)
    j.begin_flight(2, "A", 1, 2, 4)
    j.commit_load_case(2, 0, [EndPoint("root", 1.0, 2.0)])
    j.begin_flight(2, "A", 1, 2, 4)                  # interrupted: run again from the first
    for k in range(4):
        j.commit_load_case(2, k, [EndPoint("root", 1.0 + k, 2.0 + k)])
    TurningPointLog(tmp_path, BLOCK).export(j)
    t = read_turning_points(tmp_path, filter=ds.field("flight") == 2).to_pylist()
    assert [(r["attempt"], r["load_case"], r["rerun"]) for r in t] == \
        [(1, 0, False), (2, 0, True), (2, 1, True), (2, 2, True), (2, 3, True)]


def test_what_a_kill_leaves_is_never_read_twice_and_is_cleaned_on_open(tmp_path):
    j = journal_with_flights(tmp_path, 3)
    log = TurningPointLog(tmp_path, BLOCK)
    log.export(j)
    fly(j, 4)
    fly(j, 5)
    compact, log.compact = log.compact, lambda block: None
    log.export(j, prune=False)
    block = tmp_path / "turning_points" / "block=000001"
    small = {p.name: p.read_bytes() for p in block.iterdir()}
    assert sorted(small) == ["part-000000001-000000003.parquet", "part-000000004-000000005.parquet"]
    compact(1)
    # a kill between the compaction's rename and its removals, and one inside a write
    for name, data in small.items():
        (block / name).write_bytes(data)
    (block / ".part-000000006-000000006.parquet.123.tmp").write_bytes(b"PAR1 torn")
    assert len(list(block.iterdir())) == 4
    assert read_turning_points(tmp_path).num_rows == 5 * 4 * 4
    assert ds.dataset(tmp_path / "turning_points", partitioning="hive").count_rows() == 5 * 4 * 4 * 2
    again = TurningPointLog(tmp_path, BLOCK)
    assert sorted(p.name for p in block.iterdir()) == ["part-000000001-000000005.parquet"]
    assert again.exported_through == 5
    assert ds.dataset(tmp_path / "turning_points", partitioning="hive").count_rows() == 5 * 4 * 4


def test_a_block_left_uncompacted_by_a_kill_is_compacted_on_open(tmp_path):
    j = journal_with_flights(tmp_path, 3)
    log = TurningPointLog(tmp_path, BLOCK)
    log.export(j)
    fly(j, 4)
    fly(j, 5)
    log.compact = lambda block: None                 # killed before it compacted
    log.export(j, prune=False)
    assert len(turning_point_files(tmp_path)) == 2
    TurningPointLog(tmp_path, BLOCK).export(j)
    assert [p.name for p in turning_point_files(tmp_path)] == ["part-000000001-000000005.parquet"]
    assert j.end_points(1, 5) == []                  # and the journal pruned at the next export


def test_a_failed_write_leaves_no_file_and_says_so(tmp_path, monkeypatch):
    table = pa.table({"x": [1.0, 2.0]})
    path = write_parquet_atomic(table, tmp_path / "a.parquet")

    def full(*args, **kwargs):
        with open(args[1], "wb") as fh:
            fh.write(b"PAR1 half")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(pq, "write_table", full)
    with pytest.raises(DataError, match=r"cannot write .*a.parquet: .*No space left on device; "
                                        r"nothing of it was written"):
        write_parquet_atomic(pa.table({"x": [3.0]}), path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.parquet"]
    assert pq.read_table(path).column("x").to_pylist() == [1.0, 2.0]


def rows(channels, first_s: float, seconds: float, period_s: float = 0.002, t0: float = 0.0):
    n = int(round(seconds / period_s))
    t = t0 + np.arange(n) * period_s
    out = {"t": t, "cycle": np.arange(n), "sync_time": 1.8e9 + first_s + np.arange(n) * period_s}
    rng = np.random.default_rng(int(first_s))
    names = channels or [None]
    for i, c in enumerate(names):
        sfx = f".{c}" if c else ""
        r = 2000.0 + 1000.0 * np.sin(2 * np.pi * 0.5 * t + i)
        y = r + rng.normal(0, 2.0, n)
        out.update({f"r{sfx}": r, f"y{sfx}": y, f"u{sfx}": np.gradient(r, period_s) / 120.0,
                    f"y_counts{sfx}": np.round(y * 98.0665).astype(np.int32),
                    f"spool{sfx}": np.gradient(r, period_s) / 120.0,
                    f"valve_status{sfx}": np.full(n, 0x27, np.uint16), f"stale{sfx}": np.zeros(n, bool)})
    return out


def test_the_rolling_window_keeps_its_length_and_an_event_window_is_a_run(tmp_path):
    from analysis import load_all
    from gateway.runs import load_run
    test = load_test_file(EXAMPLE_TEST, check_controller=False)
    w = SignalWindow(tmp_path, CHANNELS, 0.002, rolling_window_s=20.0, event_window_s=3.0,
                     chunk_s=5.0, meta=rig_meta(test.station))
    for k in range(12):                                  # 60 s in 5-s appends
        w.append_rows(rows(CHANNELS, 5.0 * k, 5.0, t0=5.0 * k))
        if k == 2:
            event = w.mark_event("limit", "force limit indicated", time_s=1.8e9 + 12.0,
                                 channel="tip", flight=42)
        w.sync()
        chunks = w.chunks()
        assert len(chunks) == min(k + 1, 4)            # a chunk's rows full: written at once
        if chunks:
            assert (chunks[-1][1] - chunks[0][0]) / 1000.0 <= 20.0
            assert all((b - a) / 1000.0 < 5.0 for a, b, _ in chunks)
    assert w.close() == [event]
    assert event.path.parent == tmp_path / "events" and event.path.name.endswith("-limit-tip-f42")
    run = load_run(event.path)
    assert run.channels == CHANNELS and len(run) == 3001
    assert run.meta["event"]["kind"] == "limit" and run.meta["event"]["truncated"] is False
    assert run.sync_time[0] == pytest.approx(1.8e9 + 9.0) and run.sync_time[-1] == pytest.approx(1.8e9 + 15.0)
    tip = load_run(event.path, channel="tip")
    assert tip.meta["channel"] == "tip" and np.isfinite(tip.y).all()
    records = load_all([event.path], channel="tip")
    assert len(records) == 1 and len(records[0].t) == 3001 and records[0].notes == []


def test_a_kill_while_an_event_window_is_written_leaves_no_window_without_its_run_json(tmp_path, monkeypatch):
    import endurance.storage as storage
    w = SignalWindow(tmp_path, CHANNELS, 0.002, rolling_window_s=4.0, event_window_s=1.0, chunk_s=1.0)
    w.append_rows(rows(CHANNELS, 0.0, 3.0))
    w.mark_event("limit", "force limit indicated", time_s=1.8e9 + 1.0, channel="tip", flight=7)

    def killed(path, data):                               # the process dies before run.json is in
        raise OSError("killed")

    monkeypatch.setattr(storage, "write_json", killed)
    with pytest.raises((OSError, DataError)):
        w.close()
    left = [p for p in (tmp_path / "events").iterdir()]
    assert [p.name.startswith(".") for p in left] == [True], left     # signals written, hidden
    assert event_windows(tmp_path) == []
    monkeypatch.undo()
    again = SignalWindow(tmp_path, CHANNELS, 0.002, rolling_window_s=4.0, event_window_s=1.0, chunk_s=1.0)
    assert list((tmp_path / "events").iterdir()) == []                 # the next open removes it
    again.close()


def test_a_stands_event_window_is_a_one_channel_run_and_an_event_at_the_end_is_kept(tmp_path):
    from analysis import load_all
    from gateway.runs import load_run
    w = SignalWindow(tmp_path, None, 0.002, rolling_window_s=10.0, event_window_s=2.0, chunk_s=2.0)
    # two passes, each with t from 0 (a flight each), a second apart on the wall clock
    w.append_rows(rows(None, 0.0, 4.0))
    w.append_rows(rows(None, 5.0, 4.0))
    between = w.mark_event("note", "between two flights", time_s=1.8e9 + 5.0)
    end = w.mark_event("interlock", "hydraulic pressure low")     # at the last row
    assert w.close() == [between, end]
    run = load_run(between.path)
    assert run.channels == [] and run.meta["event"]["truncated"] is False
    assert np.all(np.diff(run.t) > 0)                    # t made to increase over the restart
    records = load_all([between.path])
    assert len(records) == 2 and len(records[0].t) == 500 and len(records[1].t) >= 1000   # split at the gap
    run = load_run(end.path)
    assert run.meta["event"]["truncated"] is True and len(run) == 1001       # 2 s before it, none after
    assert run.sync_time[-1] == pytest.approx(1.8e9 + 9.0 - 0.002)


def test_in_lockstep_the_windows_hold_the_stands_seconds_not_the_walls(tmp_path):
    """A lockstep run 8x faster than real time: the rolling window keeps rolling_window_s of
    the stand's rows (what the plan counts), an event window ±event_window_s of the stand's
    time; a second session on the same directory numbers on from what the first left."""
    from gateway.runs import load_run
    fast = 8.0
    def lockstep_rows(first_s: float, seconds: float):
        out = rows(CHANNELS, first_s, seconds, t0=first_s)
        out["sync_time"] = 1.8e9 + (out["t"] - out["t"][0]) / fast + first_s / fast
        return out
    w = SignalWindow(tmp_path, CHANNELS, 0.002, rolling_window_s=20.0, event_window_s=3.0, chunk_s=5.0)
    for k in range(12):                                  # 60 s of stand time in 7.5 s of wall
        w.append_rows(lockstep_rows(5.0 * k, 5.0))
        if k == 6:
            event = w.mark_event("interlock", "spike", time_s=1.8e9 + 31.0 / fast)
        w.sync()
    rows_kept = sum(pq.read_metadata(p).num_rows for _, _, p in w.chunks())
    assert rows_kept == 10_000                            # 20 s of the stand at 2 ms
    assert w.close() == [event]
    run = load_run(event.path)
    assert len(run) == 3001 and run.t[0] == pytest.approx(28.0) and run.t[-1] == pytest.approx(34.0)
    assert run.meta["event"]["truncated"] is False
    # the next session: its event at its start reaches back into the last one's rows
    w2 = SignalWindow(tmp_path, CHANNELS, 0.002, rolling_window_s=20.0, event_window_s=3.0, chunk_s=5.0)
    again = w2.mark_event("resume", "after the stop", time_s=1.8e9 + 60.0 / fast + 0.5)
    w2.append_rows({**rows(CHANNELS, 60.5, 10.0),
                    "sync_time": 1.8e9 + 60.0 / fast + 0.5 + np.arange(5000) * 0.002 / fast})
    assert w2.close() == [again]
    run = load_run(again.path)
    # 0.5 s of wall between the sessions: 2.5 s of the first one's last rows, 3 s of the second
    assert abs(len(run) - (1250 + 1501)) <= 1 and run.meta["event"]["truncated"] is False
    assert sum(pq.read_metadata(p).num_rows for _, _, p in w2.chunks()) == 10_000


def test_a_trip_acted_on_a_timeout_after_its_onset_keeps_the_stand_up_to_then_and_after(tmp_path):
    """A heartbeat's loss is acted on 3 s of the wall after its onset: in lockstep at 8x that is
    24 s of the stand's time, past a window of ±3 s around the onset; the window reaches from
    3 s before the onset to 3 s after the moment the stand was acted on."""
    from gateway.runs import load_run
    from endurance.report import stop_deviation
    fast = 8.0
    w = SignalWindow(tmp_path, CHANNELS, 0.002, rolling_window_s=60.0, event_window_s=3.0, chunk_s=5.0)
    for k in range(12):                                  # 60 s of stand time in 7.5 s of wall
        out = rows(CHANNELS, 5.0 * k, 5.0, t0=5.0 * k)
        out["sync_time"] = 1.8e9 + out["t"] / fast
        w.append_rows(out)
        if k == 2:
            onset = 1.8e9 + 11.0 / fast
            event = w.mark_event("heartbeat_lost", "inner", time_s=onset, channel="inner", acted_s=onset + 3.0)
        w.sync()
    assert w.close() == [event]
    run = load_run(event.path)
    assert run.t[0] == pytest.approx(8.0) and run.t[-1] == pytest.approx(11.0 + 24.0 + 3.0)
    assert run.meta["event"]["truncated"] is False
    # the stop's deviation counts from the reading before the hold, not from the window's end
    stop = stop_deviation(event.path, CHANNELS, [1e4, 1e4, 5e3, 5e3])
    held = np.array([np.interp(35.0 - 0.002, run.t, run.signals[f"y.{c}"]) for c in CHANNELS])
    assert np.allclose(stop["forces_at_kgf"], held, atol=20.0) and stop["rows_after"] == 1501


def test_continuous_time_keeps_the_gap_between_passes():
    t = np.r_[np.arange(5) * 0.002, np.arange(3) * 0.002]
    wall = np.r_[10 + np.arange(5) * 0.002, 11 + np.arange(3) * 0.002]
    out = continuous_time(t, wall, 0.002)
    assert np.allclose(out[:5], t[:5]) and np.allclose(np.diff(out[5:]), 0.002)
    assert out[5] - out[4] == pytest.approx(11 - (10 + 0.008))


def test_a_write_error_of_the_window_is_heard_at_the_next_flush(tmp_path, monkeypatch):
    w = SignalWindow(tmp_path, CHANNELS, 0.002, rolling_window_s=4.0, event_window_s=1.0, chunk_s=1.0)
    import endurance.storage as storage

    def full(table, path):
        raise DataError(f"cannot write {path}: No space left on device; nothing of it was written")

    monkeypatch.setattr(storage, "write_parquet_atomic", full)
    w.append_rows(rows(CHANNELS, 0.0, 3.0))
    with pytest.raises(DataError, match="the signal window cannot write: cannot write .*No space left"):
        w.sync()
    with pytest.raises(DataError, match="No space left"):
        w.close()


def test_the_estimate_counts_end_points_per_channel_and_the_fixed_windows(tmp_path):
    from endurance.storage import JOURNAL_FLIGHT_B, JOURNAL_LOAD_CASE_B, TURNING_POINT_FILE_B
    test = load_test_file(EXAMPLE_TEST, check_controller=False)
    unit = Calibration(turning_point_b=10.0, journal_load_case_b=20.0, journal_end_point_b=50.0,
                       sample_channel_b=30.0, sample_row_b=4.0)
    e = storage_estimate(test, unit)
    block = test.block
    lc = sum(block.counts[t] * test.flight_types[t].load_cases for t in block.counts) / block.size
    assert e.turning_points_per_1000_flights == pytest.approx(1000 * lc * 4)
    assert e.turning_point_bytes_per_1000_flights == pytest.approx(
        1000 * lc * 4 * 10.0 + 1000 / block.size * TURNING_POINT_FILE_B)
    assert e.journal_bytes_per_1000_flights == pytest.approx(
        1000 * (JOURNAL_FLIGHT_B + lc * JOURNAL_LOAD_CASE_B))
    assert e.rolling_window == pytest.approx((600 + 60) * 500 * (4 * 30.0 + 4.0))
    assert e.event_window == pytest.approx(60 * 500 * (4 * 30.0 + 4.0))
    assert e.monitor_bytes_per_1000_flights > 0          # the trend's rows (no flight time: no gain rows)
    assert e.total > 100 * e.per_1000_flights + e.rolling_window
    assert "MB per 1,000 flights" in e.text() and "monitors' rows" in e.text()
    # N channels: a stand is N = 1
    stand = load_test_file(write_stand_test(tmp_path, flights=1000), check_controller=False)
    one = storage_estimate(stand, unit)
    assert one.channels == 1 and one.rolling_window == pytest.approx((600 + 60) * 500 * 34.0)


def _offline_testdir_bytes(tmp_path, flights: int):
    """TESTDIR's bytes after ``flights`` flights of the short example offline with both monitors
    and time scaling (no inspection), its start-up files (a new journal, the lock) taken off."""
    from endurance.journal import Journal
    from tests.support.endurance_run import OfflineStand, copy_short_test, fly
    test_file = copy_short_test(tmp_path / f"t{flights}")
    text = test_file.read_text()
    text = text[:text.index("[[inspection]]")] + text[text.index("[storage]"):]
    test_file.write_text(text + '\n[monitor.trend]\naction = "hold"\nlearn_flights = 9\n\n'
                                '[monitor.gain]\nmode = "watch"\n\n[time_scaling]\naccuracy_pct = 0.5\n')
    testdir = tmp_path / f"T{flights}"
    assert fly(testdir, test_file, OfflineStand(), flights).flights_done == flights
    import sqlite3
    from endurance.journal import JOURNAL_FILE
    with sqlite3.connect(testdir / JOURNAL_FILE) as db:    # the pruned end points' pages given back
        assert db.execute("PRAGMA auto_vacuum").fetchone()[0] == 2
        assert db.execute("PRAGMA freelist_count").fetchone()[0] <= 8
    test = load_test_file(test_file)
    fresh = tmp_path / f"fresh{flights}"
    fp = test.fingerprint()
    Journal.create(fresh, test.name, flights, test.station.names, fp.digest, fp.to_json(), text).close()
    size = lambda d: sum(p.stat().st_size for p in d.rglob("*") if p.is_file())       # noqa: E731
    return size(testdir) - size(fresh), test


@pytest.mark.slow
def test_a_short_offline_test_writes_what_its_plan_promised(tmp_path):
    """Everything an offline session writes (turning points, journal with the monitors' rows,
    per-type state, its record) within 25 % of the plan for the same flights, and its growth per
    1,000 flights within 25 % of the plan's (the gain's rows at the rates' flight time)."""
    from loading.minimum_time import programme_timing
    short, long = 72, 144          # a few blocks: the fixed parts (per type, a partial file) amortized
    grown = {}
    for n in (short, long):
        grown[n], test = _offline_testdir_bytes(tmp_path, n)
    flight_s = sum(test.block.counts[t] * programme_timing(ft.programme, test.controller.model,
                                                           test.controller.command_limit_pct).programme_time_s
                   for t, ft in test.flight_types.items()) / test.block.size
    e = storage_estimate(test, flight_s=flight_s)
    for n in (short, long):
        assert grown[n] == pytest.approx(e.grown(n), rel=0.25), (n, grown[n], e.grown(n))
    per_1000 = (grown[long] - grown[short]) / (long - short) * 1000
    assert per_1000 == pytest.approx(e.per_1000_flights, rel=0.25), (per_1000, e.per_1000_flights)


@pytest.mark.slow
def test_the_calibration_is_what_writing_real_data_measures(tmp_path):
    measured = calibrate(tmp_path)
    for field in dataclasses.fields(Calibration):
        stated, now = getattr(CALIBRATION, field.name), getattr(measured, field.name)
        assert now == pytest.approx(stated, rel=0.2), f"{field.name}: measured {now:.2f}, stated {stated}"


@pytest.mark.slow
def test_an_event_window_is_read_by_compare_diagnose_and_report_as_any_run(tmp_path):
    """stand compare, diagnose and report take an event window as a run directory: a rig's with
    --channel, a stand's as it is (the signals a plant g = 120 kgf/(%·s) would give, 2 kgf noise)."""
    import subprocess
    import sys
    test = load_test_file(EXAMPLE_TEST, check_controller=False)
    windows = {}
    for name, channels, meta in (("rig", CHANNELS, rig_meta(test.station)), ("stand", None, {})):
        w = SignalWindow(tmp_path / name, channels, 0.002, rolling_window_s=20.0, event_window_s=4.0,
                         chunk_s=5.0, meta=meta)
        w.append_rows(rows(channels, 0.0, 10.0))
        event = w.mark_event("force_limit", "a trip", time_s=1.8e9 + 5.0, channel="tip" if channels else None)
        w.close()
        windows[name] = event.path

    def stand(*args):
        res = subprocess.run([sys.executable, "-m", "stand", *map(str, args)], capture_output=True, text=True,
                             timeout=600, cwd=tmp_path)
        assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr[-2000:]
        return res.stdout

    for name, extra in (("rig", ["--channel", "tip"]), ("stand", [])):
        out = json.loads(stand("compare", windows[name], "--model", "base", "--no-plots", "--json", *extra))
        assert abs(out["params"]["g"] - 120.0) < 2.0 and out["metrics"]["n_samples"] >= 3500, out
        assert out["metrics"]["rmse"] < 2 * out["metrics"]["noise_floor_rmse"], out["metrics"]
        out = json.loads(stand("diagnose", windows[name], "--candidates", "reversal", "--json", *extra))
        assert out["model"] == "base" and out["verdict"], out["verdict"]
        stand("report", windows[name], "--model", "base", "--out", tmp_path / f"report-{name}", *extra)
        history = json.loads((tmp_path / f"report-{name}" / "history.json").read_text())
        assert (tmp_path / f"report-{name}" / "report.html").is_file()
        assert history["dataset"]["samples"] >= 3500 and history["versions"][-1]["model"] == "base", history["dataset"]
        assert abs(history["versions"][-1]["params"]["g"] - 120.0) < 2.0


def test_a_stops_deviation_from_the_ratios_counts_from_when_the_stand_was_acted_on(tmp_path):
    """A heartbeat's loss is acted on a timeout after its onset (the programme moving meanwhile,
    its channels out of phase): the deviation counts from the hold, where the forces stand
    still; a spike's reading at the event is left out; a window of another trip named."""
    from endurance.report import stop_deviation
    ranges = [10000.0, 10000.0, 5000.0, 5000.0]

    def window(name: str, spike: bool, acted_s: float | None):
        w = SignalWindow(tmp_path / name, CHANNELS, 0.002, rolling_window_s=30.0, event_window_s=6.0,
                         chunk_s=5.0)
        moving = rows(CHANNELS, 0.0, 8.0)
        if spike:                                       # the reading at the event: tip +3000 kgf
            moving["y.tip"][2500] += 3000.0
        w.append_rows(moving)
        held = rows(CHANNELS, 8.0, 2.0, t0=8.0)         # every force held where it stood
        for c in CHANNELS:
            held[f"y.{c}"] = np.full(len(held["t"]), moving[f"y.{c}"][-1])
        w.append_rows(held)
        event = w.mark_event("heartbeat_lost", "inner's valve", time_s=1.8e9 + 5.0, channel="inner",
                             acted_s=acted_s)
        w.close()
        return event.path

    held = stop_deviation(window("hb", False, 1.8e9 + 8.0), CHANNELS, ranges)
    assert held["pct_of_range"] < 0.2 and held["acted_after_s"] == pytest.approx(3.0), held
    assert held["rows_after"] == 1000
    moving = stop_deviation(window("onset", False, None), CHANNELS, ranges)    # as if held at the onset
    assert moving["pct_of_range"] > 10 * held["pct_of_range"] + 5.0, moving
    spike = stop_deviation(window("spike", True, None), CHANNELS, ranges)
    assert spike["pct_of_range"] == pytest.approx(moving["pct_of_range"], rel=0.05), spike
    assert max(spike["forces_at_kgf"]) < 3100.0


def test_across_a_hold_that_ended_the_session_the_resumes_found_forces_are_measured(tmp_path):
    """A trip whose hold ended the session (no reading after it, as in lockstep): the deviation
    across the hold is what the next resume found (its session's record) against the ratios
    before the trip; a stand that sagged on one channel meanwhile is seen, one that held is
    not; a resume before the trip, or none, is no answer."""
    from endurance.report import found_at_resume, held_deviation, stop_deviation
    ranges = [10000.0, 10000.0, 5000.0, 5000.0]
    w = SignalWindow(tmp_path / "trip", CHANNELS, 0.002, rolling_window_s=30.0, event_window_s=6.0, chunk_s=5.0)
    before = rows(CHANNELS, 0.0, 4.0)
    w.append_rows(before)
    trip = w.mark_event("force_limit", "tip", time_s=1.8e9 + 4.0, channel="tip")   # after the last reading
    w.close()
    stop = stop_deviation(trip.path, CHANNELS, ranges)
    assert stop["rows_after"] == 0 and stop["pct_of_range"] == 0.0
    last = np.array([before[f"y.{c}"][-1] for c in CHANNELS])
    testdir = tmp_path / "T"
    (testdir / "sessions").mkdir(parents=True)
    assert found_at_resume(testdir, stop["time"]) is None

    def resume(number: int, started: float, forces) -> dict:
        record = {"kind": "resume", "started_at": started,
                  "loading": {"began_at": started + 0.8, "forces_found_kgf": list(map(float, forces))}}
        (testdir / "sessions" / f"{number:04d}.json").write_text(json.dumps(record))
        return found_at_resume(testdir, stop["time"])

    sagged = last.copy()
    sagged[1] -= 400.0                                   # inner lost 400 kgf of 10,000 meanwhile
    assert resume(1, 1.8e9 - 100.0, sagged) is None       # a resume before the trip
    held = held_deviation(stop, resume(2, 1.8e9 + 60.0, last), ranges)
    assert held["pct_of_range"] < 1e-9 and held["after_s"] == pytest.approx(56.8)
    (testdir / "sessions" / "0002.json").unlink()
    assert held_deviation(stop, resume(3, 1.8e9 + 60.0, sagged), ranges)["pct_of_range"] > 2.5
    # the first resume after the trip was killed before it loaded (it started the test, wrote no
    # record): the record of a later one is not what the hold left, so no answer
    with Journal.create(testdir, "t", 10, CHANNELS, "f" * 64, "{}", "") as j:
        j.add_event("started", "resumed at flight 3 load case 2", time_s=1.8e9 + 30.0)
    assert found_at_resume(testdir, stop["time"]) is None
    # ... and that session's own record is (its command began before its journal's start)
    (testdir / "sessions" / "0003.json").write_text(json.dumps(
        {"kind": "resume", "started_at": 1.8e9 + 25.0, "loading": {"began_at": 1.8e9 + 30.5,
                                                                    "forces_found_kgf": list(map(float, last))}}))
    assert held_deviation(stop, found_at_resume(testdir, stop["time"]), ranges)["pct_of_range"] < 1e-9
