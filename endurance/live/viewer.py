"""A viewer of the live page's stream without a browser: ``GET /live`` read on a thread, every
message kept with its arrival time (scripts, the benchmark's viewers, the tests).

HTTP/1.0, so the response's body is the stream itself (no chunks), read off a plain socket that
:meth:`StreamViewer.close` shuts down under the reading thread.
"""
from __future__ import annotations

import json
import socket
import threading
import time
import urllib.parse


class StreamViewer:
    """The stream of the page at ``url`` (``http://HOST:PORT/``): :attr:`messages` holds
    ``(time.time() on arrival, event, data)``."""

    def __init__(self, url: str, timeout_s: float = 30.0) -> None:
        where = urllib.parse.urlsplit(url)
        self.messages: list[tuple[float, str | None, object]] = []
        self._sock = socket.create_connection((where.hostname, where.port), timeout=timeout_s)
        self._sock.sendall(f"GET /live HTTP/1.0\r\nHost: {where.netloc}\r\n\r\n".encode())
        self._thread = threading.Thread(target=self._read, name="live-viewer", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        event = None
        try:
            with self._sock.makefile("rb") as stream:
                for raw in stream:
                    line = raw.decode().rstrip("\r\n")
                    if line.startswith("event: "):
                        event = line[7:]
                    elif line.startswith("data: "):
                        self.messages.append((time.time(), event, json.loads(line[6:])))
        except (OSError, ValueError):
            pass

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
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._thread.join(timeout=10)
        self._sock.close()
