"""The live page's parts without a bus (endurance.live): the ring the loop puts into, the feed a
session publishes and a watcher reads, the inbox of events from outside a session, the
operator's token, and the page's server on a stopped test: every refusal (no token configured,
no header, a wrong token, a GET on an action, other paths, another Host), each logged in the
journal and none moving anything; /status.json is stand test status --json's text; the page
loads nothing from elsewhere."""
from __future__ import annotations

import json
import re
import socket
from pathlib import Path

import pytest

from core.errors import ParameterError
from endurance.inbox import INBOX_DIR, record_event, take_in
from endurance.journal import Journal, MonitorStep
from endurance.live.feed import LIVE_FILE, FeedClient, LiveFeed
from endurance.live.operator import REFUSALS_PER_MINUTE, Operator, read_token_file, resume_command
from endurance.live.ring import MARGIN, SampleRing
from endurance.live.server import Address, LiveServer, serve_address
from endurance.live.viewer import StreamViewer
from endurance.monitors import detector_rows
from endurance.report import status_json, status_of
from endurance.trends import TrendDetector, TrendOptions
from tests.support.live import TOKEN, journal_of_flights, request, stand, token_file, wait_for


# -- the ring and the feed ------------------------------------------------------------------------------------
def test_a_ring_gives_each_reader_what_came_since_it_looked_and_the_newest_when_it_fell_behind():
    ring = SampleRing(MARGIN + 36)
    assert ring.since(0) == (0, [])
    for i in range(10):
        ring.put(i)
    seq, rows = ring.since(0)
    assert (seq, rows) == (10, list(range(10)))
    for i in range(10, 500):
        ring.put(i)
    seq2, rows = ring.since(seq)                       # lapped: the newest capacity - MARGIN
    assert seq2 == 500 and rows == list(range(464, 500))
    assert ring.since(seq2) == (500, [])
    with pytest.raises(ValueError):
        SampleRing(MARGIN)


def test_a_session_feed_decimates_the_loop_and_serves_watchers_with_its_key_only(tmp_path):
    feed = LiveFeed(sample_hz=50.0)
    feed.open(tmp_path, ["a", "b"], 0.002)
    info = json.loads((tmp_path / LIVE_FILE).read_text())
    assert (tmp_path / LIVE_FILE).stat().st_mode & 0o777 == 0o600
    assert feed.hello == {"channels": ["a", "b"], "period_s": 0.002, "sample_hz": 50.0, "pid": info["pid"]}
    client = FeedClient(tmp_path).start()
    try:
        wait_for(lambda: client.hello, 10, "the watcher connected")
        for k in range(200):                           # 0.4 s of 2 ms cycles: a row every 20 ms
            feed.cycle(1000.0 + k * 0.002, [k, -k], [k + 1, -k - 1], [0.5, -0.5])
        for k in range(20):                            # slow lockstep cycles of 7 ms: every 3rd
            feed.cycle(1000.4 + k * 0.007, [k, -k], [k + 1, -k - 1], [0.5, -0.5])
        wait_for(lambda: client.ring.count >= 27, 10, "the rows at the watcher")
        _, rows = client.ring.since(0)
        assert rows[0] == (1000.0, 0, 0, 1, -1, 0.5, -0.5) and rows[1][1] == 10 and len(rows) == 20 + 7
        assert [r[1] for r in rows[20:]] == [0, 3, 6, 9, 12, 15, 18]
        # a connection without the key gets nothing and is closed
        with socket.create_connection(("127.0.0.1", info["port"]), timeout=5) as sock:
            sock.sendall(b"not-the-key\n")
            assert sock.recv(100) == b""
    finally:
        client.close()
        feed.close()
    assert not (tmp_path / LIVE_FILE).exists() and feed.hello is None


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
    (None, 0o600, "no such file"),
    ("\n\n", 0o600, "it is empty"),
    (TOKEN, 0o644, "others may read it (mode 0644); chmod 600"),
    (TOKEN, 0o640, "others may read it"),
    ("short", 0o600, "at least 16 characters"),
    (f"{TOKEN}\n{TOKEN}", 0o600, "give one line"),
])
def test_a_token_file_that_is_missing_empty_short_or_readable_by_others_is_refused(tmp_path, text, mode, message):
    path = tmp_path / "token"
    if text is not None:
        path.write_text(text)
        path.chmod(mode)
    with pytest.raises(ParameterError, match=re.escape(message)):
        read_token_file(path)


def test_a_token_file_gives_its_one_line_and_the_token_is_compared_whole(tmp_path):
    assert read_token_file(token_file(tmp_path / "token", f"  {TOKEN}  ")) == TOKEN
    operator = Operator(tmp_path, TOKEN)
    assert operator.refusal(f"Bearer {TOKEN}") is None and operator.refusal(f"bearer  {TOKEN} ") is None
    assert operator.refusal(f"Bearer {TOKEN[:-1]}") == "wrong token"
    assert operator.refusal(f"Bearer {TOKEN}x") == "wrong token"


def test_the_serve_address_binds_loopback_unless_a_host_is_named():
    assert serve_address("8080") == Address("127.0.0.1", 8080)
    assert serve_address(":0") == Address("127.0.0.1", 0)
    assert serve_address("0.0.0.0:81") == Address("0.0.0.0", 81) and not serve_address("0.0.0.0:81").loopback
    assert serve_address("[::1]:8080") == Address("::1", 8080) and serve_address("[::1]:8080").loopback
    assert serve_address("localhost:1").loopback
    for bad in ("abc", "host:", "1:2:3", "127.0.0.1:70000", "[::1]8080"):
        with pytest.raises(ParameterError, match="--serve"):
            serve_address(bad)


# -- the server on a stopped test -----------------------------------------------------------------------------------
@pytest.fixture
def page(tmp_path):
    """A page served for a stopped test (watch's kind), with or without the operator's token."""
    servers = []

    def serve(token: str | None = TOKEN) -> tuple[str, Path]:
        testdir = journal_of_flights(tmp_path / f"T{len(servers)}")
        server = LiveServer(Address("127.0.0.1", 0), testdir, FeedClient(testdir), Operator(testdir, token), "watch")
        servers.append(server)
        return server.start(), testdir

    yield serve
    for server in servers:
        server.stop()


def events_of(testdir: Path, kind: str) -> list[dict]:
    with Journal.open(testdir) as j:
        return [e for e in j.events() if e["kind"] == kind]


def test_every_refusal_is_403_or_405_logged_in_the_journal_and_moves_nothing(page):
    url, testdir = page(TOKEN)
    bearer = {"Authorization": f"Bearer {TOKEN}"}
    cases = [("POST", "pause", {}, 403, "no Authorization header"),
             ("POST", "stop", {"Authorization": "Bearer not-the-token-at-all"}, 403, "wrong token"),
             ("POST", "resume", {"Authorization": f"Basic {TOKEN}"}, 403, "is not Bearer TOKEN"),
             ("POST", "pause", {"Authorization": "Bearer "}, 403, "is not Bearer TOKEN"),
             ("GET", "pause", bearer, 405, "is an action: POST it"),
             ("PUT", "stop", bearer, 405, "is an action: POST it"),
             ("DELETE", "resume", bearer, 405, "is an action: POST it")]
    for method, action, headers, code, why in cases:
        status, head, body = request(url + action, method, headers, b"" if method != "GET" else None)
        assert status == code and why in json.loads(body)["refused"], (method, action, status, body)
    logged = events_of(testdir, "refused")
    assert len(logged) == len(cases)
    assert "POST /pause from 127.0.0.1 refused: no Authorization header" in logged[0]["message"]
    assert "GET /pause from 127.0.0.1 refused: an action is a POST" in logged[4]["message"]
    # other paths and methods: nothing there
    for method, path, code in (("GET", "nothing", 404), ("POST", "", 405), ("POST", "status.json", 405),
                               ("POST", "pause/now", 404), ("POST", "live", 405), ("POST", "static/live.js", 405)):
        assert request(url + path, method, bearer, b"")[0] == code, (method, path)
    # a name that is not loopback's (a DNS name pointed at 127.0.0.1): refused
    assert request(url + "status.json", headers={"Host": "evil.example:80"})[0] == 403
    assert not (testdir / "stop.json").exists() and not (testdir / "sessions").exists()     # no resume
    assert len(events_of(testdir, "refused")) == len(cases)
    assert events_of(testdir, "operator") == []


def test_a_read_only_page_refuses_every_action_even_with_a_token(page):
    url, testdir = page(None)
    for action in ("pause", "stop", "resume"):
        status, _, body = request(url + action, "POST", {"Authorization": f"Bearer {TOKEN}"}, b"")
        assert status == 403 and "read-only" in json.loads(body)["refused"]
    assert len(events_of(testdir, "refused")) == 3
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


def test_refusals_are_logged_at_most_ten_a_minute(tmp_path):
    testdir = journal_of_flights(tmp_path / "T")
    operator = Operator(testdir, TOKEN)
    for _ in range(REFUSALS_PER_MINUTE + 5):
        operator.log_refusal("POST /stop", "wrong token", "127.0.0.1")
    assert len(events_of(testdir, "refused")) == REFUSALS_PER_MINUTE


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
    assert not (tmp_path / "X").exists()


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
