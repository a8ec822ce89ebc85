"""A viewer of the live page's stream without a browser: ``GET /live`` read on a thread, every
message kept with its arrival time (scripts, the benchmark's viewers, the tests). Like a
browser's ``EventSource`` it opens the stream again when it ends, if asked to.

HTTP/1.0, so the response's body is the stream itself (no chunks), read off a plain socket that
:meth:`StreamViewer.close` shuts down under the reading thread.
"""
from __future__ import annotations

import json
import socket
import ssl
import threading
import time
import urllib.parse


class StreamViewer:
    """The stream of the page at ``url`` (``http://HOST:PORT/`` or ``https://``, then with
    ``context``): :attr:`messages` holds ``(time.time() on arrival, event, data)``.
    ``reconnect_s``: open it again that long after it ended (None: once); ``source``: the
    address to connect from."""

    def __init__(self, url: str, timeout_s: float = 30.0, reconnect_s: float | None = None,
                 source: str | None = None, context: ssl.SSLContext | None = None,
                 host: str | None = None) -> None:
        where = urllib.parse.urlsplit(url)
        self.address = (where.hostname, where.port)
        self.host = host or where.netloc
        self.tls = where.scheme == "https"
        self.context = context
        self.timeout_s = timeout_s
        self.reconnect_s = reconnect_s
        self.source = source
        self.messages: list[tuple[float, str | None, object]] = []
        #: the times the stream was opened (its first message's arrival each)
        self.opened: list[float] = []
        self._halt = threading.Event()
        self._sock: socket.socket | None = None
        self._sock = self._connect()                 # the first: an error at once if there is no server
        self._thread = threading.Thread(target=self._run, name="live-viewer", daemon=True)
        self._thread.start()

    def _connect(self) -> socket.socket:
        sock = socket.create_connection(self.address, timeout=self.timeout_s,
                                        source_address=(self.source, 0) if self.source else None)
        if self.tls:
            sock = (self.context or ssl.create_default_context()).wrap_socket(
                sock, server_hostname=self.host.rsplit(":", 1)[0])
        sock.sendall(f"GET /live HTTP/1.0\r\nHost: {self.host}\r\n\r\n".encode())
        return sock

    def _run(self) -> None:
        while True:
            if self._sock is not None:
                self._read(self._sock)
            if self.reconnect_s is None or self._halt.wait(self.reconnect_s):
                return
            try:
                self._sock = self._connect()
            except OSError:
                self._sock = None
            if self._halt.is_set():
                return

    def _read(self, sock: socket.socket) -> None:
        event = None
        first = True
        try:
            with sock.makefile("rb") as stream:
                for raw in stream:
                    line = raw.decode().rstrip("\r\n")
                    if line.startswith("event: "):
                        event = line[7:]
                    elif line.startswith("data: "):
                        now = time.time()
                        if first:
                            self.opened.append(now)
                            first = False
                        self.messages.append((now, event, json.loads(line[6:])))
        except (OSError, ValueError):
            pass
        finally:
            sock.close()

    def of(self, event: str) -> list[tuple[float, object]]:
        """``(arrival, data)`` of every ``event`` message so far."""
        return [(t, d) for t, e, d in list(self.messages) if e == event]

    def updates_per_s(self, last_s: float | None = None) -> float:
        """``samples`` messages a second after the first (the greeting's window), over the
        last ``last_s`` seconds (default: all)."""
        times = [t for t, _ in self.of("samples")[1:]]
        if last_s is not None and times:
            times = [t for t in times if t >= times[-1] - last_s]
        return (len(times) - 1) / (times[-1] - times[0]) if len(times) > 2 else 0.0

    def close(self) -> None:
        self._halt.set()
        sock = self._sock
        if sock is not None:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self._thread.join(timeout=10)
