"""The bounds on what a client may take of the live page's server (endurance.live.limits, guard,
process), each at a small limit on a page served for a stopped test: connections over the limits
in all and per address are closed as they come; a second stream from an address is 503; a viewer
that stops reading, a request whose headers or body do not come, and headers over the limit lose
their connection; refusals are journalled alone, then as one summary; the log is rate-limited;
and the server in its own process is started again when killed, and ends with its session.
The whole at the issue's scale: tests/test_live_abuse.py."""
from __future__ import annotations

import io
import logging
import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from endurance.live.binding import Binding
from endurance.live.feed import LiveFeed
from endurance.live.limits import Limits, RateLimitedHandler, RefusalTally
from endurance.live.process import PageProcess
from endurance.live.viewer import StreamViewer
from tests.support.live import (TOKEN, events_of, journal_of_flights, refused_events, request, serve_page,
                                wait_for)


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


# -- telling refusals --------------------------------------------------------------------------------------------
def test_refusals_are_journalled_alone_until_a_flood_and_then_as_one_summary():
    clock, journalled = Clock(), []
    tally = RefusalTally(Limits(tracked_addresses=3), journalled.append, logging.getLogger("t"), clock)
    tally.refuse("10.0.0.1", "POST /pause", "wrong token")
    clock.now += 1
    tally.refuse("10.0.0.1", "POST /pause", "wrong token")
    assert journalled == ["POST /pause from 10.0.0.1 refused: wrong token"] * 2
    for k in range(3000):                                    # a flood from one address, and a few others
        tally.refuse("10.0.0.9", "GET /x", "no such page" if k % 3 else "wrong token")
    for address in ("10.0.0.2", "10.0.0.3", "10.0.0.4", "10.0.0.5"):
        tally.refuse(address, "a connection", "over its 32 connections")
    clock.now += 4.0
    tally.tick()
    assert len(journalled) == 2                             # a burst's summary waits for its end
    clock.now += 1.0
    tally.tick()
    assert journalled[2] == ("3,004 requests refused in the last 5 s: 3,000 from 10.0.0.9 (no such page 2,000, "
                             "wrong token 1,000); 1 from 10.0.0.2 (over its 32 connections 1); 1 from 10.0.0.3 "
                             "(over its 32 connections 1); 2 from other addresses (over its 32 connections 2)")
    # a flood that goes on: one summary a minute, nothing alone
    for minute in range(3):
        for _ in range(120):
            clock.now += 0.5
            tally.refuse("10.0.0.9", "GET /x", "no such page")
            tally.tick()
    assert journalled[3:] == ["121 requests refused from 10.0.0.9 in the last minute: no such page 121"] * 2
    clock.now += 5.0
    tally.tick()                                            # ... and once it stops, the rest
    assert journalled[5].startswith("118 requests refused from 10.0.0.9 in the last ")
    clock.now += 61.0                                       # quiet for a minute: alone again
    tally.refuse("10.0.0.1", "POST /stop", "wrong token")
    assert journalled[-1] == "POST /stop from 10.0.0.1 refused: wrong token" and tally.total == 2 + 3004 + 360 + 1


def test_a_refusal_that_cannot_be_journalled_is_said_in_the_log(caplog):
    def no_journal(message: str) -> None:
        raise OSError("no journal yet")
    tally = RefusalTally(Limits(), no_journal, logging.getLogger("t"), Clock())
    with caplog.at_level(logging.WARNING):
        tally.refuse("10.0.0.1", "POST /pause", "wrong token")
    assert "could not journal a refusal (OSError: no journal yet): POST /pause from 10.0.0.1" in caplog.text


def test_the_log_writes_at_most_its_lines_a_minute_then_says_how_many_it_left_out():
    clock, out = Clock(), io.StringIO()
    handler = RateLimitedHandler(out, 10, clock)
    log = logging.getLogger("test-rate-limited")
    log.addHandler(handler)
    log.propagate = False
    try:
        for k in range(25):
            log.warning("line %d %s", k, "x" * 10000)
        clock.now += 61.0
        handler.roll()
        log.warning("the next minute")
    finally:
        log.removeHandler(handler)
    lines = out.getvalue().splitlines()
    assert len(lines) == 12 and all(len(line) <= RateLimitedHandler.MAX_CHARS + 1 for line in lines)
    assert lines[10] == "live page: 15 more log lines left out in the last minute" and lines[11] == "the next minute"


# -- the server's bounds -------------------------------------------------------------------------------------------
def connect(url: str, source: str = "127.0.0.1", rcvbuf: int | None = None) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    if rcvbuf:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)      # before the window is agreed
    sock.settimeout(10)
    sock.bind((source, 0))
    sock.connect(("127.0.0.1", int(url.rsplit(":", 1)[1].strip("/"))))
    return sock


def closed_by_server(sock: socket.socket, within_s: float) -> bool:
    """Whether the server closes ``sock`` within ``within_s`` (reading what it sends)."""
    sock.settimeout(within_s)
    deadline = time.monotonic() + within_s
    try:
        while time.monotonic() < deadline:
            if not sock.recv(65536):
                return True
    except ConnectionResetError:
        return True
    except socket.timeout:
        return False
    return False


def test_connections_over_the_limits_in_all_and_per_address_are_closed_as_they_come(tmp_path):
    limits = Limits(connections=6, connections_per_address=4, summary_quiet_s=0.5)
    with serve_page(tmp_path, limits) as serve:
        url, testdir = serve(None)
        guard = serve.servers[0].server
        held = [connect(url) for _ in range(4)]
        wait_for(lambda: guard.connections.by_address["127.0.0.1"] == 4, 10, "four connections held")
        fifth = connect(url)
        assert closed_by_server(fifth, 5.0)
        others = [connect(url, "127.0.0.2") for _ in range(2)]        # another address: its own share ...
        wait_for(lambda: guard.connections.total == 6, 10, "six connections held")
        assert closed_by_server(connect(url, "127.0.0.3"), 5.0)       # ... up to the server's in all
        held.pop().close()
        wait_for(lambda: guard.connections.total == 5, 10, "a connection closed by its client")
        status, head, _ = request(url.replace("127.0.0.1", "localhost") + "page.json")
        assert status == 200
        for sock in held + others + [fifth]:
            sock.close()
        wait_for(lambda: guard.connections.total == 0, 10, "every connection gone")
        refused = wait_for(lambda: refused_events(testdir, 2), 10, "the refusals in the journal")
        messages = " / ".join(e["message"] for e in refused)
        assert "a connection from 127.0.0.1 refused: over its 4 connections" in messages
        assert "a connection from 127.0.0.3 refused: over the server's 6 connections" in messages


def test_streams_are_bounded_per_address_and_a_viewer_that_stops_reading_loses_its_connection(tmp_path):
    limits = Limits(streams_per_address=1, write_timeout_s=2.0, summary_quiet_s=0.5)
    with serve_page(tmp_path, limits) as serve:
        url, testdir = serve(None)
        guard = serve.servers[0].server
        feed = LiveFeed(sample_hz=1000.0)                 # 16 channels at 1,000 rows/s: ~300 kB/s on the stream
        feed.open(testdir, [f"c{i}" for i in range(16)], 0.001)
        try:
            stalled = connect(url, rcvbuf=4096)
            stalled.sendall(b"GET /live HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")   # and never reads
            wait_for(lambda: guard.connections.total == 1, 10, "the stream open")
            status, head, body = request(url + "live")              # the address has its one stream
            assert status == 503 and head["Retry-After"] == "10" and b"has 1 live streams open" in body
            good = StreamViewer(url, source="127.0.0.2")            # another address has its own
            t0 = time.monotonic()
            while guard.connections.by_address.get("127.0.0.1") and time.monotonic() - t0 < 20:
                now = time.time()
                for k in range(50):
                    feed.cycle(now + k * 0.001, [k] * 16, [k] * 16, [0.5] * 16)
                time.sleep(0.05)
            print(f"the stalled viewer closed after {time.monotonic() - t0:.1f} s")
            assert not guard.connections.by_address.get("127.0.0.1"), "the stalled viewer still connected"
            assert len(good.of("samples")) > 10 and guard.connections.by_address["127.0.0.2"] == 1
            good.close()
            stalled.close()
        finally:
            feed.close()
        refused = wait_for(lambda: refused_events(testdir, 1), 10, "the refusal in the journal")
        assert refused[0]["message"] == "GET /live from 127.0.0.1 refused: too many live streams"


def test_headers_or_a_body_that_do_not_come_or_are_too_large_lose_their_connection(tmp_path):
    limits = Limits(header_timeout_s=1.0, body_timeout_s=1.0, summary_quiet_s=0.5)
    with serve_page(tmp_path, limits) as serve:
        url, testdir = serve(TOKEN)
        guard = serve.servers[0].server
        slow = connect(url)                                # slowloris: a header line a byte at a time
        slow.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        t0 = time.monotonic()
        for _ in range(4):
            time.sleep(0.3)
            try:
                slow.sendall(b"a")
            except OSError:
                break
        assert closed_by_server(slow, 5.0) and time.monotonic() - t0 < 4.0
        body = connect(url)                                # a body that does not come
        body.sendall(b"POST /pause HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 100\r\n\r\nab")
        assert closed_by_server(body, 5.0)
        big = connect(url)                                 # headers over the limit: closed, nothing read
        big.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " + b"a" * 20000 + b"\r\n\r\n")
        assert closed_by_server(big, 5.0)
        junk = connect(url)                                # not HTTP: 400
        junk.sendall(b"\x16\x03\x01\x02\x00garbage\r\n\r\n")
        junk.settimeout(5)
        assert junk.recv(100).startswith(b"HTTP/1.1 400")
        for sock in (slow, body, big, junk):
            sock.close()
        wait_for(lambda: guard.connections.total == 0, 10, "every connection gone")
        refused = wait_for(lambda: refused_events(testdir, 1), 10, "the refusals in the journal")
        messages = " / ".join(e["message"] for e in refused)
        assert "body too slow" in messages and "malformed request" in messages, messages


# -- the server in a process of its own ---------------------------------------------------------------------------
def test_a_killed_server_is_started_again_on_the_same_port_and_a_viewer_comes_back(tmp_path):
    testdir = journal_of_flights(tmp_path / "T")
    page = PageProcess(testdir, "watch", Binding.check("127.0.0.1:0"), TOKEN, out=sys.stderr)
    url = page.start()
    viewer = None
    try:
        first = page.pid
        assert oom_score_adj(first) == 1000                 # the kernel's first choice, not the session
        viewer = StreamViewer(url, reconnect_s=0.2)
        wait_for(lambda: viewer.opened, 10, "the stream")
        os.kill(first, signal.SIGKILL)
        killed = time.monotonic()
        wait_for(lambda: len(viewer.opened) >= 2, 30, "the viewer back on a new server")
        took = time.monotonic() - killed
        assert page.pid not in (None, first) and page.pids == [first, page.pid]
        assert request(url + "status.json")[0] == 200
        (event,) = wait_for(lambda: events_of(testdir, "live_page"), 10, "the restart in the journal")
        assert f"process {first}) ended (killed by SIGKILL); served again by process {page.pid}" in event["message"]
        print(f"viewer back {took:.1f} s after the kill")
    finally:
        if viewer is not None:
            viewer.close()
        page.stop()
    assert page.pid is None
    with pytest.raises(OSError):
        connect(url)                                       # nothing listens once the page is stopped


def test_the_server_ends_with_the_process_that_started_it(tmp_path):
    testdir = journal_of_flights(tmp_path / "T")
    script = ("import sys, time\n"
              "from endurance.live.binding import Binding\n"
              "from endurance.live.process import PageProcess\n"
              f"page = PageProcess({str(testdir)!r}, 'watch', Binding.check('127.0.0.1:0'), None)\n"
              "page.start()\n"
              "print(page.pid, flush=True)\n"
              "time.sleep(600)\n")
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        server = int(parent.stdout.readline())
        parent.kill()                                      # no chance to stop it: its stdin closes
        parent.wait()
        wait_for(lambda: not os.path.exists(f"/proc/{server}") or _zombie(server), 10, "the server's end")
    finally:
        if parent.poll() is None:
            parent.kill()


def oom_score_adj(pid: int | str) -> int:
    with open(f"/proc/{pid}/oom_score_adj") as fh:
        return int(fh.read())


def _zombie(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True
