"""The live page's parts without a bus (endurance.live): the ring the loop writes and the server
reads, the feed that follows it from session to session, the inbox of events from outside a
session, the operator's token and its file, where the page may listen, and the page's server on a
stopped test: every refusal (no token configured, no header, a wrong token, any other method on an
action, other paths, another Host) answered with the security headers, journalled (a flood as one
summary) and moving nothing; /status.json is stand test status --json's text; the page loads
nothing from elsewhere. The server's bounds: tests/test_live_limits.py."""
from __future__ import annotations

import argparse
import json
import os
import re
import socket
import stat
import threading
from pathlib import Path

import numpy as np
import pytest

from core.errors import ParameterError
from endurance.inbox import INBOX_DIR, record_event, take_in
from endurance.journal import Journal, MonitorStep
from endurance.live.binding import Address, Binding, serve_address
from endurance.live.feed import LIVE_FILE, RING_DIR, RING_PREFIX, FeedReader, LiveFeed
from endurance.live.operator import Operator, read_token_file, resume_command, write_token_file
from endurance.live.ring import MARGIN, RingFile
from endurance.live.viewer import StreamViewer
from endurance.monitors import detector_rows
from endurance.report import status_json, status_of
from endurance.trends import TrendDetector, TrendOptions
from tests.support.live import (TOKEN, events_of, journal_of_flights, refused_events, request, serve_page, stand,
                                token_file, wait_for)


# -- the ring and the feed ------------------------------------------------------------------------------------
def test_a_ring_gives_each_reader_what_came_since_it_looked_and_the_newest_when_it_fell_behind(tmp_path):
    ring = RingFile.create(tmp_path / "r", 3, MARGIN + 36, {"pid": 1})
    reader = RingFile.open(tmp_path / "r")
    assert reader.hello == {"pid": 1} and reader.count == 0 and reader.since(0)[1].shape == (0, 3)
    assert stat.S_IMODE((tmp_path / "r").stat().st_mode) == 0o600
    for i in range(10):
        ring.put(float(i), [i + 0.5], [-i])
    seq, rows = reader.since(0)
    assert seq == 10 and rows.tolist() == [[i, i + 0.5, -i] for i in range(10)]
    for i in range(10, 500):
        ring.put(float(i), [0.0], [0.0])
    seq2, rows = reader.since(seq)                       # lapped: the newest capacity - MARGIN
    assert seq2 == 500 and rows[:, 0].tolist() == list(range(464, 500))
    assert len(reader.since(seq2)[1]) == 0
    # a slot being written (its sequence 0) or reused since is left out, never a torn row
    ring._seqs[499 % ring.capacity] = 0
    assert reader.since(497)[1][:, 0].tolist() == [497.0, 498.0]
    ring.close()
    assert reader.closed and not (tmp_path / "r").exists()
    with pytest.raises(ValueError):
        RingFile.create(tmp_path / "q", 3, MARGIN, {})
    big = RingFile.create(tmp_path / "big", 1 + 3 * 500, 100, {"channels": [f"channel-{i:04d}" for i in range(500)]})
    assert RingFile.open(tmp_path / "big").hello == big.hello                 # a hello of 7 kB: two pages
    (tmp_path / "junk").write_bytes(b"x" * 5000)
    with pytest.raises(ValueError, match="not a ring"):
        RingFile.open(tmp_path / "junk")
    os.mkfifo(tmp_path / "fifo")                          # not a plain file: refused, never a wait
    with pytest.raises(ValueError, match="not a ring"):
        RingFile.open(tmp_path / "fifo")


def test_a_session_feed_decimates_the_loop_and_the_reader_follows_it_from_session_to_session(tmp_path):
    reader = FeedReader(tmp_path)
    assert reader.hello is None and reader.count == 0
    feed = LiveFeed(sample_hz=50.0)
    feed.open(tmp_path, ["a", "b"], 0.002)
    assert feed.hello == {"channels": ["a", "b"], "period_s": 0.002, "sample_hz": 50.0, "pid": os.getpid()}
    ring = Path(json.loads((tmp_path / LIVE_FILE).read_text())["ring"])
    assert ring.parent == RING_DIR and stat.S_IMODE(ring.stat().st_mode) == 0o600    # in memory, not on disk
    assert stat.S_IMODE((tmp_path / LIVE_FILE).stat().st_mode) == 0o600
    for k in range(200):                           # 0.4 s of 2 ms cycles: a row every 20 ms
        feed.cycle(1000.0 + k * 0.002, np.array([k, -k]), [k + 1, -k - 1], [0.5, -0.5])
    for k in range(20):                            # slow lockstep cycles of 7 ms: every 3rd
        feed.cycle(1000.4 + k * 0.007, [k, -k], [k + 1, -k - 1], [0.5, -0.5])
    reader.poll(10.0)
    assert reader.hello == feed.hello and reader.channels == ["a", "b"]
    seq, rows = reader.since(0)
    assert seq == 27 and rows[0].tolist() == [1000.0, 0, 0, 1, -1, 0.5, -0.5] and rows[1, 1] == 10
    assert rows[20:, 1].tolist() == [0, 3, 6, 9, 12, 15, 18]
    feed.close()                                   # the session ends: its ring goes
    reader.poll(11.0)
    assert reader.hello is None and reader.count == 27
    assert not (tmp_path / LIVE_FILE).exists() and not ring.exists()
    feed = LiveFeed()                              # the next session: numbering goes on
    feed.open(tmp_path, ["a"], 0.002)
    feed.cycle(2000.0, [1.0], [2.0], [3.0])
    reader.poll(12.0)
    seq2, rows = reader.since(seq)
    assert seq2 == 28 and rows.tolist() == [[2000.0, 1.0, 2.0, 3.0]] and reader.channels == ["a"]
    feed.close()
    # a session killed leaves its ring: a reader passes it over (its process is gone), the next
    # session of the test removes it
    dead = 2 ** 22 + 12345
    left = RING_DIR / f"{RING_PREFIX}{dead}-test.ring"
    RingFile.create(left, 4, 100, {"channels": ["a"], "pid": dead, "sample_hz": 50.0})
    (tmp_path / LIVE_FILE).write_text(json.dumps({"ring": str(left), "pid": dead}))
    reader.poll(13.0)
    assert reader.hello is None
    feed.open(tmp_path, ["a"], 0.002)
    assert not left.exists()
    reader.poll(14.0)
    assert reader.hello == feed.hello
    feed.close()
    reader.close()


def test_a_feed_that_cannot_publish_leaves_the_session_running_without_signals(tmp_path, caplog):
    feed = LiveFeed()
    feed.open(tmp_path / "not-there", ["a"], 0.002)           # TESTDIR/live.json cannot be written
    feed.cycle(1000.0, [1.0], [2.0], [3.0])                    # nothing to do, nothing raised
    assert feed.hello is None and "this session publishes no signals (FileNotFoundError" in caplog.text
    assert not list(RING_DIR.glob(f"{RING_PREFIX}{os.getpid()}-*"))         # its ring removed
    feed.close()


# -- events from outside a session ----------------------------------------------------------------------------
def test_an_event_from_outside_goes_into_the_journal_or_through_the_session_that_holds_it(tmp_path):
    testdir = journal_of_flights(tmp_path / "T")
    assert record_event(testdir, "refused", "by hand") == "journal"
    with Journal.open(testdir, write=True) as session:            # a session holds the lock
        assert record_event(testdir, "operator", "first", time_s=100.0) == "inbox"
        assert record_event(testdir, "operator", "second", time_s=101.0) == "inbox"
        (testdir / INBOX_DIR / "zz-bad.json").write_text("{not json")
        assert take_in(testdir, session) == 2
        assert take_in(testdir, session) == 0
        events = session.events()
    assert [e["message"] for e in events[-4:-1]] == ["by hand", "first", "second"]
    assert events[-1]["kind"] == "inbox" and "zz-bad.json is not an event" in events[-1]["message"]
    assert events[-3]["time"] == 100.0
    assert sorted(p.name for p in (testdir / INBOX_DIR).iterdir()) == ["zz-bad.bad"]


# -- the token ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("text, mode, message", [
    (None, 0o600, "no such file (make one with stand test token FILE)"),
    ("\n\n", 0o600, "it is empty"),
    (TOKEN, 0o644, "others may read it (mode 0644); chmod 600"),
    (TOKEN, 0o640, "others may read it"),
    ("short", 0o600, "at least 16 printable ASCII characters"),
    (f"{TOKEN}\n{TOKEN}", 0o600, "give one line"),
    (TOKEN + "é", 0o600, "printable ASCII"),                  # latin-1 in a header: it could never match
    (TOKEN + "\x7f", 0o600, "printable ASCII"),
    ("x" * 2000, 0o600, "is not a token file"),
])
def test_a_token_file_that_is_missing_empty_short_not_ascii_or_readable_by_others_is_refused(tmp_path, text, mode,
                                                                                             message):
    path = tmp_path / "token"
    if text is not None:
        path.write_text(text)
        path.chmod(mode)
    with pytest.raises(ParameterError, match=re.escape(message)):
        read_token_file(path)


def test_a_token_file_that_is_not_a_plain_file_is_refused_before_it_is_read(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo, 0o600)
    done = []
    reader = threading.Thread(target=lambda: done.append(pytest.raises(ParameterError, read_token_file, fifo)),
                              daemon=True)
    reader.start()
    reader.join(5.0)                                    # a read of a FIFO with no writer would wait for ever
    assert done and "not a plain file" in str(done[0].value)
    (tmp_path / "dir").mkdir(mode=0o700)
    with pytest.raises(ParameterError, match="not a plain file"):
        read_token_file(tmp_path / "dir")


def test_a_token_file_gives_its_one_line_and_the_token_is_compared_whole(tmp_path):
    assert read_token_file(token_file(tmp_path / "token", f"  {TOKEN}  ")) == TOKEN
    operator = Operator(tmp_path, TOKEN)
    assert operator.refusal(f"Bearer {TOKEN}") is None and operator.refusal(f"bearer  {TOKEN} ") is None
    assert operator.refusal(f"Bearer {TOKEN[:-1]}") == "wrong token"
    assert operator.refusal(f"Bearer {TOKEN}x") == "wrong token"


def test_stand_test_token_makes_a_token_file_for_its_owner_alone_and_never_overwrites_one(tmp_path):
    path = tmp_path / "token"
    res = stand("test", "token", path)
    assert res.returncode == 0 and f"--operator-token-file {path}" in res.stdout
    token = read_token_file(path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and len(token) == 32 and token not in res.stdout
    res = stand("test", "token", path)
    assert res.returncode == 2 and "it exists" in res.stderr and read_token_file(path) == token
    assert read_token_file(write_token_file(tmp_path / "other")) != token


# -- where the page listens ------------------------------------------------------------------------------------
def test_the_serve_address_binds_loopback_unless_a_host_is_named():
    assert serve_address("8080") == Address("127.0.0.1", 8080)
    assert serve_address(":0") == Address("127.0.0.1", 0)
    assert serve_address("0.0.0.0:81") == Address("0.0.0.0", 81) and not serve_address("0.0.0.0:81").loopback
    assert serve_address("[::1]:8080") == Address("::1", 8080) and serve_address("[::1]:8080").loopback
    assert serve_address("localhost:1").loopback and serve_address("127.0.0.2:1").loopback
    for bad in ("abc", "host:", "1:2:3", "127.0.0.1:70000", "[::1]8080"):
        with pytest.raises(ParameterError, match="--serve"):
            serve_address(bad)


def test_beyond_loopback_a_page_needs_its_names_and_a_token_needs_https():
    with pytest.raises(ParameterError, match="listens beyond this computer: name the host names .* --allow-host"):
        Binding.check("0.0.0.0:8080")
    with pytest.raises(ParameterError, match="token would cross the network in clear. Give the page a certificate "
                                             "with --tls-cert CERT.pem --tls-key KEY.pem"):
        Binding.check("0.0.0.0:8080", ["rig-pc"], token=True)
    with pytest.raises(ParameterError, match="go together"):
        Binding.check("0.0.0.0:8080", ["rig-pc"], tls_cert="c.pem")
    with pytest.raises(ParameterError, match="--allow-host 'a b'"):
        Binding.check("0.0.0.0:8080", ["a b"])
    read_only = Binding.check("0.0.0.0:8080", ["Rig-PC.lab.", "10.0.0.5"])    # read-only, plain HTTP: allowed
    assert read_only.url(8080) == "http://rig-pc.lab:8080/" and "plain HTTP" in read_only.exposure(8080)
    # the Host check: loopback's names and addresses, the allowed names, the bound address; never off
    for host in ("localhost", "127.0.0.1", "[::1]", "127.0.0.2", "rig-pc.lab", "RIG-PC.LAB.", "10.0.0.5"):
        assert read_only.host_allowed(host), host
    for host in ("evil.example", "rig-pc.lab.evil.example", "10.0.0.6", "", "0.0.0.0"):
        assert not read_only.host_allowed(host), host
    named = Binding.check("192.0.2.7:8080", ["rig-pc"])
    assert named.host_allowed("192.0.2.7") and named.url(1) == "http://192.0.2.7:1/"
    loopback = Binding.check("127.0.0.1:0", token=True)                      # loopback: plain HTTP is fine
    assert loopback.exposure(1) == "" and not loopback.host_allowed("evil.example")


# -- the server on a stopped test -----------------------------------------------------------------------------------
@pytest.fixture
def page(tmp_path):
    """A page served for a stopped test (watch's kind), with or without the operator's token."""
    with serve_page(tmp_path) as serve:
        yield serve


SECURITY = {"Content-Security-Policy": "default-src 'self'; frame-ancestors 'none'", "X-Content-Type-Options": "nosniff",
            "Referrer-Policy": "no-referrer", "Cache-Control": "no-store"}


def test_every_refusal_is_answered_with_its_reason_and_headers_journalled_and_moves_nothing(page):
    url, testdir = page(TOKEN)
    bearer = {"Authorization": f"Bearer {TOKEN}"}
    cases = [("POST", "pause", {}, 403, "no Authorization header"),
             ("POST", "stop", {"Authorization": "Bearer not-the-token-at-all"}, 403, "wrong token"),
             ("POST", "resume", {"Authorization": f"Basic {TOKEN}"}, 403, "is not Bearer TOKEN"),
             ("POST", "pause", {"Authorization": "Bearer "}, 403, "is not Bearer TOKEN"),
             ("GET", "pause", bearer, 405, "is an action: POST it"),
             ("PUT", "stop", bearer, 405, "is an action: POST it"),
             ("DELETE", "resume", bearer, 405, "is an action: POST it"),
             ("HEAD", "pause", bearer, 405, None),
             ("OPTIONS", "stop", bearer, 405, "is an action: POST it"),
             ("TRACE", "resume", bearer, 405, None),
             ("POST", "pause", bearer | {"Content-Length": "5000"}, 413, "a body of 5,000 bytes: at most 1,024"),
             ("GET", "nothing", {}, 404, "no such page"),
             ("GET", "static/x%00", {}, 404, "no such page"),
             ("GET", "static/..%2F..%2Fpyproject.toml", {}, 404, "no such page"),
             ("GET", "static/%ff%fe", {}, 400, None),
             ("POST", "pause/now", bearer, 404, "no such page"),
             ("POST", "", bearer, 405, None),
             ("POST", "status.json", bearer, 405, None),
             ("POST", "live", bearer, 405, None),
             ("GET", "status.json", {"Host": "evil.example:80"}, 403, "this server answers only to its own names"),
             ("GET", "live", {"Host": "127.0.0.1.evil.example"}, 403, "this server answers only to its own names")]
    for method, path, headers, code, why in cases:
        data = b"x" * 5000 if code == 413 else (b"" if method in ("POST", "PUT") else None)
        status, head, body = request(url + path, method, headers, data)
        assert status == code, (method, path, status, body)
        assert {k: head.get(k) for k in SECURITY} == SECURITY, (method, path, head)
        if why is not None:
            assert why in json.loads(body)["refused"], (method, path, body)
    assert not (testdir / "stop.json").exists() and not (testdir / "sessions").exists()     # no resume
    # journalled: the first two on their own (with their reasons), the rest as one summary
    refused = wait_for(lambda: refused_events(testdir, 3), 20, "the summary of the refusals")
    assert refused[0]["message"].startswith("POST /pause from 127.0.0.1 refused: no Authorization header")
    assert refused[1]["message"] == "POST /stop from 127.0.0.1 refused: wrong token"
    summary = refused[2]["message"]
    assert summary.startswith(f"{len(cases) - 2} requests refused from 127.0.0.1 in the last "), summary
    for counted in ("an action is a POST 6", "no such page 4", "method not allowed 3", "Host not allowed 2",
                    "body too large 1", "the Authorization header is not Bearer TOKEN 2", "bad request 1"):
        assert counted in summary, (counted, summary)
    assert events_of(testdir, "operator") == []


def test_a_read_only_page_refuses_every_action_even_with_a_token(page):
    url, testdir = page(None)
    for action in ("pause", "stop", "resume"):
        status, _, body = request(url + action, "POST", {"Authorization": f"Bearer {TOKEN}"}, b"")
        assert status == 403 and "read-only" in json.loads(body)["refused"]
    refused = wait_for(lambda: refused_events(testdir, 3), 20, "the refusals in the journal")
    assert refused[2]["message"].startswith("1 request refused from 127.0.0.1 in the last ")
    assert json.loads(request(url + "page.json")[2])["read_only"] is True


def test_with_the_token_an_action_the_test_cannot_take_now_is_409_and_says_why(page):
    url, testdir = page(TOKEN)
    bearer = {"Authorization": f"Bearer {TOKEN}"}
    status, _, body = request(url + "pause", "POST", bearer, b"")
    assert status == 409 and "no session runs the test (it is stopped)" in json.loads(body)["refused"]
    assert not (testdir / "stop.json").exists()
    with Journal.open(testdir, write=True) as j:
        j.set_target(3)                                        # finished: 3 of 3
    status, _, body = request(url + "resume", "POST", bearer, b"")
    assert status == 409 and "the test is finished" in json.loads(body)["refused"]
    # stopped by the trend's alarm: what the inspection found is the command line's to say
    url, testdir = page(TOKEN)
    detector = TrendDetector(["root", "inner"], None, TrendOptions())
    detector.latched[0, 1] = True
    with Journal.open(testdir, write=True) as j:
        j.record_monitors(MonitorStep(detector_rows(detector)))
        j.start()
        j.stop("monitor_alarm: flight 3: channel inner needs 3.1 % more flow")
    status, _, body = request(url + "resume", "POST", bearer, b"")
    assert status == 409 and "the trend's alarm on inner stopped the test" in json.loads(body)["refused"]
    assert "--inspected" in json.loads(body)["refused"] and not (testdir / "sessions").exists()
    assert events_of(testdir, "refused") == []                 # the operator's, not a refusal


def test_a_resume_from_the_page_runs_stand_test_resume_with_the_options_the_test_was_started_with(tmp_path):
    testdir = journal_of_flights(tmp_path / "T")
    command = resume_command(testdir)
    assert command[1:] == ["-m", "stand", "test", "resume", str(testdir.resolve()), "--lockstep"]


def test_status_json_is_what_stand_test_status_json_prints(page):
    url, testdir = page(TOKEN)
    status, head, body = request(url + "status.json")
    cli = stand("test", "status", testdir, "--json")
    assert status == 200 and head["Content-Type"] == "application/json"
    assert body.decode() == cli.stdout == status_json(status_of(testdir))


def test_the_page_and_its_assets_come_from_the_server_alone(page):
    url, _ = page(TOKEN)
    status, head, body = request(url)
    html = body.decode()
    assert status == 200 and "default-src 'self'" in head["Content-Security-Policy"]
    assets = re.findall(r'(?:src|href)="([^"]+)"', html)
    assert len(assets) >= 5 and all(a.startswith("/static/") for a in assets), assets
    for asset in assets:
        assert request(url + asset.lstrip("/"))[0] == 200, asset
    script = request(url + "static/live.js")[2].decode()
    assert "http://" not in script and "https://" not in script


def test_the_stream_greets_a_viewer_with_the_page_status_events_and_trends(page):
    url, testdir = page(TOKEN)
    reader = StreamViewer(url)
    try:
        wait_for(lambda: reader.of("trend"), 10, "the greeting")
        (_, info), = reader.of("page")
        assert info["channels"] == ["root", "inner"] and info["read_only"] is False and info["session"] is None
        (_, status), = reader.of("status")
        assert status == status_of(testdir)
        (_, events), = reader.of("events")
        assert [e["kind"] for e in events] == ["started", "stopped"]
        (_, trend), = reader.of("trend")
        assert [r["flight"] for r in trend] == [1, 2, 3]
        # each flight's peak: reached 2 kgf (root) and 4 kgf (inner) above its level, % of the range
        assert trend[0]["channels"]["root"]["error_pct"] == pytest.approx(100 * 2 / 1010)
        assert trend[0]["channels"]["inner"]["flow_pct"] == pytest.approx(11.0)
        assert trend[2]["channels"]["root"]["flow_rise_pct"] == pytest.approx(100 * (8 / 7 - 1))
        # an event recorded later reaches the viewer
        record_event(testdir, "operator", "a note")
        wait_for(lambda: len(reader.of("events")) >= 2, 10, "the new event")
        assert reader.of("events")[-1][1][0]["message"] == "a note"
    finally:
        reader.close()


# -- the command line ------------------------------------------------------------------------------------------------
def test_the_command_line_says_what_is_wrong_with_a_live_option(tmp_path):
    testdir = journal_of_flights(tmp_path / "T")
    loose = token_file(tmp_path / "loose", mode=0o644)
    res = stand("test", "watch", testdir, "--operator-token-file", loose)
    assert res.returncode == 2 and "others may read it" in res.stderr
    res = stand("test", "watch", tmp_path / "none", "--serve", "0")
    assert res.returncode == 2 and "holds no test" in res.stderr
    res = stand("test", "start", "examples/test.toml", "--out", tmp_path / "X", "--serve", "host:port")
    assert res.returncode == 2 and "--serve host:port: give HOST:PORT" in res.stderr
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        res = stand("test", "watch", testdir, "--serve", f"127.0.0.1:{port}")
    assert res.returncode == 2 and f"--serve 127.0.0.1:{port}: cannot listen there" in res.stderr
    # beyond loopback, HTTPS for a token: refused before anything listens or starts
    good = token_file(tmp_path / "good")
    res = stand("test", "start", "examples/test.toml", "--out", tmp_path / "X", "--serve", "0.0.0.0:0",
                "--allow-host", "rig-pc", "--operator-token-file", good)
    assert res.returncode == 2 and "the token would cross the network in clear" in res.stderr
    assert "--tls-cert CERT.pem --tls-key KEY.pem" in res.stderr and "openssl req -x509" in res.stderr
    assert not (tmp_path / "X").exists()


def test_the_live_options_are_checked_together(tmp_path):
    from stand.commands.live_page import check_live_options

    def check(serve=None, token=None, allow=None, cert=None, key=None):
        return check_live_options(argparse.Namespace(serve=serve, operator_token_file=token, allow_host=allow,
                                                     tls_cert=cert, tls_key=key))
    good = token_file(tmp_path / "good")
    assert check() == (None, None)
    with pytest.raises(ParameterError, match="--allow-host: give --serve HOST:PORT too"):
        check(allow=["rig-pc"])
    with pytest.raises(ParameterError, match="--tls-cert: give --serve"):
        check(cert="c.pem", key="k.pem")
    with pytest.raises(ParameterError, match="--allow-host NAME"):
        check("0.0.0.0:0")
    with pytest.raises(ParameterError, match="--tls-cert c.pem: No such file"):
        check("0", cert="c.pem", key="k.pem")
    with pytest.raises(ParameterError, match="cannot use them"):
        check("0", cert=str(good), key=str(good))
    binding, token = check("127.0.0.1:0", str(good))
    assert token == TOKEN and binding.address.loopback and not binding.tls


def test_every_file_the_page_loads_ships_in_the_package():
    """pyproject's package-data for endurance.live covers every file under static/ (an asset of a
    new kind would be left out of an install, and the page would break only there)."""
    import tomllib
    from pathlib import PurePosixPath
    root = Path(__file__).resolve().parents[1]
    globs = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["endurance.live"]
    static = root / "endurance" / "live"
    files = [str(p.relative_to(static)) for p in (static / "static").rglob("*") if p.is_file()]
    assert files and all(any(PurePosixPath(f).match(g) for g in globs) for f in files), files
