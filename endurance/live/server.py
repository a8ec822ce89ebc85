r"""The live page's server: tornado's HTTP server on an event loop of its own thread.

=================  ===================================================================
``GET /``          the page (``static/index.html``; every asset in the package, no CDN)
``GET /static/*``  its script, style and the plotting library (uPlot, vendored)
``GET /status.json``  exactly what ``stand test status --json`` prints
``GET /page.json`` what the page needs to know: channels, window, read-only or not
``GET /live``      the live stream, server-sent events (below)
``POST /pause``    stop at the end of the flight; ``/stop``: at once, unloading keeping the
``POST /stop``     ratios; ``/resume``: resume the test (:mod:`endurance.live.operator`).
``POST /resume``   Each with ``Authorization: Bearer TOKEN``; refused (403) and logged
                   otherwise; any other method on them 405 (logged too), other paths 404
=================  ===================================================================

**The stream** (``text/event-stream``; a browser's ``EventSource`` reconnects by itself): on
connect ``page`` (as ``/page.json``), ``samples`` (the last :data:`WINDOW_S` s), ``status``,
``events`` (the latest 50), ``trend`` (the flights the page keeps); then every
:data:`TICK_S` the new ``samples`` (columns: ``t`` epoch s, per channel ``y`` force and ``r``
reference in kgf, ``u`` valve command in %), ``events`` as the journal records them (polled
every :data:`EVENTS_EVERY` ticks), ``status`` when it changed (polled every
:data:`STATUS_EVERY` ticks, and at once after an event), ``trend`` after each flight,
``session`` when the feed's session comes or goes. One message is encoded once for every
viewer; a viewer that falls :data:`VIEWER_BACKLOG` messages behind is dropped.

**It does not disturb the loop.** The server reads what the session publishes (the feed's ring
buffer, :mod:`endurance.live.feed`) and the journal (a reader in WAL mode); its work is a few
small JSON messages a tick, whatever the number of viewers. ``benchmarks/live.py`` measures the
loop with and without three viewers.

**Safety.** It binds 127.0.0.1 unless ``--serve`` names another host; bound to loopback it
answers only requests whose ``Host`` is a loopback name (a web page elsewhere cannot reach it by
a DNS name pointing at 127.0.0.1); its pages may load nothing from elsewhere
(``Content-Security-Policy``); a cross-origin page cannot send the ``Authorization`` header
(no CORS is answered).
"""
from __future__ import annotations

import asyncio
import ipaddress
import json
import logging
import math
import socket
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import tornado.httpserver
import tornado.ioloop
import tornado.iostream
import tornado.netutil
import tornado.web

from core.errors import ParameterError
from endurance.report import status_json

from .operator import ACTIONS, Operator, Refused
from .ring import SampleRing
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
LOOPBACK_NAMES = {"localhost", "127.0.0.1", "::1"}
log = logging.getLogger(__name__)


# -- the address -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Address:
    host: str
    port: int

    @property
    def loopback(self) -> bool:
        try:
            return ipaddress.ip_address(self.host).is_loopback
        except ValueError:
            return self.host == "localhost"

    def url(self, port: int | None = None) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port if port is None else port}/"


def serve_address(text: str) -> Address:
    """``--serve``'s value: ``HOST:PORT``, ``[IPV6]:PORT``, ``:PORT`` or ``PORT`` (then
    127.0.0.1); port 0: any free one."""
    value = text.strip()
    host, port = "127.0.0.1", value
    if value.startswith("["):
        inside, _, rest = value[1:].partition("]")
        if not rest.startswith(":"):
            raise ParameterError(f"--serve {text}: give [IPV6]:PORT, e.g. [::1]:8080")
        host, port = inside, rest[1:]
    elif ":" in value:
        host, _, port = value.rpartition(":")
        host = host or "127.0.0.1"
        if ":" in host:
            raise ParameterError(f"--serve {text}: an IPv6 address goes in brackets, e.g. [::1]:8080")
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ParameterError(f"--serve {text}: give HOST:PORT with a port 0-65535, e.g. 127.0.0.1:8080 "
                             "(a port alone serves on 127.0.0.1)")
    return Address(host, int(port))


# -- where the signals come from --------------------------------------------------------------------------
class SampleSource(Protocol):
    """A session's live rows (:class:`~endurance.live.feed.LiveFeed` in the test process,
    :class:`~endurance.live.feed.FeedClient` in a watcher)."""

    ring: SampleRing
    channels: list[str]
    hello: dict | None


def sse(event: str, data: Any) -> bytes:
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n".encode()


def sample_columns(rows: list, n: int) -> dict:
    """Rows ``(t, y…, r…, u…)`` of ``n`` channels as the stream's columns (NaN: null)."""
    def col(k: int, digits: int) -> list:
        return [None if not math.isfinite(row[k]) else round(row[k], digits) for row in rows]
    return {"t": col(0, 3), "y": [col(1 + i, 1) for i in range(n)], "r": [col(1 + n + i, 1) for i in range(n)],
            "u": [col(1 + 2 * n + i, 3) for i in range(n)]}


class Hub:
    """The stream's viewers and what is sent to them (module docstring); its :meth:`tick`
    runs on the server's event loop."""

    def __init__(self, view: JournalView, source: SampleSource, operator: Operator, kind: str) -> None:
        self.view = view
        self.source = source
        self.operator = operator
        self.kind = kind
        self.viewers: set[asyncio.Queue] = set()
        self.seq = source.ring.count
        self.ticks = 0
        self.status_text: str | None = None
        self.session: dict | None = None

    def page(self) -> dict:
        return {"kind": self.kind, "channels": self.channels(), "window_s": WINDOW_S,
                "read_only": self.operator.read_only,
                "actions": [a for a in ACTIONS if a != "resume" or self.operator.can_resume],
                "session": self.source.hello}

    def channels(self) -> list[str]:
        if self.source.channels:
            return list(self.source.channels)
        journal = self.view.journal
        return list(journal.channels) if journal is not None else []

    def greeting(self) -> list[bytes]:
        """What a viewer gets first (module docstring); call it right before :meth:`join`."""
        new = self.view.new_trends()                  # the flights done before it, at first
        if new:
            self.send(sse("trend", new))
        n = len(self.channels())
        ring = self.source.ring
        window = int(WINDOW_S * (self.source.hello or {}).get("sample_hz", 50.0))
        _, rows = ring.since(self.seq - window)
        rows = [r for r in rows if len(r) == 1 + 3 * n]
        out = [sse("page", self.page())]
        if rows:
            out.append(sse("samples", sample_columns(rows, n)))
        status = self.view.status()
        if status is not None:
            out.append(sse("status", status))
        out.append(sse("events", self.view.recent_events()))
        out.append(sse("trend", list(self.view.trends.rows)))
        return out

    def join(self) -> asyncio.Queue:
        q: asyncio.Queue = asyncio.Queue(VIEWER_BACKLOG)
        self.viewers.add(q)
        return q

    def leave(self, q: asyncio.Queue) -> None:
        self.viewers.discard(q)

    def send(self, message: bytes) -> None:
        for q in list(self.viewers):
            try:
                q.put_nowait(message)
            except asyncio.QueueFull:          # it does not keep up: drop it (None ends it)
                self.viewers.discard(q)
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
        hello = self.source.hello
        if hello != self.session:
            self.session = hello
            self.send(sse("session", {"session": hello, "channels": self.channels()}))
        self.seq, rows = self.source.ring.since(self.seq)
        n = len(self.channels())
        rows = [r for r in rows if len(r) == 1 + 3 * n]
        if rows and self.viewers:
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
            q.put_nowait(None)
        self.viewers.clear()


# -- the handlers -----------------------------------------------------------------------------------------
class _Guarded:
    """Every handler: the Host check (module docstring) and the security headers."""

    def prepare(self) -> None:
        settings = self.application.settings
        if settings["loopback"]:
            host = self.request.host_name.strip("[]").lower()
            if host not in LOOPBACK_NAMES and not _is_loopback(host):
                raise tornado.web.HTTPError(403, reason="Host not allowed")

    def set_default_headers(self) -> None:
        self.set_header("Content-Security-Policy", "default-src 'self'; frame-ancestors 'none'")
        self.set_header("X-Content-Type-Options", "nosniff")
        self.set_header("Referrer-Policy", "no-referrer")
        self.set_header("Cache-Control", "no-store")


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class _Handler(_Guarded, tornado.web.RequestHandler):
    @property
    def hub(self) -> Hub:
        return self.application.settings["hub"]

    def reply(self, status: int, body: dict) -> None:
        self.set_status(status)
        self.set_header("Content-Type", "application/json")
        self.finish(json.dumps(body) + "\n")

    def write_error(self, status_code: int, **kwargs: Any) -> None:
        self.set_header("Content-Type", "application/json")
        self.finish(json.dumps({"error": self._reason}) + "\n")


class _Static(_Guarded, tornado.web.StaticFileHandler):
    pass


class PageHandler(_Handler):
    def get(self) -> None:
        self.set_header("Content-Type", "text/html; charset=utf-8")
        self.finish((STATIC / "index.html").read_bytes())


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
    async def get(self) -> None:
        self.set_header("Content-Type", "text/event-stream")
        self.set_header("X-Accel-Buffering", "no")
        hub = self.hub
        for message in hub.greeting():
            self.write(message)
        q = self._queue = hub.join()
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
        q = getattr(self, "_queue", None)
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
        client = self.request.remote_ip or "?"
        why = operator.refusal(self.request.headers.get("Authorization"))
        if why is not None:
            operator.log_refusal(f"POST /{action}", why, client)
            self.reply(403, {"refused": why})
            return
        try:
            done = operator.act(action, client)
        except Refused as exc:
            self.reply(exc.status, {"refused": str(exc)})
            return
        self.reply(200, {"ok": True, "action": done.action, "message": done.message})

    def _not_post(self, action: str) -> None:
        self.hub.operator.log_refusal(f"{self.request.method} /{action}", "an action is a POST",
                                      self.request.remote_ip or "?")
        self.set_header("Allow", "POST")
        self.reply(405, {"refused": f"/{action} is an action: POST it with Authorization: Bearer TOKEN"})

    get = put = delete = patch = _not_post     # type: ignore[assignment]


def _quiet(handler: tornado.web.RequestHandler) -> None:
    log.debug("%s %s %s", handler.get_status(), handler.request.method, handler.request.uri)


def make_app(hub: Hub, loopback: bool) -> tornado.web.Application:
    actions = "|".join(ACTIONS)
    return tornado.web.Application([
        (r"/", PageHandler),
        (r"/status\.json", StatusHandler),
        (r"/page\.json", PageInfoHandler),
        (r"/live", StreamHandler),
        (rf"/({actions})", ActionHandler),
        (r"/static/(.*)", _Static, {"path": str(STATIC)}),
    ], hub=hub, loopback=loopback, log_function=_quiet, compress_response=False)


# -- the server -----------------------------------------------------------------------------------------------
class LiveServer:
    """The page's server for the test in ``testdir`` on ``address`` (module docstring):
    :meth:`start` binds (a clear error if it cannot) and serves on a thread of its own;
    ``kind`` "session" (served by the running session) or "watch"."""

    def __init__(self, address: Address, testdir: str | Path, source: SampleSource, operator: Operator,
                 kind: str) -> None:
        self.address = address
        self.testdir = Path(testdir)
        self.source = source
        self.operator = operator
        self.kind = kind
        self.url: str | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self.hub: Hub | None = None

    def start(self) -> str:
        """Bind and serve; the page's URL."""
        try:
            sockets = tornado.netutil.bind_sockets(self.address.port, self.address.host,
                                                   family=socket.AF_UNSPEC)
        except (OSError, socket.gaierror) as exc:
            raise ParameterError(f"--serve {self.address.host}:{self.address.port}: cannot listen there "
                                 f"({exc.strerror or exc})") from None
        port = sockets[0].getsockname()[1]
        self.url = self.address.url(port)
        self._thread = threading.Thread(target=self._serve, args=(sockets,), name="live-page", daemon=True)
        self._thread.start()
        self._ready.wait(10.0)
        return self.url

    def _serve(self, sockets) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        self._loop = loop
        self.hub = Hub(JournalView(self.testdir), self.source, self.operator, self.kind)
        server = tornado.httpserver.HTTPServer(make_app(self.hub, self.address.loopback))
        server.add_sockets(sockets)
        ticker = tornado.ioloop.PeriodicCallback(self.hub.tick, TICK_S * 1000)
        ticker.start()
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            ticker.stop()
            server.stop()
            self.hub.close()
            self.hub.view.close()
            loop.run_until_complete(asyncio.sleep(0.05))
            loop.close()

    def stop(self) -> None:
        if self._loop is not None and self._thread is not None:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=5.0)
