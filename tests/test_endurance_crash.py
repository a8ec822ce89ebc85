"""The journal survives kill -9 (endurance.journal, with the turning-point log of
endurance.storage): a child process commits load cases in a tight loop and is killed at random
moments, again and again; after each kill the journal passes SQLite's integrity check, its
count equals the flights whose every load case is committed (counted here with plain SQL),
no load case is recorded twice, every commit the child saw return is there (at most one more
than it acknowledged), the reopened journal continues from the right load case, and the
turning-point log reads whole with each end point once."""
from __future__ import annotations

import random
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from endurance.journal import JOURNAL_FILE, Journal
from endurance.storage import TurningPointLog, read_turning_points

from tests.support.journal_writer import BLOCK, CHANNELS, load_cases_of

ROOT = Path(__file__).resolve().parents[1]


def next_after(flight: int, index: int) -> tuple[int, int]:
    """The (flight, load case) after load case ``index`` of ``flight``."""
    return (flight, index + 1) if index + 1 < load_cases_of(flight) else (flight + 1, 0)


def last_ack(testdir: Path) -> tuple[int, int, int] | None:
    path = testdir / "acks.log"
    if not path.exists():
        return None
    lines = [ln for ln in path.read_text().splitlines() if ln.strip()]
    if not lines:
        return None
    parts = lines[-1].split()
    if len(parts) != 3:                     # a line cut by the kill: the one before is whole
        parts = lines[-2].split()
    return tuple(int(p) for p in parts)


def check_journal(testdir: Path) -> dict:
    """Every invariant after a kill, from plain SQL; the figures."""
    db = sqlite3.connect(testdir / JOURNAL_FILE)
    try:
        assert db.execute("PRAGMA integrity_check").fetchall() == [("ok",)]
        done, flight, attempt, lcs = db.execute(
            "SELECT flights_done, flight, attempt, load_cases_done FROM state").fetchone()
        complete = db.execute(
            "SELECT COUNT(*) FROM flights f WHERE (SELECT COUNT(*) FROM load_cases l WHERE "
            "l.flight = f.number AND l.attempt = f.attempt) = f.load_cases").fetchone()[0]
        assert done == complete, f"count {done} but {complete} flights have every load case"
        assert db.execute("SELECT COUNT(*) FROM (SELECT flight, attempt, idx FROM load_cases "
                          "GROUP BY flight, attempt, idx HAVING COUNT(*) > 1)").fetchone()[0] == 0
        assert db.execute("SELECT COUNT(*) FROM flights WHERE status = 'done'").fetchone()[0] == done
        total = db.execute("SELECT COUNT(*) FROM load_cases").fetchone()[0]
        reruns = db.execute("SELECT COALESCE(SUM(attempt - 1), 0) FROM flights").fetchone()[0]
    finally:
        db.close()
    journal = Journal.open(testdir)
    assert journal.integrity_check() == []
    assert journal.state() == "interrupted"
    pos = journal.position()
    journal.close()
    if flight is not None:
        assert (pos.flight, pos.load_case) == (flight, lcs)
    return {"done": done, "position": (pos.flight, pos.load_case), "attempt": pos.attempt,
            "load_cases": total, "reruns": reruns}


def check_log(testdir: Path, done: int) -> int:
    """The turning-point log after a kill: it reads whole (no torn file), each end point once,
    its flights contiguous and counted, every load case of a flight's last attempt in it."""
    log = TurningPointLog(testdir, BLOCK)         # removes what a kill left (the child is dead)
    table = read_turning_points(testdir)
    if not table.num_rows:
        return 0
    rows = table.select(["flight", "attempt", "load_case", "channel"]).to_pylist()
    keys = {(r["flight"], r["attempt"], r["load_case"], r["channel"]) for r in rows}
    assert len(keys) == len(rows), "an end point is in the log twice"
    flights = sorted({r["flight"] for r in rows})
    assert flights == list(range(1, log.exported_through + 1)) and log.exported_through <= done
    for f in flights[-5:]:
        last = max(a for (g, a, _, _) in keys if g == f)
        assert {(k, c) for (g, a, k, c) in keys if g == f and a == last} == \
            {(k, c) for k in range(load_cases_of(f)) for c in CHANNELS}
    return log.exported_through


def crash_loop(tmp_path: Path, kills: int, alive_s: tuple[float, float], storage: bool) -> dict:
    testdir = tmp_path / "test"
    rng = random.Random(20261127)
    expected = None              # the position the last check read
    figures = {"kills": 0, "ahead": 0, "reruns": 0, "exported": 0}
    reruns = 0                   # restarts told to run the flight in progress again
    for kill in range(kills):
        cmd = [sys.executable, "-m", "tests.support.journal_writer", str(testdir)]
        cmd += ["--storage"] if storage else []
        cmd += ["--rerun"] if kill % 2 else []
        child = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                 text=True)
        try:
            line = child.stdout.readline().split()
            assert line and line[0] == "resume", child.stderr.read()
            resumed = (int(line[1]), int(line[3]))
            if expected is not None:
                assert resumed == expected, f"kill {kill}: resumed at {resumed}, not {expected}"
            reruns += line[2] != "None" and kill % 2 == 1
            time.sleep(rng.uniform(*alive_s))
        finally:
            child.send_signal(signal.SIGKILL)
            child.wait()
        assert child.returncode == -signal.SIGKILL, child.stderr.read()
        figures["kills"] += 1
        state = check_journal(testdir)
        ack = last_ack(testdir)
        assert ack is not None, "the child committed nothing"
        acked = next_after(ack[0], ack[2])
        # every commit that returned is there; at most one more than acknowledged
        assert state["position"] in (acked, next_after(*acked)), (state, ack)
        figures["ahead"] += state["position"] != acked
        expected = state["position"]
        if storage:
            figures["exported"] = check_log(testdir, state["done"])
        figures.update(done=state["done"], load_cases=state["load_cases"], reruns=state["reruns"])
        # every flight run again is a new attempt, recorded once
        assert state["reruns"] == reruns
    return figures


def test_the_journal_survives_kill_9_in_a_tight_loop(tmp_path):
    figures = crash_loop(tmp_path, kills=4, alive_s=(0.4, 1.2), storage=False)
    assert figures["kills"] == 4 and figures["done"] > 4
    print(f"\n{figures}")


@pytest.mark.slow
def test_the_journal_and_the_turning_point_log_survive_many_kills(tmp_path):
    figures = crash_loop(tmp_path, kills=12, alive_s=(1.0, 4.0), storage=True)
    assert figures["kills"] == 12 and figures["exported"] > 2 * BLOCK
    print(f"\n{figures}")
