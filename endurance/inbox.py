"""Events from outside the session: a journal has one writer, the process that holds the test's
lock, so another process (the live page's server, :mod:`endurance.live`) records an event
through the session that runs the test.

:func:`record_event` writes it into the journal itself when no session runs (taking the lock
for the moment of one transaction), else drops it as a file into ``TESTDIR/inbox/``; the
session's journal writer takes every file in, in the order they were written, as its own event
(:func:`take_in`, polled with the stop file) and deletes it. A file left by a session that ended
between the look and the drop is taken in by the next session (or the next
:func:`record_event` when none runs). A process that holds the lock itself (a page served by
the running session) drops its events there too: one way for every event from outside.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

from core.durable import write_json

from .journal import Journal, TestLocked, lock_holder

INBOX_DIR = "inbox"


def record_event(testdir: str | Path, kind: str, message: str, channel: str | None = None,
                 time_s: float | None = None) -> str:
    """Record an event in the journal of ``testdir`` (module docstring). Returns how:
    ``"journal"`` (written) or ``"inbox"`` (handed to the running session)."""
    testdir = Path(testdir)
    event = {"kind": kind, "message": message, "channel": channel,
             "time_s": time.time() if time_s is None else float(time_s)}
    if lock_holder(testdir) is None:
        try:
            with Journal.open(testdir, write=True) as journal:
                take_in(testdir, journal)
                journal.add_event(event["kind"], event["message"], channel=event["channel"],
                                  time_s=event["time_s"])
            return "journal"
        except TestLocked:             # a session began meanwhile: it takes it in
            pass
    _drop(testdir, event)
    return "inbox"


def _drop(testdir: Path, event: dict) -> None:
    inbox = testdir / INBOX_DIR
    inbox.mkdir(exist_ok=True)
    write_json(inbox / f"{time.time_ns():020d}-{os.getpid()}.json", event)


def take_in(testdir: str | Path, journal: Journal) -> int:
    """Record every event waiting in the inbox in ``journal`` (open for writing), oldest first,
    deleting each file once recorded; returns how many. A file that is not an event is set
    aside as ``*.bad`` (named in an event), never retried."""
    inbox = Path(testdir) / INBOX_DIR
    try:
        names = sorted(p for p in inbox.iterdir() if p.suffix == ".json")
    except FileNotFoundError:
        return 0
    done = 0
    for path in names:
        try:
            event = json.loads(path.read_text())
            journal.add_event(str(event["kind"]), str(event["message"]), channel=event.get("channel"),
                              time_s=float(event["time_s"]))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            path.rename(path.with_suffix(".bad"))
            journal.add_event("inbox", f"{path.name} is not an event ({type(exc).__name__}: {exc}); "
                              "set aside as .bad")
            continue
        path.unlink(missing_ok=True)
        done += 1
    return done
