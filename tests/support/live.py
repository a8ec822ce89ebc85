"""The live page's tests: a test on the emulated example rig with a page served beside it or by
it, the operator's token file, and plain HTTP clients of the page (its stream read as a
browser's EventSource reads it)."""
from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

from endurance.journal import Journal, lock_holder

TOKEN = "s3cret-operator-token-0123"
#: a loaded 2-core host may starve the emulator's heartbeats for a second (as test_endurance_e2e)
GATEWAY = ["--lockstep", "--no-progress", "--heartbeat-timeout", "3000"]


def token_file(path: Path, token: str = TOKEN, mode: int = 0o600) -> Path:
    path.write_text(token + "\n")
    path.chmod(mode)
    return path


def stand(*args, timeout: float = 120) -> subprocess.CompletedProcess:
    res = subprocess.run([sys.executable, "-m", "stand", *map(str, args)], capture_output=True, text=True,
                         timeout=timeout)
    assert "Traceback" not in res.stderr + res.stdout, res.stderr
    return res


def serving(*args) -> tuple[subprocess.Popen, str]:
    """``stand ARGS`` in the background, serving a page (``--serve 127.0.0.1:0``); the process
    and the page's URL (its first line)."""
    proc = subprocess.Popen([sys.executable, "-m", "stand", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    if not line.startswith("live page: "):
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError(f"no page served: {line}{out}{err}")
    return proc, line.split()[2]


def flights_done(testdir: Path) -> int:
    try:
        with Journal.open(testdir) as j:
            return j.flights_done
    except Exception:                     # not made yet
        return 0


def wait_for(predicate, timeout: float, why: str, every: float = 0.1):
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        assert time.monotonic() < deadline, f"{why}: not within {timeout} s"
        time.sleep(every)


def stop_sessions(testdir: Path) -> None:
    """End whatever session still runs the test (a resume the page started), by its pid."""
    import os
    import signal
    holder = lock_holder(testdir)
    if holder and holder.get("pid"):
        try:
            os.kill(int(holder["pid"]), signal.SIGTERM)
        except ProcessLookupError:
            return
        wait_for(lambda: lock_holder(testdir) is None, 60, "the session to end")


def request(url: str, method: str = "GET", headers: dict | None = None,
            data: bytes | None = None) -> tuple[int, dict, bytes]:
    """(status, headers, body) of one request, errors included."""
    req = urllib.request.Request(url, method=method, headers=headers or {}, data=data)
    try:
        with urllib.request.urlopen(req, timeout=30) as res:
            return res.status, dict(res.headers), res.read()
    except urllib.error.HTTPError as exc:
        return exc.code, dict(exc.headers), exc.read()


def journal_of_flights(testdir: Path, flights: int = 3, target: int = 10, channels=("root", "inner")) -> Path:
    """A test directory whose journal holds ``flights`` flights of three load cases (ground,
    peak, ground) with end points, stopped, as a session leaves it; no bus, no plant. Its
    test.json names examples/test.toml with ``--lockstep`` as the gateway's options."""
    from endurance.journal import EndPoint
    from tests.support.endurance_run import EXAMPLE
    with Journal.create(testdir, "a test of the live page", target, list(channels), "f" * 64, "{}",
                        EXAMPLE.read_text()) as journal:
        journal.start()
        for n in range(1, flights + 1):
            journal.begin_flight(n, "C", 1, n, 3)
            for k, level in enumerate((0.0, 1000.0 + 10 * n, 0.0)):
                journal.commit_load_case(n, k, [EndPoint(c, level, level + 2.0 * (i + 1), 5.0 * (i + 1) + n)
                                                 for i, c in enumerate(channels)])
        journal.stop("operator: stopped at the end of flight %d" % flights)
    (testdir / "test.json").write_text(json.dumps({"test_file": str(EXAMPLE), "gateway_args": ["--lockstep"]}))
    return testdir


def events_of(testdir: Path, kind: str) -> list[dict]:
    with Journal.open(testdir) as j:
        return [e for e in j.events() if e["kind"] == kind]


def refused_events(testdir: Path, at_least: int) -> list[dict] | None:
    """The journal's ``refused`` events once there are ``at_least`` (None before)."""
    refused = events_of(testdir, "refused")
    return refused if len(refused) >= at_least else None


@contextlib.contextmanager
def serve_page(tmp_path: Path, limits=None):
    """A factory of pages served in this process (on a thread each) for stopped tests (watch's
    kind), with or without the operator's token: ``serve(token) -> (url, testdir)``, the servers
    in ``serve.servers``. Summaries of refusals 0.5 s after the last (instead of 5 s), unless
    ``limits`` says otherwise."""
    from endurance.live.binding import Binding, bind_listeners
    from endurance.live.limits import Limits
    from endurance.live.operator import Operator
    from endurance.live.server import LiveServer
    limits = limits or Limits(summary_quiet_s=0.5)
    servers = []

    def serve(token: str | None = TOKEN, testdir: Path | None = None) -> tuple[str, Path]:
        testdir = testdir or journal_of_flights(tmp_path / f"T{len(servers)}")
        binding = Binding.check("127.0.0.1:0")
        sockets = bind_listeners(binding.address)
        server = LiveServer(testdir, Operator(testdir, token), "watch", binding, limits)
        servers.append(server)
        server.sockets = sockets
        server.start(sockets)
        return binding.url(sockets[0].getsockname()[1]), testdir

    serve.servers = servers
    try:
        yield serve
    finally:
        for server in servers:
            server.stop()
            for sock in server.sockets:
                sock.close()


def page_server(session: int) -> int | None:
    """The pid of the page server ``session`` (a session or ``stand test watch``) started (a
    child of one of its threads), or None."""
    for task in os.listdir(f"/proc/{session}/task"):
        try:
            with open(f"/proc/{session}/task/{task}/children") as fh:
                children = fh.read().split()
        except OSError:
            continue
        for child in children:
            try:
                with open(f"/proc/{child}/cmdline", "rb") as fh:
                    if b"endurance.live.process" in fh.read():
                        return int(child)
            except OSError:
                continue
    return None
