r"""The live page's server: the page, its stream and the operator's actions (tornado, on an event
loop of its own, in a process of its own: :mod:`endurance.live.process`).

=================  ===================================================================
``GET /``          the page (``static/index.html``; every asset in the package, no CDN)
``GET /static/*``  its script, style and the plotting library (uPlot, vendored)
``GET /status.json``  exactly what ``stand test status --json`` prints
``GET /page.json`` what the page needs to know: channels, window, read-only or not
``GET /live``      the live stream, server-sent events (below)
``POST /pause``    stop at the end of the flight; ``/stop``: at once, unloading keeping the
``POST /stop``     ratios; ``/resume``: resume the test (:mod:`endurance.live.operator`).
``POST /resume``   Each with ``Authorization: Bearer TOKEN``; refused (403) otherwise; any
                   other method on them 405; other paths 404. Every refusal is counted
                   (:class:`endurance.live.limits.RefusalTally`).
=================  ===================================================================

**The stream** (``text/event-stream``; a browser's ``EventSource`` reconnects by itself, after
:data:`RETRY_MS`): on connect ``page`` (as ``/page.json``), ``samples`` (the last
:data:`WINDOW_S` s), ``status``, ``events`` (the latest 50), ``trend`` (the flights the page
keeps); then every :data:`TICK_S` the new ``samples`` (columns: ``t`` epoch s, per channel ``y``
force and ``r`` reference in kgf, ``u`` valve command in %), ``events`` as the journal records
them (polled every :data:`EVENTS_EVERY` ticks), ``status`` when it changed (polled every
:data:`STATUS_EVERY` ticks, and at once after an event), ``trend`` after each flight,
``session`` when a session comes or goes. One message is encoded once for every viewer; a viewer
that falls :data:`VIEWER_BACKLOG` messages behind is dropped.

**What it reads.** The session's rows from ``TESTDIR/live.ring`` (:mod:`endurance.live.feed`,
mapped read-only) and the journal (a reader in WAL mode): nothing it does reaches the session
but the operator's actions and its events (``TESTDIR/stop.json``, ``TESTDIR/inbox/``).

**Safety.** The Host check (:class:`endurance.live.binding.Binding`: never off), the security
headers on every response (:data:`endurance.live.guard.SECURITY_HEADERS`: its pages load nothing
from elsewhere), no CORS (a page elsewhere cannot send the ``Authorization`` header), the static
files read once at start (no path reaches the file system), and every resource a client can
take bounded (:mod:`endurance.live.guard`, :mod:`endurance.live.limits`).
"""
from __future__ import annotations

import asyncio
import collections
import json
import logging
import mimetypes
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import tornado.ioloop
import tornado.iostream
import tornado.web

from endurance.inbox import record_event
from endurance.report import status_json

from .binding import Binding
from .feed import FeedReader
from .guard import SECURITY_HEADERS, GuardedHTTPServer, TornadoRefusals, printable
from .limits import Limits, RateLimitedHandler, RefusalTally
from .operator import ACTIONS, Operator, Refused
from .view import JournalView

STATIC = Path(__file__).resolve().parent / "static"
#: the seconds of signals the page shows
WINDOW_S = 30.0
#: how often the stream sends what is new, s
TICK_S = 0.05
EVENTS_EVERY = 2
STATUS_EVERY = 10
#: messages a viewer may fall behind before it is dropped
VIEWER_BACKLOG = 400
#: how long a browser waits before it opens the stream again, ms
RETRY_MS = 1000
#: how often the connections are swept, the refusals summarised and the log rolled, s
HOUSEKEEPING_S = 1.0
log = logging.getLogger(__name__)


def sse(event: str, data: Any) -> bytes:
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n".encode()


def sample_columns(rows: np.ndarray, n: int) -> dict:
    """Rows ``(t, y…, r…, u…)`` of ``n`` channels as the stream's columns (NaN: null)."""
    def col(k: int, digits: int) -> list:
        return [v if v == v else None for v in np.round(rows[:, k], digits).tolist()]
    return {"t": col(0, 3), "y": [col(1 + i, 1) for i in range(n)], "r": [col(1 + n + i, 1) for i in range(n)],
            "u": [col(1 + 2 * n + i, 3) for i in range(n)]}


class Hub:
    """The stream's viewers and what is sent to them (module docstring); its :meth:`tick`
    runs on the server's event loop."""

    def __init__(self, view: JournalView, source: FeedReader, operator: Operator, kind: str,
                 limits: Limits = Limits()) -> None:
        self.view = view
        self.source = source
        self.operator = operator
        self.kind = kind
        self.limits = limits
        self.viewers: dict[asyncio.Queue, str] = {}
        self.by_address: collections.Counter[str] = collections.Counter()
        self.seq = source.count
        self.ticks = 0
        self.status_text: str | None = None
        self.session: dict | None = None

    def page(self) -> dict:
        return {"kind": self.kind, "channels": self.channels(), "window_s": WINDOW_S,
                "read_only": self.operator.read_only,
                "actions": [a for a in ACTIONS if a != "resume" or self.operator.can_resume],
                "session": self.source.hello}

    def channels(self) -> list[str]:
        if self.source.channels and self.source.hello is not None:
            return list(self.source.channels)
        journal = self.view.journal
        return list(journal.channels) if journal is not None else []

    def refusal(self, client: str) -> str | None:
        """Why a new stream for ``client`` is refused (None: it may have one)."""
        if len(self.viewers) >= self.limits.streams:
            return f"the server has {self.limits.streams} live streams open; try again later"
        if self.by_address[client] >= self.limits.streams_per_address:
            return f"{client} has {self.limits.streams_per_address} live streams open; close a page"
        return None

    def greeting(self) -> list[bytes]:
        """What a viewer gets first (module docstring); call it right before :meth:`join`."""
        new = self.view.new_trends()                  # the flights done before it, at first
        if new:
            self.send(sse("trend", new))
        n = len(self.channels())
        window = int(WINDOW_S * (self.source.hello or {}).get("sample_hz", 50.0))
        _, rows = self.source.since(self.seq - window)
        out = [f"retry: {RETRY_MS}\n\n".encode(), sse("page", self.page())]
        if len(rows) and rows.shape[1] == 1 + 3 * n:
            out.append(sse("samples", sample_columns(rows, n)))
        status = self.view.status()
        if status is not None:
            out.append(sse("status", status))
        out.append(sse("events", self.view.recent_events()))
        out.append(sse("trend", list(self.view.trends.rows)))
        return out

    def join(self, client: str) -> asyncio.Queue:
        q: asyncio.Queue = asyncio.Queue(VIEWER_BACKLOG)
        self.viewers[q] = client
        self.by_address[client] += 1
        return q

    def leave(self, q: asyncio.Queue) -> None:
        client = self.viewers.pop(q, None)
        if client is not None:
            self.by_address[client] -= 1
            if self.by_address[client] <= 0:
                del self.by_address[client]

    def send(self, message: bytes) -> None:
        for q in list(self.viewers):
            try:
                q.put_nowait(message)
            except asyncio.QueueFull:          # it does not keep up: drop it (None ends it)
                self.leave(q)
                while not q.empty():
                    q.get_nowait()
                q.put_nowait(None)

    def tick(self) -> None:
        try:
            self._tick()
        except Exception:                      # never let one bad poll end the stream
            log.exception("live page: a tick failed")

    def _tick(self) -> None:
        self.ticks += 1
        self.source.poll(time.monotonic())
        hello = self.source.hello
        if hello != self.session:
            self.session = hello
            self.send(sse("session", {"session": hello, "channels": self.channels()}))
        self.seq, rows = self.source.since(self.seq)
        n = len(self.channels())
        if len(rows) and self.viewers and rows.shape[1] == 1 + 3 * n:
            self.send(sse("samples", sample_columns(rows, n)))
        fresh = False
        if self.ticks % EVENTS_EVERY == 0:
            events = self.view.new_events()
            if events:
                self.send(sse("events", events))
                fresh = True
        if fresh or self.ticks % STATUS_EVERY == 0:
            status = self.view.status()
            text = json.dumps(status, sort_keys=True)
            if status is not None and text != self.status_text:
                self.status_text = text
                self.send(sse("status", status))
                trend = self.view.new_trends()
                if trend:
                    self.send(sse("trend", trend))

    def close(self) -> None:
        for q in list(self.viewers):
            while not q.empty():
                q.get_nowait()
            q.put_nowait(None)
        self.viewers.clear()
        self.by_address.clear()


# -- the handlers -----------------------------------------------------------------------------------------
class _Handler(tornado.web.RequestHandler):
    """Every handler: the Host check (module docstring), the security headers, JSON errors;
    :attr:`refusal` says why a request was refused (counted when it ends)."""

    refusal: str | None = None

    @property
    def hub(self) -> Hub:
        return self.application.settings["hub"]

    @property
    def client(self) -> str:
        return self.request.remote_ip or "?"

    def prepare(self) -> None:
        binding: Binding = self.application.settings["binding"]
        if not binding.host_allowed(self.request.host_name):
            self.refuse(403, "Host not allowed", f"this server answers only to its own names, not "
                                                 f"{printable(self.request.host_name, 64)}")

    def refuse(self, status: int, why: str, message: str | None = None) -> None:
        """Answer ``status`` with ``{"refused": message}``; counted as refused for ``why``."""
        self.refusal = why
        self.reply(status, {"refused": message or why})

    def set_default_headers(self) -> None:
        self.clear_header("Server")                  # what it runs on is nobody's business
        for name, value in SECURITY_HEADERS.items():
            self.set_header(name, value)

    def reply(self, status: int, body: dict) -> None:
        self.set_status(status)
        self.set_header("Content-Type", "application/json")
        self.finish(json.dumps(body) + "\n")

    def write_error(self, status_code: int, **kwargs: Any) -> None:
        self.set_header("Content-Type", "application/json")
        self.finish(json.dumps({"error": self._reason}) + "\n")


class NotFoundHandler(_Handler):
    """Any path the server does not have: 404 (every method), headers and all."""

    def prepare(self) -> None:
        super().prepare()
        if not self._finished:
            self.refuse(404, "no such page")


class PageHandler(_Handler):
    def get(self) -> None:
        body, kind = self.application.settings["files"]["index.html"]
        self.set_header("Content-Type", kind)
        self.finish(body)


class StaticHandler(_Handler):
    """The page's files, read once at start (:func:`static_files`): no path reaches the disk."""

    def get(self, path: str) -> None:
        found = self.application.settings["files"].get(path)
        if found is None:
            self.refuse(404, "no such page")
            return
        body, kind = found
        self.set_header("Content-Type", kind)
        self.finish(body)


class StatusHandler(_Handler):
    def get(self) -> None:
        status = self.hub.view.status()
        if status is None:
            self.reply(503, {"error": "the test has no journal yet"})
            return
        self.set_header("Content-Type", "application/json")
        self.finish(status_json(status))


class PageInfoHandler(_Handler):
    def get(self) -> None:
        self.reply(200, self.hub.page())


class StreamHandler(_Handler):
    _queue: asyncio.Queue | None = None

    async def get(self) -> None:
        hub = self.hub
        why = hub.refusal(self.client)
        if why is not None:
            self.set_header("Retry-After", "10")
            self.refuse(503, "too many live streams", why)
            return
        self.set_header("Content-Type", "text/event-stream")
        self.set_header("X-Accel-Buffering", "no")
        for message in hub.greeting():
            self.write(message)
        q = self._queue = hub.join(self.client)
        try:
            await self.flush()
            while True:
                message = await q.get()
                if message is None:
                    break
                self.write(message)
                await self.flush()
        except tornado.iostream.StreamClosedError:
            pass
        finally:
            hub.leave(q)

    def on_connection_close(self) -> None:
        q = self._queue
        if q is not None:
            self.hub.leave(q)
            try:
                q.put_nowait(None)
            except asyncio.QueueFull:
                pass


class ActionHandler(_Handler):
    """``POST /pause|stop|resume`` (module docstring)."""

    def post(self, action: str) -> None:
        operator = self.hub.operator
        why = operator.refusal(self.request.headers.get("Authorization"))
        if why is not None:
            self.refuse(403, why)
            return
        try:
            done = operator.act(action, self.client)
        except Refused as exc:
            self.reply(exc.status, {"refused": str(exc)})
            return
        self.reply(200, {"ok": True, "action": done.action, "message": done.message})

    def _not_post(self, action: str) -> None:
        self.set_header("Allow", "POST")
        self.refuse(405, "an action is a POST", f"/{action} is an action: POST it with Authorization: Bearer TOKEN")

    get = head = options = put = delete = patch = _not_post     # type: ignore[assignment]


def _log_request(tally: RefusalTally) -> Callable[[tornado.web.RequestHandler], None]:
    """Every request at its end: a refused one counted for its client (a handler's
    :attr:`_Handler.refusal`, tornado's own 400 and 405); not a 409 (the operator's action
    that cannot be taken now) nor a server's error (tornado logs those)."""
    def logged(handler: tornado.web.RequestHandler) -> None:
        status = handler.get_status()
        why = getattr(handler, "refusal", None)
        if why is None:
            if status == 405:
                why = "an action is a POST" if isinstance(handler, ActionHandler) else "method not allowed"
            elif status == 400:
                why = "bad request"
            else:
                return
        request = handler.request
        tally.refuse(request.remote_ip or "?", f"{request.method} {printable(request.path)}", why)
    return logged


def static_files() -> dict[str, tuple[bytes, str]]:
    """Every file of ``static/`` by its path there: its bytes and type."""
    out = {}
    for path in sorted(STATIC.rglob("*")):
        if path.is_file():
            kind = mimetypes.guess_type(path.name)[0] or "text/plain"
            if kind.startswith("text/") or kind.endswith(("+xml", "javascript")):
                kind += "; charset=utf-8"
            out[path.relative_to(STATIC).as_posix()] = (path.read_bytes(), kind)
    return out


def make_app(hub: Hub, binding: Binding, tally: RefusalTally) -> tornado.web.Application:
    actions = "|".join(ACTIONS)
    return tornado.web.Application([
        (r"/", PageHandler),
        (r"/status\.json", StatusHandler),
        (r"/page\.json", PageInfoHandler),
        (r"/live", StreamHandler),
        (rf"/({actions})", ActionHandler),
        (r"/static/(.*)", StaticHandler),
    ], hub=hub, binding=binding, files=static_files(), default_handler_class=NotFoundHandler,
        log_function=_log_request(tally), compress_response=False)


# -- the server -----------------------------------------------------------------------------------------------
class LiveServer:
    """The page's server for the test in ``testdir`` (module docstring) on listening ``sockets``
    (:func:`endurance.live.binding.bind_listeners`): :meth:`serve` in the calling thread until
    :meth:`stop` (the server's process), or :meth:`start` on a thread of its own (the tests).
    ``kind`` "session" (served for the running session) or "watch"; ``record`` journals a
    refusal's message (default: a ``refused`` event in the test's journal)."""

    def __init__(self, testdir: str | Path, operator: Operator, kind: str, binding: Binding,
                 limits: Limits = Limits(), record: Callable[[str], None] | None = None) -> None:
        self.testdir = Path(testdir)
        self.operator = operator
        self.kind = kind
        self.binding = binding
        self.limits = limits
        self.record = record or (lambda message: record_event(self.testdir, "refused", message))
        self.hub: Hub | None = None
        self.server: GuardedHTTPServer | None = None
        self.tally: RefusalTally | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()

    def serve(self, sockets, on_ready: Callable[[], None] | None = None) -> None:
        """Serve on ``sockets`` in this thread until :meth:`stop`; ``on_ready`` once it accepts."""
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        self._loop = loop
        tally = self.tally = RefusalTally(self.limits, self.record, log)
        refusals = TornadoRefusals(tally)
        general = logging.getLogger("tornado.general")
        general.addFilter(refusals)
        level = general.level
        general.setLevel(logging.INFO)
        self.hub = Hub(JournalView(self.testdir), FeedReader(self.testdir), self.operator, self.kind, self.limits)
        server = self.server = GuardedHTTPServer(make_app(self.hub, self.binding, tally), limits=self.limits,
                                                 tally=tally, ssl_options=self.binding.tls_context())
        server.add_sockets(sockets)
        handlers = [h for h in logging.getLogger().handlers if isinstance(h, RateLimitedHandler)]

        def housekeeping() -> None:
            server.sweep()
            tally.tick()
            for handler in handlers:
                handler.roll()
        ticker = tornado.ioloop.PeriodicCallback(self.hub.tick, TICK_S * 1000)
        keeper = tornado.ioloop.PeriodicCallback(housekeeping, HOUSEKEEPING_S * 1000)
        ticker.start()
        keeper.start()
        self._ready.set()
        if on_ready is not None:
            on_ready()
        try:
            loop.run_forever()
        finally:
            ticker.stop()
            keeper.stop()
            server.stop()
            tally.flush()
            self.hub.close()
            self.hub.view.close()
            self.hub.source.close()
            general.removeFilter(refusals)
            general.setLevel(level)
            loop.run_until_complete(asyncio.sleep(0.05))
            loop.close()

    def start(self, sockets) -> None:
        """:meth:`serve` on a thread of its own; returns once it accepts."""
        self._thread = threading.Thread(target=self.serve, args=(sockets,), name="live-page", daemon=True)
        self._thread.start()
        if not self._ready.wait(30.0):
            raise RuntimeError("the live page's server did not start")

    def stop(self) -> None:
        """End :meth:`serve` (from any thread)."""
        if self._loop is not None and not self._loop.is_closed():
            try:
                self._loop.call_soon_threadsafe(self._loop.stop)
            except RuntimeError:
                pass
        if self._thread is not None:
            self._thread.join(timeout=5.0)


def log_to_stderr(limits: Limits) -> RateLimitedHandler:
    """The server process's logging: warnings and worse to stderr, rate-limited."""
    handler = RateLimitedHandler(sys.stderr, limits.log_lines_per_minute)
    handler.setLevel(logging.WARNING)
    handler.setFormatter(logging.Formatter("%(asctime)s %(message)s", "%Y-%m-%d %H:%M:%S"))
    root = logging.getLogger()
    root.addHandler(handler)
    root.setLevel(logging.WARNING)
    return handler
