"""What a client may take of the live page's server, and how refusals are told (docs/endurance.md,
the live page; the figures' reasons: :class:`Limits`).

* :class:`Connections`: the open connections, in all and per client address, against the
  limits; a connection over them is closed as it is accepted (nothing is read from it).
* :class:`RefusalTally`: every refused request counted per client; a refusal is journalled on
  its own only if fewer than :attr:`Limits.refusals_alone` came in the minute before it (a
  mistyped token shows at once, with its reason), the rest together as one summary per
  :attr:`Limits.summary_every_s`, or :attr:`Limits.summary_quiet_s` after the last of a burst:
  "4,212 requests refused from 127.0.0.4 in the last 14 s: no such page 3,100, wrong token
  1,112". The summary is also the server's one log line about them.
* :class:`RateLimitedHandler`: every other log line, at most :attr:`Limits.log_lines_per_minute`
  a minute, then one line saying how many were left out.
"""
from __future__ import annotations

import collections
import logging
import resource
import time
from dataclasses import dataclass, asdict
from typing import Callable

#: descriptors the server keeps for itself (the journal, the ring, the listening sockets, a
#: resume's pipes, its imports) below its limit; the rest may be connections
FD_RESERVE = 32


@dataclass(frozen=True)
class Limits:
    """The bounds on what clients may take (module docstring). Each default, and why:"""

    #: open connections in all, at most (and at most the descriptor limit less
    #: :data:`FD_RESERVE`): a control room has a few browsers, each up to 6 connections
    connections: int = 256
    #: from one client address: a few browser tabs behind one address; one client cannot take
    #: the others' share
    connections_per_address: int = 32
    #: live streams in all and per address: one per open page; each costs ~24 kB and its share of
    #: every tick's writes
    streams: int = 64
    streams_per_address: int = 8
    #: a request's line and headers, bytes: a browser's request is under 2 kB without cookies
    #: (this page sets none), nginx's default allows a line of 8 kB
    header_bytes: int = 8192
    #: a request's body, bytes: no action takes one
    body_bytes: int = 1024
    #: to send a request's line and headers, and for a kept-alive connection to send its next
    #: request, s (browsers send at once; a slow sender is holding a connection)
    header_timeout_s: float = 10.0
    #: to send a request's body, s
    body_timeout_s: float = 10.0
    #: a response (or the live stream) that cannot be written for this long closes its
    #: connection, s: a viewer that stopped reading (the stream's own backlog drops one that
    #: reads too slowly)
    write_timeout_s: float = 10.0
    #: refusals journalled one by one in any minute (the rest are summarised)
    refusals_alone: int = 2
    #: a summary of refusals at most this often, s
    summary_every_s: float = 60.0
    #: ... or this long after the last refusal of a burst, s
    summary_quiet_s: float = 5.0
    #: client addresses a summary counts one by one (the rest together)
    tracked_addresses: int = 1000
    #: log lines a minute, at most (then one line says how many were left out)
    log_lines_per_minute: int = 10

    def to_dict(self) -> dict:
        return asdict(self)

    def connection_cap(self) -> int:
        """The connections the process may hold: :attr:`connections`, or fewer if its
        descriptor limit is lower."""
        soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
        if soft == resource.RLIM_INFINITY:
            return self.connections
        return max(min(self.connections, soft - FD_RESERVE), 1)


class Connections:
    """The server's open connections by client address, against :class:`Limits`."""

    def __init__(self, limits: Limits) -> None:
        self.limits = limits
        self.cap = limits.connection_cap()
        self.by_address: collections.Counter[str] = collections.Counter()
        self.total = 0

    def refusal(self, address: str) -> str | None:
        """Why a new connection from ``address`` is refused (None: it is taken)."""
        if self.total >= self.cap:
            return f"over the server's {self.cap} connections"
        if self.by_address[address] >= self.limits.connections_per_address:
            return f"over its {self.limits.connections_per_address} connections"
        return None

    def opened(self, address: str) -> None:
        self.total += 1
        self.by_address[address] += 1

    def closed(self, address: str) -> None:
        self.total -= 1
        self.by_address[address] -= 1
        if self.by_address[address] <= 0:
            del self.by_address[address]


def _plural(n: int, what: str) -> str:
    return f"{n:,} {what}{'' if n == 1 else 's'}"


def _span(seconds: float) -> str:
    return "minute" if 58.0 <= seconds <= 62.0 else f"{seconds:.0f} s"


class RefusalTally:
    """Refused requests, counted per client and told as the module docstring says: ``record``
    journals a message (``endurance.inbox.record_event``'s ``refused`` event), ``log`` gets the
    summaries. :meth:`tick` once a second or so; :meth:`flush` at the end."""

    OTHERS = "other addresses"

    def __init__(self, limits: Limits, record: Callable[[str], None], log: logging.Logger,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.limits = limits
        self.record = record
        self.log = log
        self.clock = clock
        self._recent: collections.deque[float] = collections.deque()
        self._counts: dict[str, collections.Counter[str]] = {}
        self._first = 0.0
        self._last = 0.0
        #: refusals so far (every one, told alone or summarised)
        self.total = 0

    def refuse(self, client: str, what: str, why: str) -> None:
        """``what`` (e.g. ``POST /pause``) from ``client`` refused for ``why`` (a fixed phrase:
        summaries count by it)."""
        now = self.clock()
        self.total += 1
        recent = self._recent
        while recent and now - recent[0] > 60.0:
            recent.popleft()
        if len(recent) < self.limits.refusals_alone and not self._counts:
            recent.append(now)
            self._record(f"{what} from {client} refused: {why}")
            return
        recent.append(now)
        if len(recent) > self.limits.refusals_alone:
            recent.popleft()
        if not self._counts:
            self._first = now
        self._last = now
        if client not in self._counts and len(self._counts) >= self.limits.tracked_addresses:
            client = self.OTHERS
        self._counts.setdefault(client, collections.Counter())[why] += 1

    def tick(self) -> None:
        """The summary, if it is due (module docstring)."""
        if not self._counts:
            return
        now = self.clock()
        if now - self._first >= self.limits.summary_every_s or now - self._last >= self.limits.summary_quiet_s:
            self.flush()

    def flush(self) -> None:
        """The summary of what is counted, now."""
        if not self._counts:
            return
        span = _span(max(self.clock() - self._first, 1.0))
        counts, self._counts = self._counts, {}
        others = counts.pop(self.OTHERS, collections.Counter())
        ranked = sorted(counts.items(), key=lambda kv: -sum(kv[1].values()))
        shown, rest = ranked[:5], ranked[5:]
        for _, reasons in rest:
            others.update(reasons)
        n = sum(sum(c.values()) for c in counts.values()) + sum(others.values()) - \
            sum(sum(c.values()) for _, c in rest)

        def why(reasons: collections.Counter) -> str:
            return ", ".join(f"{r} {k:,}" for r, k in reasons.most_common())
        if len(shown) == 1 and not others:
            message = f"{_plural(n, 'request')} refused from {shown[0][0]} in the last {span}: {why(shown[0][1])}"
        else:
            parts = [f"{sum(reasons.values()):,} from {client} ({why(reasons)})" for client, reasons in shown]
            if others:
                parts.append(f"{sum(others.values()):,} from other addresses ({why(others)})")
            message = f"{_plural(n, 'request')} refused in the last {span}: " + "; ".join(parts)
        self.log.warning("live page: %s", message)
        self._record(message)

    def _record(self, message: str) -> None:
        try:
            self.record(message)
        except Exception as exc:                        # no journal yet, a full disk: the log says it
            self.log.warning("live page: could not journal a refusal (%s: %s): %s", type(exc).__name__, exc,
                             message)


class RateLimitedHandler(logging.StreamHandler):
    """A log handler that writes at most ``per_minute`` records a minute (a traceback cut to
    its last :attr:`MAX_CHARS` characters), then one line with how many it left out."""

    MAX_CHARS = 4000

    def __init__(self, stream, per_minute: int, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(stream)
        self.per_minute = per_minute
        self.clock = clock
        self._start = clock()
        self._written = 0
        self.left_out = 0

    def roll(self) -> None:
        """A new minute, if it is one: say how many lines the last left out."""
        now = self.clock()
        if now - self._start < 60.0:
            return
        if self.left_out:
            super().emit(logging.makeLogRecord({
                "name": "endurance.live", "levelno": logging.WARNING, "levelname": "WARNING",
                "msg": f"live page: {_plural(self.left_out, 'more log line')} left out in the last minute"}))
        self._start, self._written, self.left_out = now, 0, 0

    def emit(self, record: logging.LogRecord) -> None:
        self.roll()
        if self._written >= self.per_minute:
            self.left_out += 1
            return
        self._written += 1
        super().emit(record)

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        return text if len(text) <= self.MAX_CHARS else "…" + text[-self.MAX_CHARS:]
