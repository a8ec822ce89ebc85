"""The live page's HTTP server below the application: tornado's, with every connection counted and
bounded (:class:`endurance.live.limits.Limits`).

* **Accepting.** A connection over the limits (in all, per client address) is closed as it is
  accepted and counted as a refusal. When accepting fails all the same (out of descriptors:
  the journal, a resume's pipes and the imports take some of the process's limit), the server
  stops accepting for :data:`ACCEPT_PAUSE_S` instead of failing in a loop.
* **Counting.** A connection counts from its acceptance until its socket is closed, whatever
  closes it (the stream's ``close_fd``): so the count is the descriptors it holds.
* **Sizes and times.** tornado's own: a request's line and headers at most
  :attr:`~Limits.header_bytes`, within :attr:`~Limits.header_timeout_s` (also a kept-alive
  connection's wait for its next request), a body within :attr:`~Limits.body_timeout_s`; a body
  declared longer than :attr:`~Limits.body_bytes` is answered 413 before any of it is read.
* **Writing.** A connection whose output has waited :attr:`~Limits.write_timeout_s` without the
  client taking it is closed (:meth:`GuardedHTTPServer.sweep`, every second).
* **Malformed requests.** tornado answers them 400; its log line for each is counted as a
  refusal instead (:class:`TornadoRefusals`).
"""
from __future__ import annotations

import errno
import json
import logging
import socket
import ssl
import time
from typing import Any

import tornado.httpserver
import tornado.httputil
import tornado.iostream
import tornado.netutil
from tornado.ioloop import IOLoop

from .binding import BACKLOG
from .limits import Connections, Limits, RefusalTally

#: how long the server stops accepting when it is out of descriptors, s
ACCEPT_PAUSE_S = 0.25
#: what the server reads at a time, and at most holds unread, per connection, bytes
READ_CHUNK_BYTES = 16384
MAX_READ_BUFFER_BYTES = 65536
#: on every response: no script, style or frame from elsewhere, no guessing of types, no referrer
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}
log = logging.getLogger(__name__)


def client_of(address: Any) -> str:
    return str(address[0]) if isinstance(address, tuple) and address else "?"


class _Counted:
    """A stream that tells its server when its socket is closed."""

    server: "GuardedHTTPServer"
    client: str

    def close_fd(self) -> None:
        try:
            super().close_fd()                       # type: ignore[misc]
        finally:
            self.server._closed(self)


class _Stream(_Counted, tornado.iostream.IOStream):
    pass


class _TLSStream(_Counted, tornado.iostream.SSLIOStream):
    pass


class _BodyLimit(tornado.httputil.HTTPMessageDelegate):
    """The application's delegate for one request, behind a look at its declared length."""

    def __init__(self, inner: tornado.httputil.HTTPMessageDelegate, conn, server: "GuardedHTTPServer",
                 client: str) -> None:
        self.inner = inner
        self.conn = conn
        self.server = server
        self.client = client

    def headers_received(self, start_line, headers):
        length = headers.get("Content-Length", "").strip()
        if length.isdigit() and int(length) > self.server.limits.body_bytes:
            self.server.refuse_body(self.conn, start_line, self.client, int(length))
            return None
        return self.inner.headers_received(start_line, headers)

    def data_received(self, chunk):
        return self.inner.data_received(chunk)

    def finish(self) -> None:
        self.inner.finish()

    def on_connection_close(self) -> None:
        self.inner.on_connection_close()


def raw_response(status: int, reason: str, body: dict) -> bytes:
    """A whole response with the security headers, for a connection tornado no longer handles."""
    data = (json.dumps(body) + "\n").encode()
    head = [f"HTTP/1.1 {status} {reason}", "Content-Type: application/json", f"Content-Length: {len(data)}",
            "Connection: close", *(f"{k}: {v}" for k, v in SECURITY_HEADERS.items())]
    return ("\r\n".join(head) + "\r\n\r\n").encode() + data


class GuardedHTTPServer(tornado.httpserver.HTTPServer):
    """tornado's HTTP server with the module docstring's bounds; ``tally`` counts refusals."""

    def initialize(self, request_callback, *, limits: Limits, tally: RefusalTally,  # type: ignore[override]
                   ssl_options: ssl.SSLContext | None = None) -> None:
        super().initialize(request_callback, ssl_options=ssl_options, decompress_request=False,
                           max_header_size=limits.header_bytes, max_body_size=limits.body_bytes,
                           idle_connection_timeout=limits.header_timeout_s, body_timeout=limits.body_timeout_s,
                           max_buffer_size=MAX_READ_BUFFER_BYTES)
        self.read_chunk_size = READ_CHUNK_BYTES
        self.limits = limits
        self.tally = tally
        self.connections = Connections(limits)
        #: every open stream, and since when its output has waited (None: it has not)
        self.streams: dict[tornado.iostream.IOStream, float | None] = {}
        #: times the server was out of descriptors
        self.out_of_descriptors = 0

    # -- accepting ------------------------------------------------------------------------------------
    def add_sockets(self, sockets) -> None:
        for sock in sockets:
            self._sockets[sock.fileno()] = sock
            self._handlers[sock.fileno()] = self._listen(sock)

    def _listen(self, sock: socket.socket):
        loop = IOLoop.current()
        state = {"on": True, "removed": False}

        def again() -> None:
            if not state["removed"] and not state["on"]:
                state["on"] = True
                loop.add_handler(sock, accept, IOLoop.READ)

        def accept(fd, events) -> None:
            for _ in range(BACKLOG):
                if state["removed"]:
                    return
                try:
                    conn, address = sock.accept()
                except (BlockingIOError, InterruptedError):
                    return
                except ConnectionAbortedError:
                    continue
                except OSError as exc:             # out of descriptors (or worse): a pause, never a busy loop
                    if exc.errno in (errno.EMFILE, errno.ENFILE):
                        self.out_of_descriptors += 1
                    log.warning("live page: cannot accept (%s); not accepting for %.2f s",
                                exc.strerror or exc, ACCEPT_PAUSE_S)
                    loop.remove_handler(sock)
                    state["on"] = False
                    loop.call_later(ACCEPT_PAUSE_S, again)
                    return
                client = client_of(address)
                why = self.connections.refusal(client)
                if why is not None:
                    conn.close()
                    self.tally.refuse(client, "a connection", why)
                    continue
                self._handle_connection(conn, address)

        loop.add_handler(sock, accept, IOLoop.READ)

        def remove() -> None:
            state["removed"] = True
            if state["on"]:
                loop.remove_handler(sock)
        return remove

    def _handle_connection(self, connection: socket.socket, address: Any) -> None:
        if self.ssl_options is not None:
            try:
                connection = tornado.netutil.ssl_wrap_socket(connection, self.ssl_options, server_side=True,
                                                             do_handshake_on_connect=False)
            except (ssl.SSLError, OSError):
                connection.close()
                return
            stream: tornado.iostream.IOStream = _TLSStream(connection, max_buffer_size=self.max_buffer_size,
                                                           read_chunk_size=self.read_chunk_size)
        else:
            stream = _Stream(connection, max_buffer_size=self.max_buffer_size, read_chunk_size=self.read_chunk_size)
        stream.server = self                       # type: ignore[attr-defined]
        stream.client = client_of(address)         # type: ignore[attr-defined]
        self.connections.opened(stream.client)     # type: ignore[attr-defined]
        self.streams[stream] = None
        self.handle_stream(stream, address)

    def _closed(self, stream) -> None:
        if self.streams.pop(stream, False) is not False:
            self.connections.closed(stream.client)

    # -- requests -------------------------------------------------------------------------------------
    def start_request(self, server_conn, request_conn):
        delegate = super().start_request(server_conn, request_conn)
        return _BodyLimit(delegate, request_conn, self, str(getattr(server_conn.context, "remote_ip", "?")))

    def refuse_body(self, request_conn, start_line, client: str, length: int) -> None:
        """A body declared longer than the limit: 413, and the connection closed (its body unread)."""
        stream = request_conn.detach()
        limit = self.limits.body_bytes
        data = raw_response(413, "Content Too Large", {
            "refused": f"a body of {length:,} bytes: at most {limit:,} (no action takes one)"})
        self.tally.refuse(client, f"{start_line.method} {printable(start_line.path)}", "body too large")

        def done(future) -> None:
            future.exception()
            stream.close()
        try:
            stream.write(data).add_done_callback(done)
        except tornado.iostream.StreamClosedError:
            pass

    # -- writing --------------------------------------------------------------------------------------
    def sweep(self) -> None:
        """Close every connection whose output has waited :attr:`Limits.write_timeout_s`."""
        now = time.monotonic()
        for stream, since in list(self.streams.items()):
            if not stream.writing():
                self.streams[stream] = None
            elif since is None:
                self.streams[stream] = now
            elif now - since >= self.limits.write_timeout_s:
                stream.close()


def printable(text: str, limit: int = 80) -> str:
    """A client's text (a path) as it may go into the journal: printable, at most ``limit``."""
    out = "".join(c if c.isprintable() and c != "\\" else repr(c)[1:-1] for c in text[:limit])
    return out + ("…" if len(text) > limit else "")


class TornadoRefusals(logging.Filter):
    """tornado's log line for each malformed request (it answers 400 and closes) and each failed
    TLS handshake (plain HTTP on an HTTPS page, say) counted as a refusal of its client instead;
    its line for a request it refused (``400 GET /%ff: Invalid unicode``) left out (the
    application counts those)."""

    COUNTED = {"Malformed HTTP message from": "malformed request", "Timeout reading body from": "body too slow"}

    def __init__(self, tally: RefusalTally) -> None:
        super().__init__()
        self.tally = tally

    def filter(self, record: logging.LogRecord) -> bool:
        if record.msg == "%d %s: %s" and isinstance(record.args, tuple) and record.args \
                and 400 <= record.args[0] < 500:
            return False
        args = record.args if isinstance(record.args, tuple) else ()
        if record.msg == "SSL Error on %s %s: %s" and len(args) == 3:     # not TLS, or a TLS it refuses
            self.tally.refuse(client_of(args[1]), "a connection", "TLS handshake failed")
            return False
        for start, why in self.COUNTED.items():
            if isinstance(record.msg, str) and record.msg.startswith(start):
                context = args[0] if args else None
                self.tally.refuse(str(getattr(context, "remote_ip", "?")), "a request", why)
                return False
        return True
