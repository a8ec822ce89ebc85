r"""The live rows a running session publishes, and the page server's end of them.

::

    test process                                      the page's server (a process of its own)
    control loop ──cycle()──▶ LiveFeed                FeedReader (every tick of the server)
      a row every 1/SAMPLE_HZ s of the wall clock       follows TESTDIR/live.json from session
      into its ring (ring.py: a few stores into a       to session, copies the rows that are new
      mapped file, never a wait)  ────────────────▶     (a read-only mapping of the ring)

A row is ``(sync_time, forces..., references..., commands...)`` in the channels' order (kgf,
kgf, %); ``sync_time`` is the cycle's SYNC on the wall clock (epoch s). The session holds no
descriptor, thread or buffer for a reader: whatever the server does (or however many servers
read), the loop's part is the same few stores. The ring lives in memory, not on the test's
disk (:data:`RING_DIR`, a tmpfs: no page of it is ever written back, so a store never waits
for the disk), named in ``TESTDIR/live.json``; both are mode 600 (the test's user). A ring a
killed session left is removed by the next session of the test. Why a mapped file rather than
a socket: docs/decisions.md (the live page in a process of its own).
"""
from __future__ import annotations

import json
import logging
import os
import secrets
from pathlib import Path

import numpy as np

from .ring import MARGIN, RingFile

#: the file in TESTDIR that names the running session's ring
LIVE_FILE = "live.json"
#: where rings are made: memory (Linux's tmpfs), else the test's directory
RING_DIR = Path("/dev/shm")
RING_PREFIX = "hydrostand-live-"
#: rows per second the live view gets (the loop's cycles decimated to it on the wall clock: in
#: lockstep a cycle may take longer than its period)
SAMPLE_HZ = 50.0
#: a cycle this share of a row's interval after the last row makes the next (float round-off)
_EARLY = 0.95
#: seconds of rows the ring keeps (the page shows 30)
RING_S = 64.0
#: how often a reader looks whether the session it follows is still alive, s
ALIVE_EVERY_S = 1.0
log = logging.getLogger(__name__)


class LiveFeed:
    """A session's publisher (``endurance.run``'s ``publisher``): :meth:`cycle` from the control
    loop, :meth:`open` and :meth:`close` around the session's run."""

    def __init__(self, sample_hz: float = SAMPLE_HZ) -> None:
        self.sample_hz = float(sample_hz)
        self.channels: list[str] = []
        self.period_s: float | None = None
        self._next = -float("inf")
        self._interval_s = _EARLY / self.sample_hz
        self._ring: RingFile | None = None
        #: the session's channels, sample rate and pid while it runs, else None
        self.hello: dict | None = None

    # -- the control loop's --------------------------------------------------------------------------
    def cycle(self, sync_time: float, forces, references, commands) -> None:
        """One cycle: a row into the ring if it is due (module docstring)."""
        if sync_time < self._next or self._ring is None:
            return
        self._next = sync_time + self._interval_s
        self._ring.put(sync_time, forces, references, commands)

    # -- the session's --------------------------------------------------------------------------------
    def open(self, testdir: str | Path, channels: list[str], period_s: float) -> None:
        """The session begins: its channels and period; its ring is made and named in
        ``TESTDIR/live.json`` (a killed session's left removed first)."""
        testdir = Path(testdir)
        self.channels = list(channels)
        self.period_s = float(period_s)
        hello = {"channels": self.channels, "period_s": self.period_s, "sample_hz": self.sample_hz,
                 "pid": os.getpid()}
        _remove_stale(testdir)
        where = RING_DIR if RING_DIR.is_dir() and os.access(RING_DIR, os.W_OK) else testdir
        path = where / f"{RING_PREFIX}{os.getpid()}-{secrets.token_hex(6)}.ring"
        self._pointer = testdir / LIVE_FILE
        try:
            self._ring = RingFile.create(path, 1 + 3 * len(self.channels), int(RING_S * self.sample_hz) + MARGIN,
                                         hello)
            tmp = testdir / f".{LIVE_FILE}.{os.getpid()}.tmp"
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            with os.fdopen(fd, "w") as fh:
                json.dump({"ring": str(path), "pid": os.getpid()}, fh)
            os.replace(tmp, self._pointer)
        except (OSError, ValueError, MemoryError) as exc:      # the page shows no signals; the test runs
            log.warning("live page: this session publishes no signals (%s: %s)", type(exc).__name__, exc)
            self.close()
            return
        self.hello = hello

    def close(self) -> None:
        self.hello = None
        ring, self._ring = self._ring, None
        if ring is None:
            return
        ring.close()                                  # closed, and its file removed
        try:
            if _pointer(self._pointer).get("ring") == str(ring.path):
                self._pointer.unlink()
        except OSError:
            pass


def _pointer(path: Path) -> dict:
    """``TESTDIR/live.json`` ({ring, pid}); OSError or ValueError if it is not there or not one."""
    info = json.loads(path.read_text())
    if not isinstance(info, dict) or not isinstance(info.get("ring"), str):
        raise ValueError(f"{path}: not a live ring's name")
    return info


def _remove_stale(testdir: Path) -> None:
    """The ring a killed session of this test left (its process gone), removed."""
    try:
        info = _pointer(testdir / LIVE_FILE)
    except (OSError, ValueError):
        return
    ring = Path(info["ring"])
    if not _alive(int(info.get("pid") or 0)) and ring.name.startswith(RING_PREFIX):
        ring.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


class FeedReader:
    """The page server's end (module docstring): the rows of whichever session runs the test in
    ``testdir``. :meth:`poll` (the server's tick) follows the file; :attr:`hello` is the
    session's (channels, sample rate, pid) while one runs, else None. Sequence numbers go on
    from session to session (:meth:`since`), so a reader of this never sees them go back."""

    def __init__(self, testdir: str | Path) -> None:
        self.path = Path(testdir) / LIVE_FILE
        self._named: int | None = None    # the inode of the live.json that named the ring taken
        self.hello: dict | None = None
        self.channels: list[str] = []
        self._ring: RingFile | None = None
        self._offset = 0                 # this session's row 0 in the running numbering
        self._end = 0                    # the running count at the last look
        self._alive_at = 0.0
        self._passed: int | None = None  # the inode of a ring not to take (closed, dead, not one)
        self.poll()

    @property
    def count(self) -> int:
        """The running count of rows (module docstring)."""
        if self._ring is not None:
            self._end = self._offset + self._ring.count
        return self._end

    def since(self, seq: int) -> tuple[int, np.ndarray]:
        """``(count, rows)``: the rows from running sequence number ``seq`` on (as
        :meth:`endurance.live.ring.RingFile.since`), none while no session runs."""
        ring = self._ring
        if ring is None:
            return self._end, np.empty((0, 1 + 3 * len(self.channels)))
        end, rows = ring.since(max(int(seq) - self._offset, 0))
        self._end = self._offset + end
        return self._end, rows

    def poll(self, now: float = 0.0) -> None:
        """Look at ``TESTDIR/live.json``: a new session's ring, the last one gone or closed, its
        process dead (every :data:`ALIVE_EVERY_S` of ``now``, a monotonic time)."""
        try:
            inode = os.stat(self.path).st_ino
        except OSError:
            inode = None
        ring = self._ring
        if ring is not None and (inode != self._named or ring.closed):
            self._drop()
        if self._ring is None and inode is not None and inode != self._passed:
            self._take(inode)
        if self._ring is not None and now - self._alive_at >= ALIVE_EVERY_S:
            self._alive_at = now
            if not _alive(int(self._ring.hello.get("pid", 0) or 0)):
                self._passed = self._named          # killed: its files stay until the next session
                self._drop()

    def _take(self, inode: int) -> None:
        self._passed = inode                        # unless it is taken below
        try:
            ring = RingFile.open(_pointer(self.path)["ring"])
        except (OSError, ValueError):
            return
        if ring.closed or not _alive(int(ring.hello.get("pid", 0) or 0)) \
                or ring.width != 1 + 3 * len(ring.hello.get("channels", [])):
            ring.close()
            return
        self._passed = None
        self._named = inode
        self._offset = self._end
        self._ring = ring
        self.hello = dict(ring.hello)
        self.channels = list(ring.hello["channels"])

    def _drop(self) -> None:
        self._end = self.count
        ring, self._ring = self._ring, None
        self.hello = None
        if ring is not None:
            ring.close()

    def close(self) -> None:
        self._drop()
