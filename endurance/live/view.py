"""What the live page shows besides the signals, read from the journal (never written: a reader
needs no lock and never waits for the session, SQLite in WAL mode).

:class:`JournalView` keeps one read-only connection (opened when the journal exists: a page
served by ``stand test start --serve`` is up before the test's journal is made) and answers the
server's polls: the status (:func:`endurance.report.status`, the very dict ``stand test status
--json`` prints), the events since the last look, the end points' trends.
"""
from __future__ import annotations

from pathlib import Path

from endurance.journal import Journal, JournalError
from endurance.report import status

from .trend import TrendHistory

#: the events the page gets when it opens
FIRST_EVENTS = 50
#: the latest events in the status (stand test status's default)
STATUS_EVENTS = 10


class JournalView:
    """The journal of ``testdir`` as the page sees it (module docstring)."""

    def __init__(self, testdir: str | Path) -> None:
        self.testdir = Path(testdir)
        self._journal: Journal | None = None
        self.trends = TrendHistory(self.testdir)
        #: the last event the stream has sent: a journal there already has its history, which
        #: a page gets when it opens (:meth:`recent_events`); one made later is new from its first
        self.last_event_id = 0
        recent = self.recent_events()
        if recent:
            self.last_event_id = recent[-1]["id"]

    @property
    def journal(self) -> Journal | None:
        if self._journal is None:
            try:
                self._journal = Journal.open(self.testdir)
            except JournalError:
                return None
        return self._journal

    def status(self) -> dict | None:
        """What ``stand test status --json`` prints now (None before the journal exists)."""
        journal = self.journal
        return None if journal is None else status(journal, STATUS_EVENTS)

    def recent_events(self) -> list[dict]:
        """The latest :data:`FIRST_EVENTS` events (a page that opens)."""
        journal = self.journal
        return [] if journal is None else journal.events(limit=FIRST_EVENTS)

    def new_events(self) -> list[dict]:
        """The events recorded since the last call (every one since the view opened at first)."""
        journal = self.journal
        if journal is None:
            return []
        events = journal.events(since_id=self.last_event_id)
        if events:
            self.last_event_id = events[-1]["id"]
        return events

    def new_trends(self) -> list[dict]:
        journal = self.journal
        return [] if journal is None else self.trends.update(journal)

    def close(self) -> None:
        if self._journal is not None:
            self._journal.close()
            self._journal = None
