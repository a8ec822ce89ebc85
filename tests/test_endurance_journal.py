"""The endurance journal (endurance.journal): WAL with synchronous=FULL and a schema version; a
load case per transaction, the flight counted with its last load case; nothing out of order or
twice; a re-run keeps the earlier attempt; the lock refuses a second writer and dies with its
process, whose journal then says interrupted; any thread may write; the status has the pace and
the ETA; a full database raises a clear error and leaves the journal as it was."""
from __future__ import annotations

import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import threading
import uuid
from pathlib import Path

import pytest

from endurance.journal import (JOURNAL_FILE, SCHEMA_VERSION, EndPoint, Journal, JournalError, MonitorStep,
                               Position, TestLocked, lock_holder)

ROOT = Path(__file__).resolve().parents[1]
CHANNELS = ["root", "tip"]


class Clock:
    def __init__(self, t: float = 1.8e9) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def new(testdir: Path, target: int = 10, clock=None) -> Journal:
    j = Journal.create(testdir, "test", target, CHANNELS, "abc", '{"parts": {}}',
                       clock=clock or Clock())
    j.start()
    return j


def fly(j: Journal, n: int, load_cases: int = 3, flight_type: str = "A") -> None:
    j.begin_flight(n, flight_type, 1, n, load_cases)
    for k in range(load_cases):
        j.commit_load_case(n, k, [EndPoint(c, 100.0 * k, 100.0 * k + 1, 5.0) for c in CHANNELS])


def test_the_journal_is_wal_with_full_sync_and_a_schema_version(tmp_path):
    j = new(tmp_path / "t")
    assert j._db.execute("PRAGMA synchronous").fetchone()[0] == 2          # FULL
    raw = sqlite3.connect(tmp_path / "t" / JOURNAL_FILE)
    assert raw.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert raw.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    raw.close()
    j.close()
    with pytest.raises(JournalError, match="already holds a test"):
        Journal.create(tmp_path / "t", "again", 5, CHANNELS, "x")


def test_a_flight_is_counted_with_its_last_load_case_in_the_same_transaction(tmp_path):
    j = new(tmp_path / "t")
    j.begin_flight(1, "A", 1, 1, 3)
    assert j.position() == Position(1, 1, 0)
    assert j.commit_load_case(1, 0) is False and j.commit_load_case(1, 1) is False
    assert j.flights_done == 0 and j.position() == Position(1, 1, 2)
    assert j.commit_load_case(1, 2) is True
    assert j.flights_done == 1 and j.position() == Position(2, None, 0)
    assert j.flight(1).status == "done" and j.flight(1).finished is not None
    assert j.integrity_check() == []


@pytest.mark.parametrize("wrong,message", [
    (lambda j: j.commit_load_case(2, 2), "the next is load case 2"),
    (lambda j: j.commit_load_case(2, 0), "the next is load case 2"),         # never twice
    (lambda j: j.commit_load_case(3, 0), "the flight in progress is 2"),
    (lambda j: j.begin_flight(3, "A", 1, 3, 3), "the next flight is 2"),
    (lambda j: j.begin_flight(1, "A", 1, 1, 3), "the next flight is 2"),
    (lambda j: j.begin_flight(2, "B", 1, 2, 3), "was begun as type A, not B"),
    (lambda j: j.finish_flight(2), "flight 2 is not done"),
    (lambda j: j.commit_load_case(2, 1, [EndPoint("wingtip", 1, 1)]), "channel 'wingtip'"),
])
def test_a_load_case_or_flight_out_of_order_is_refused_and_changes_nothing(tmp_path, wrong, message):
    j = new(tmp_path / "t")
    fly(j, 1)
    j.begin_flight(2, "A", 1, 2, 3)
    j.commit_load_case(2, 0)
    with pytest.raises(JournalError, match=message):
        wrong(j)
    assert j.position() == Position(2, 1, 1) and j.flights_done == 1
    assert j.integrity_check() == []


def test_a_flight_begun_again_is_a_rerun_whose_earlier_attempt_stays_recorded(tmp_path):
    j = new(tmp_path / "t")
    fly(j, 1)
    j.begin_flight(2, "A", 1, 2, 3)
    j.commit_load_case(2, 0, [EndPoint("root", 1, 2)])
    j.commit_load_case(2, 1, [EndPoint("root", 3, 4)])
    assert j.begin_flight(2, "A", 1, 2, 3) == 2
    assert j.position() == Position(2, 2, 0)
    for k in range(3):
        j.commit_load_case(2, k, [EndPoint("root", 10 + k, 11 + k)])
    rec = j.flight(2)
    assert rec.rerun and rec.attempt == 2 and j.flights_done == 2
    rows = j.end_points(2, 2)
    assert [(r[3], r[4]) for r in rows] == [(1, 0), (1, 1), (2, 0), (2, 1), (2, 2)]
    assert rows[0][1:3] == (1, "A") and rows[0][5] == "root"
    assert j.events()[-1]["kind"] == "rerun"
    assert j.integrity_check() == []


def test_the_target_reached_finishes_the_test(tmp_path):
    j = new(tmp_path / "t", target=2)
    fly(j, 1)
    fly(j, 2)
    assert j.state() == "finished" and j.status()["eta_s"] == 0.0 and j.status()["flight"] is None
    with pytest.raises(JournalError, match="the test is finished"):
        j.begin_flight(3, "A", 1, 3, 3)
    j.set_target(4)
    assert j.state() == "stopped"
    j.start()
    fly(j, 3)
    assert j.flights_done == 3 and j.state() == "running"


def test_what_a_flight_type_learnt_is_kept_per_type_and_channel(tmp_path):
    j = new(tmp_path / "t")
    fly(j, 1, flight_type="A")
    j.finish_flight(1, compensation={"root": "[peak]\n\"3000\" = -4.0\n", "tip": "[peak]\n"},
                    schedule="[segments]\n")
    fly(j, 2, flight_type="B")
    j.set_compensation("B", {"root": "# B's"})
    j.close()
    r = Journal.open(tmp_path / "t")
    assert r.compensation("A") == {"root": "[peak]\n\"3000\" = -4.0\n", "tip": "[peak]\n"}
    assert r.compensation("B") == {"root": "# B's"} and r.compensation("C") == {}
    assert r.schedule("A") == "[segments]\n" and r.schedule("B") is None
    with pytest.raises(JournalError, match="opened for reading"):
        r.set_compensation("A", {"root": ""})


def test_a_flights_monitors_step_is_stored_with_what_it_taught_in_one_transaction(tmp_path):
    j = new(tmp_path / "t", target=10 ** 6)
    fly(j, 1)
    step = MonitorStep({"trend": '{"last_flight": 1}', "trend.type.A": "{}"},
                       [("trend", 1, 0, '{"flight": 1}')],
                       [("trend_alarm", "inner,tip", "flight 1: channel inner needs 3 % more flow")])
    j.finish_flight(1, compensation={"root": "# A"}, schedule="[search]\n", monitors=step)
    fly(j, 2)
    # a step that cannot be stored (the database full) stores nothing of the flight's lesson
    pages = j._db.execute("PRAGMA page_count").fetchone()[0]
    j._db.execute(f"PRAGMA max_page_count = {pages}")
    big = MonitorStep({"trend": '{"last_flight": 2}'}, [("trend", 2, 0, "x" * 100_000)])
    with pytest.raises(JournalError, match="storing what flight 2 taught in .*: the disk is full"):
        j.finish_flight(2, compensation={"root": "# B"}, monitors=big)
    j._db.execute("PRAGMA max_page_count = 1073741823")
    j.close()
    r = Journal.open(tmp_path / "t")
    assert r.monitor_states() == {"trend": '{"last_flight": 1}', "trend.type.A": "{}"}
    assert r.monitor_states("trend.type.") == {"trend.type.A": "{}"}
    assert r.monitor_history("trend") == [(1, 0, '{"flight": 1}')] and r.monitor_history("gain") == []
    assert r.compensation("A") == {"root": "# A"} and r.schedule("A") == "[search]\n"
    alarm = [e for e in r.events() if e["kind"] == "trend_alarm"]
    assert [(e["channel"], e["flight"]) for e in alarm] == [("inner,tip", 1)]
    assert r.integrity_check() == []


def test_a_journal_of_schema_1_gets_the_monitor_tables_when_opened_for_writing(tmp_path):
    j = new(tmp_path / "t")
    j.close()
    raw = sqlite3.connect(tmp_path / "t" / JOURNAL_FILE)
    raw.executescript("DROP TABLE monitor_state; DROP TABLE monitor_history; PRAGMA user_version = 1;")
    raw.close()
    with Journal.open(tmp_path / "t") as r:           # read only: no monitors, nothing changed
        assert r.monitor_states() == {} and r.monitor_history("trend") == []
    with Journal.open(tmp_path / "t", write=True) as w:
        w.record_monitors(MonitorStep({"gain": "{}"}))
        assert w.monitor_states() == {"gain": "{}"}
    raw = sqlite3.connect(tmp_path / "t" / JOURNAL_FILE)
    assert raw.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION == 2
    raw.close()


def test_a_second_writer_is_refused_naming_the_holder(tmp_path):
    j = new(tmp_path / "t")
    with pytest.raises(TestLocked, match=rf"is a live test: process {os.getpid()} on "):
        Journal.open(tmp_path / "t", write=True)
    holder = lock_holder(tmp_path / "t")
    assert holder["pid"] == os.getpid()
    reader = Journal.open(tmp_path / "t")
    assert reader.state() == "running" and reader.status()["holder"]["pid"] == os.getpid()
    j.close()
    assert lock_holder(tmp_path / "t") is None
    assert reader.state() == "interrupted"        # running, and nobody holds the lock


HOLDER = """
import sys, time
from endurance.journal import Journal
j = Journal.create(sys.argv[1], "held", 10, ["root"], "x")
j.start()
j.begin_flight(1, "A", 1, 1, 4)
j.commit_load_case(1, 0)
print("ready", flush=True)
time.sleep(60)
"""


def test_the_lock_dies_with_its_process_and_its_journal_says_interrupted(tmp_path):
    testdir = tmp_path / "t"
    child = subprocess.Popen([sys.executable, "-c", HOLDER, str(testdir)], cwd=ROOT,
                             stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "ready"
        with pytest.raises(TestLocked, match=rf"process {child.pid} on "):
            Journal.open(testdir, write=True)
        assert Journal.open(testdir).status()["state"] == "running"
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    assert (testdir / "lock").exists()                   # the file stays, the lock does not
    reader = Journal.open(testdir)
    assert reader.status()["state"] == "interrupted" and reader.status()["holder"] is None
    writer = Journal.open(testdir, write=True)
    assert writer.state() == "interrupted"
    event = writer.events()[-1]
    assert event["kind"] == "interrupted" and event["flight"] == 1
    assert f"the process {child.pid}" in event["message"] and "after 1 load case(s)" in event["message"]
    assert writer.flight(1).interruptions == 1
    writer.start()
    assert writer.position() == Position(1, 1, 1)        # continues at its second load case
    writer.commit_load_case(1, 1)
    assert writer.integrity_check() == []


def test_another_thread_may_write_and_concurrent_calls_are_serialized(tmp_path):
    j = new(tmp_path / "t", target=1000)
    errors = []

    def flights(first: int) -> None:
        try:
            fly(j, first)
        except BaseException as exc:   # noqa: BLE001 - reported below
            errors.append(exc)

    t = threading.Thread(target=flights, args=(1,))
    t.start()
    t.join()
    assert not errors and j.flights_done == 1

    def events(tag: str) -> None:
        try:
            for k in range(25):
                j.add_event("note", f"{tag} {k}")
        except BaseException as exc:   # noqa: BLE001
            errors.append(exc)

    threads = [threading.Thread(target=events, args=(f"thread {i}",)) for i in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert not errors
    assert len([e for e in j.events() if e["kind"] == "note"]) == 100
    assert j.integrity_check() == []


def test_status_has_the_position_the_pace_over_the_last_hour_and_the_eta(tmp_path):
    clock = Clock(1.8e9)
    j = new(tmp_path / "t", target=100, clock=clock)
    st = j.status()
    assert st["pace_flights_per_h"] is None and st["eta_s"] is None
    for n in range(1, 11):                   # a flight every 20 min, then one a minute
        clock.t += 1200 if n <= 5 else 60
        fly(j, n, flight_type="AB"[n % 2])
    j.begin_flight(11, "B", 2, 1, 3)
    j.commit_load_case(11, 0)
    j.add_event("limit", "force limit indicated", channel="tip", flight=11)
    st = j.status()
    assert st["state"] == "running" and st["flights_done"] == 10 and st["flights_target"] == 100
    assert st["flight"] == {"number": 11, "type": "B", "block": 2, "position": 1, "load_cases": 3,
                            "attempt": 1}
    assert st["load_case"] == 2
    # the flights finished in the last hour: 3 to 10 (at 60, 80 and 100 min, then a minute apart)
    finished = [1.8e9 + 1200 * n for n in range(1, 6)] + [1.8e9 + 6000 + 60 * k for k in range(1, 6)]
    inside = [t for t in finished if t >= clock.t - 3600]
    assert len(inside) == 8
    assert st["pace_flights_per_h"] == pytest.approx(7 / (inside[-1] - inside[0]) * 3600)
    assert st["eta_s"] == pytest.approx(90 / st["pace_flights_per_h"] * 3600)
    assert st["events"][-1]["kind"] == "limit" and st["events"][-1]["channel"] == "tip"
    assert set(st) >= {"state", "flights_done", "flights_target", "flight", "load_case",
                       "pace_flights_per_h", "eta_s", "events"}


def test_the_integrity_check_finds_a_broken_count(tmp_path):
    j = new(tmp_path / "t")
    fly(j, 1)
    fly(j, 2)
    assert j.integrity_check() == []
    j._db.execute("DELETE FROM load_cases WHERE flight = 2 AND idx = 1")
    assert j.integrity_check() == ["flight 2 is done with 2 of its 3 load cases"]
    j._db.execute("UPDATE state SET flights_done = 3")
    assert "flights_done = 3 but the done flights are 1-2" in j.integrity_check()


def test_end_points_are_pruned_only_for_done_flights(tmp_path):
    j = new(tmp_path / "t")
    fly(j, 1)
    fly(j, 2)
    assert len(j.end_points(1, 2)) == 12
    with pytest.raises(JournalError, match="only 2 are done"):
        j.prune_end_points(3)
    assert j.prune_end_points(1) == 6 and len(j.end_points(1, 2)) == 6


def test_a_journal_made_before_auto_vacuum_is_converted_once_when_opened_for_writing(tmp_path):
    """An older journal (no auto-vacuum: pruned pages stayed in the file) is rewritten with
    incremental auto-vacuum by the next writer; what it held stays, and it gives pages back."""
    j = new(tmp_path / "t", target=200)
    for n in range(1, 121):
        fly(j, n, load_cases=10)
    j.close()
    with sqlite3.connect(tmp_path / "t" / JOURNAL_FILE) as db:       # as an older hydrostand made it
        db.execute("PRAGMA auto_vacuum = NONE")
        db.execute("VACUUM")
        assert db.execute("PRAGMA auto_vacuum").fetchone()[0] == 0
    with Journal.open(tmp_path / "t") as reader:                     # a reader changes nothing
        assert reader.flights_done == 120
    with sqlite3.connect(tmp_path / "t" / JOURNAL_FILE) as db:
        assert db.execute("PRAGMA auto_vacuum").fetchone()[0] == 0
    j = Journal.open(tmp_path / "t", write=True)
    assert j.flights_done == 120 and len(j.end_points(1, 120)) == 120 * 10 * len(CHANNELS)
    j.prune_end_points(120)
    j.checkpoint()
    j.close()
    with sqlite3.connect(tmp_path / "t" / JOURNAL_FILE) as db:
        assert db.execute("PRAGMA auto_vacuum").fetchone()[0] == 2
        assert db.execute("PRAGMA freelist_count").fetchone()[0] <= 2


def test_a_journal_of_a_newer_schema_or_an_unfinished_creation_is_refused(tmp_path):
    j = new(tmp_path / "t")
    j.close()
    raw = sqlite3.connect(tmp_path / "t" / JOURNAL_FILE)
    raw.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    raw.close()
    with pytest.raises(JournalError, match="written by a newer hydrostand"):
        Journal.open(tmp_path / "t")
    raw = sqlite3.connect(tmp_path / "t" / JOURNAL_FILE)
    raw.execute("PRAGMA user_version = 0")
    raw.close()
    with pytest.raises(JournalError, match="not a complete journal"):
        Journal.open(tmp_path / "t")
    with pytest.raises(JournalError, match="holds no test"):
        Journal.open(tmp_path / "nowhere")


def test_a_full_database_raises_a_clear_error_and_the_journal_stays_as_it_was(tmp_path):
    j = new(tmp_path / "t", target=10 ** 6)
    fly(j, 1)
    pages = j._db.execute("PRAGMA page_count").fetchone()[0]
    j._db.execute(f"PRAGMA max_page_count = {pages + 2}")
    big = [EndPoint(c, float(k), float(k) + 0.5, 1.0) for k in range(40) for c in CHANNELS][:2]
    failed = None
    for n in range(2, 500):
        try:
            j.begin_flight(n, "A", 1, n, 4)
            for k in range(4):
                j.commit_load_case(n, k, big)
        except JournalError as exc:
            failed = exc
            break
    assert failed is not None and "the disk is full" in str(failed)
    assert "nothing of it was recorded" in str(failed)
    before = j.position()
    done = j.flights_done
    assert j.integrity_check() == []
    j._db.execute("PRAGMA max_page_count = 1073741823")
    # the same step again succeeds: nothing half-done was left
    if before.attempt is None:
        j.begin_flight(before.flight, "A", 1, before.flight, 4)
        before = j.position()
    for k in range(before.load_case, 4):
        j.commit_load_case(before.flight, k, big)
    assert j.flights_done == done + 1 and j.integrity_check() == []


@pytest.fixture
def tiny_filesystem(tmp_path):
    """A 1 MiB tmpfs (root only; skipped elsewhere), unmounted after."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tiny file system needs root")
    mnt = tmp_path / f"tiny-{uuid.uuid4().hex[:6]}"
    mnt.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def test_a_full_disk_raises_a_clear_error_and_the_journal_reopens_consistent(tiny_filesystem):
    testdir = tiny_filesystem / "t"
    j = new(testdir, target=10 ** 6)
    filler = tiny_filesystem / "filler"
    failed = None
    with open(filler, "wb") as fh:               # leave the journal a few pages
        try:
            fh.write(b"\0" * (os.statvfs(tiny_filesystem).f_bavail * 4096 - 48 * 1024))
        except OSError:
            pass
    points = [EndPoint(c, 1000.0 + k, 1000.5 + k, 1.0) for k in range(1) for c in CHANNELS]
    n = 0
    try:
        for n in range(1, 10 ** 5):
            j.begin_flight(n, "A", 1, n, 5)
            for k in range(5):
                j.commit_load_case(n, k, points)
    except JournalError as exc:
        failed = exc
    assert failed is not None, "the disk never filled"
    assert "the disk is full" in str(failed) and "nothing of it was recorded" in str(failed)
    position, done = j.position(), j.flights_done
    j.close()
    filler.unlink()
    again = Journal.open(testdir, write=True)
    assert again.integrity_check() == []
    assert (again.position(), again.flights_done) == (position, done)
    again.start()
    p = again.position()
    if p.attempt is None:
        again.begin_flight(p.flight, "A", 1, p.flight, 5)
        p = again.position()
    for k in range(p.load_case, 5):
        again.commit_load_case(p.flight, k, points)
    assert again.flights_done == done + 1 and again.integrity_check() == []
    again.close()


def test_a_stopped_test_takes_no_load_case_until_it_starts_again(tmp_path):
    j = new(tmp_path / "t")
    j.begin_flight(1, "A", 1, 1, 3)
    j.commit_load_case(1, 0)
    j.stop("inspection")
    with pytest.raises(JournalError, match="the test is stopped; start it first"):
        j.commit_load_case(1, 1)
    assert j.status()["reason"] == "inspection" and j.events()[-1]["kind"] == "stopped"
    j.start()
    assert j.events()[-1]["message"] == "resumed at flight 1 load case 2"
    j.commit_load_case(1, 1)
    assert j.position() == Position(1, 1, 2)
