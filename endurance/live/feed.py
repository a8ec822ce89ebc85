r"""The live stream a running session publishes, and the watcher's end of it.

Test process::

    control loop ──cycle()──▶ LiveFeed: a cycle every 1/SAMPLE_HZ s a row into a SampleRing
                                 │ (a store and a count: never a wait)
                                 ├──▶ the page's server in this process (``--serve``) reads the ring
                                 └──▶ feed thread: TCP on 127.0.0.1, port and key in TESTDIR/live.json
                                          │ every SEND_EVERY_S the new rows, a JSON line
    watch process                         ▼
        FeedClient thread: reads TESTDIR/live.json, connects, sends the key, puts the rows into
        its own SampleRing (the same reader code as in the test process)

A row is ``(sync_time, forces..., references..., commands...)`` in the channels' order (kgf,
kgf, %); ``sync_time`` is the cycle's SYNC on the wall clock (epoch s). Why a socket of its own:
the rolling window reaches the disk in chunks (seconds late), the journal holds end points, not
signals; a socket is read as the rows come, and its thread is the only one that waits on a
viewer. Why TCP on loopback with a key rather than a Unix socket in TESTDIR: a socket path is
limited to 107 bytes (a test directory's path may be longer); the key (random, in a file only
the test's user can read, mode 0600) keeps the feed to those who may read TESTDIR. A viewer that
does not keep up (a full send buffer of :data:`MAX_BACKLOG` bytes) is dropped; the feed never
waits for one.
"""
from __future__ import annotations

import hmac
import json
import os
import secrets
import selectors
import socket
import threading
import time
from pathlib import Path
from typing import Any

from .ring import SampleRing

LIVE_FILE = "live.json"
#: rows per second the live view gets (the loop's cycles decimated to it on the wall clock: in
#: lockstep a cycle may take longer than its period)
SAMPLE_HZ = 50.0
#: a cycle this share of a row's interval after the last row makes the next (float round-off)
_EARLY = 0.95
#: seconds of rows the rings keep (the page shows 30)
RING_S = 64.0
#: how often the feed thread sends what came
SEND_EVERY_S = 0.025
#: a viewer with this much unsent is dropped, bytes
MAX_BACKLOG = 1 << 20
#: a connection that has not sent the key within this is closed, s
AUTH_TIMEOUT_S = 2.0


def ring_for(sample_hz: float = SAMPLE_HZ) -> SampleRing:
    return SampleRing(int(RING_S * sample_hz))


class LiveFeed:
    """A session's publisher (``endurance.run``'s ``publisher``): :meth:`cycle` from the control
    loop, :meth:`open` and :meth:`close` around the session's run."""

    def __init__(self, sample_hz: float = SAMPLE_HZ) -> None:
        self.sample_hz = float(sample_hz)
        self.ring = ring_for(sample_hz)
        self.channels: list[str] = []
        self.period_s: float | None = None
        self._next = -float("inf")
        self._interval_s = _EARLY / self.sample_hz
        self._thread: _FeedThread | None = None
        #: the session's channels, sample rate and pid while it runs, else None
        self.hello: dict | None = None

    # -- the control loop's --------------------------------------------------------------------------
    def cycle(self, sync_time: float, forces, references, commands) -> None:
        """One cycle: a row into the ring if it is due (module docstring)."""
        if sync_time < self._next:
            return
        self._next = sync_time + self._interval_s
        self.ring.put((sync_time, *forces, *references, *commands))

    # -- the session's --------------------------------------------------------------------------------
    def open(self, testdir: str | Path, channels: list[str], period_s: float) -> None:
        """The session begins: its channels and period; the feed thread starts and
        ``TESTDIR/live.json`` names its port and key."""
        self.channels = list(channels)
        self.period_s = float(period_s)
        hello = {"channels": self.channels, "period_s": self.period_s, "sample_hz": self.sample_hz,
                 "pid": os.getpid()}
        self._thread = _FeedThread(Path(testdir), self.ring, hello)
        self._thread.start()
        self.hello = hello

    def close(self) -> None:
        self.hello = None
        if self._thread is not None:
            self._thread.stop()
            self._thread = None


def _encode(obj: Any) -> bytes:
    return (json.dumps(obj, separators=(",", ":")) + "\n").encode()


class _Viewer:
    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.since = time.monotonic()
        self.inbox = b""
        self.out = b""
        self.authenticated = False


class _FeedThread(threading.Thread):
    """The feed's socket (module docstring): accepts viewers, checks their key, sends each the
    last window and then every new row."""

    def __init__(self, testdir: Path, ring: SampleRing, hello: dict) -> None:
        super().__init__(name="live-feed", daemon=True)
        self.testdir = testdir
        self.ring = ring
        self.hello = hello
        self.key = secrets.token_hex(16)
        self._halt = threading.Event()
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.listener.setblocking(False)
        self.port = self.listener.getsockname()[1]
        self.path = testdir / LIVE_FILE
        tmp = testdir / f".{LIVE_FILE}.{os.getpid()}.tmp"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as fh:
            json.dump({**hello, "port": self.port, "key": self.key}, fh)
        os.replace(tmp, self.path)
        self.viewers: dict[socket.socket, _Viewer] = {}
        self.sent = ring.count

    def stop(self) -> None:
        self._halt.set()
        self.join(timeout=2.0)
        try:
            if json.loads(self.path.read_text()).get("key") == self.key:
                self.path.unlink()
        except (OSError, ValueError):
            pass

    def run(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self.listener, selectors.EVENT_READ)
        try:
            while not self._halt.is_set():
                for key, _ in sel.select(timeout=SEND_EVERY_S):
                    if key.fileobj is self.listener:
                        self._accept(sel)
                    else:
                        self._read(sel, self.viewers.get(key.fileobj))
                self._send_new(sel)
        finally:
            for v in list(self.viewers.values()):
                self._drop(sel, v)
            sel.close()
            self.listener.close()

    def _accept(self, sel) -> None:
        try:
            sock, _ = self.listener.accept()
        except OSError:
            return
        sock.setblocking(False)
        self.viewers[sock] = _Viewer(sock)
        sel.register(sock, selectors.EVENT_READ)

    def _read(self, sel, viewer: _Viewer | None) -> None:
        if viewer is None:
            return
        try:
            data = viewer.sock.recv(4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            self._drop(sel, viewer)
            return
        if viewer.authenticated:
            return                                  # a viewer has nothing more to say
        viewer.inbox += data
        if b"\n" not in viewer.inbox:
            if len(viewer.inbox) > 256:
                self._drop(sel, viewer)
            return
        given = viewer.inbox.split(b"\n", 1)[0].strip()
        if not hmac.compare_digest(given, self.key.encode()):
            self._drop(sel, viewer)
            return
        viewer.authenticated = True
        _, rows = self.ring.since(self.ring.count - int(RING_S * self.hello["sample_hz"]))
        viewer.out += _encode({"hello": self.hello}) + (_encode({"rows": rows}) if rows else b"")
        self._flush(sel, viewer)

    def _send_new(self, sel) -> None:
        now = time.monotonic()
        for v in [v for v in self.viewers.values() if not v.authenticated and now - v.since > AUTH_TIMEOUT_S]:
            self._drop(sel, v)
        self.sent, rows = self.ring.since(self.sent)
        line = _encode({"rows": rows}) if rows else b""
        for v in list(self.viewers.values()):
            if v.authenticated:
                v.out += line
                self._flush(sel, v)

    def _flush(self, sel, viewer: _Viewer) -> None:
        if not viewer.out:
            return
        try:
            n = viewer.sock.send(viewer.out)
            viewer.out = viewer.out[n:]
        except (BlockingIOError, InterruptedError):
            pass
        except OSError:
            self._drop(sel, viewer)
            return
        if len(viewer.out) > MAX_BACKLOG:
            self._drop(sel, viewer)

    def _drop(self, sel, viewer: _Viewer) -> None:
        self.viewers.pop(viewer.sock, None)
        try:
            sel.unregister(viewer.sock)
        except (KeyError, ValueError):
            pass
        viewer.sock.close()


class FeedClient:
    """The watcher's end (module docstring): a thread that follows whichever session runs the
    test in ``testdir`` (``TESTDIR/live.json``), putting its rows into :attr:`ring`.
    :attr:`hello` is the session's (channels, sample rate, pid) while connected, else None."""

    RETRY_S = 0.5

    def __init__(self, testdir: str | Path) -> None:
        self.testdir = Path(testdir)
        self.ring = ring_for()
        self.hello: dict | None = None
        self.channels: list[str] = []
        self._halt = threading.Event()
        self._sock: socket.socket | None = None
        self._thread = threading.Thread(target=self._run, name="live-feed-client", daemon=True)

    def start(self) -> "FeedClient":
        self._thread.start()
        return self

    def close(self) -> None:
        self._halt.set()
        sock = self._sock
        if sock is not None:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self._thread.join(timeout=2.0)

    def _run(self) -> None:
        while not self._halt.is_set():
            try:
                info = json.loads((self.testdir / LIVE_FILE).read_text())
                self._follow(int(info["port"]), str(info["key"]))
            except (OSError, ValueError, KeyError, TypeError):
                pass
            self.hello = None
            self._halt.wait(self.RETRY_S)

    def _follow(self, port: int, key: str) -> None:
        with socket.create_connection(("127.0.0.1", port), timeout=1.0) as sock:
            self._sock = sock
            try:
                sock.sendall(key.encode() + b"\n")
                sock.settimeout(None)
                with sock.makefile("rb") as stream:
                    for line in stream:
                        if self._halt.is_set():
                            return
                        msg = json.loads(line)
                        if "hello" in msg:
                            self.hello = msg["hello"]
                            self.channels = list(self.hello["channels"])
                        for row in msg.get("rows", ()):
                            self.ring.put(tuple(row))
            finally:
                self._sock = None
