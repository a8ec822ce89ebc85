"""Nothing on the network can stop a running test (issue 49): the example's test on the emulated
example rig (``stand emulate --rig --lockstep`` in its own process on private loopback buses),
started with ``--serve 127.0.0.1:0`` and a descriptor limit of 128 (the session's, so its page
server's too). From 127.0.0.2, 1,000 connections held open, 200 ``/live`` streams that never
read and 8 slowloris connections; from 127.0.0.3, 5,000 bad requests (bad paths, wrong tokens,
bodies over the limit, foreign Hosts, methods an action does not take, garbage); all at once,
and the page's server ``kill -9``'d in the middle of it. A viewer from 127.0.0.1 that behaves
(it opens the stream again a second after it ends, as a browser does) gets updates throughout
and again within 5 s of the server's restart; the test flies on, every flight counted, no
interruption; the session's memory stays within 50 MB of what it was, the server's stderr
(the session's) under 100 kB; the journal holds a summary of the refusals, not one event each,
and says the server was started again."""
from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import time

import pytest

from endurance.journal import Journal
from endurance.live.viewer import StreamViewer
from tests.support.endurance_run import copy_short_test
from tests.support.live import GATEWAY, events_of, flights_done, page_server, stand, token_file, wait_for

pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.serial]

DESCRIPTORS = 128
#: the issue's bounds
MEMORY_BOUND_MB = 50.0
STDERR_BOUND_BYTES = 100_000
BACK_WITHIN_S = 5.0


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise AssertionError(f"no VmRSS for {pid}")


def limited() -> None:
    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (DESCRIPTORS, hard))


def test_nothing_on_the_network_stops_a_running_test(tmp_path, start_rig_emulator):
    rig = start_rig_emulator()
    test_file = copy_short_test(tmp_path / "t", rig.read_text())
    testdir = tmp_path / "T"
    token = token_file(tmp_path / "token")
    stderr_path = tmp_path / "session.err"
    figures: dict = {}
    with open(stderr_path, "wb") as err:
        session = subprocess.Popen([sys.executable, "-m", "stand", "test", "start", str(test_file), "--out",
                                    str(testdir), "--flights", "500", *GATEWAY, "--serve", "127.0.0.1:0",
                                    "--operator-token-file", str(token)],
                                   stdout=subprocess.PIPE, stderr=err, text=True, preexec_fn=limited)
    viewer = abuser = None
    try:
        line = session.stdout.readline()
        assert line.startswith("live page: http://127.0.0.1:"), line + stderr_path.read_text()
        url = line.split()[2]
        port = int(url.rsplit(":", 1)[1].strip("/"))
        wait_for(lambda: flights_done(testdir) >= 1, 120, "a flight counted")
        server = page_server(session.pid)
        assert server is not None
        with open(f"/proc/{server}/limits") as fh:
            assert any(f"Max open files            {DESCRIPTORS}" in line for line in fh)
        viewer = StreamViewer(url, reconnect_s=1.0)
        wait_for(lambda: len(viewer.of("samples")) > 5, 30, "the viewer's updates")
        baseline = rss_mb(session.pid)

        # -- all at once, and the server killed in the middle of it ---------------------------------------
        abuser = subprocess.Popen([sys.executable, "-m", "tests.support.abuse", str(port), "--seconds", "12"],
                                  stdout=subprocess.PIPE, text=True)
        time.sleep(5.0)
        figures["viewer_updates_per_s_under_abuse"] = round(viewer.updates_per_s(last_s=3.0), 1)
        flights_at_kill = flights_done(testdir)
        figures["server_rss_mb_under_abuse"] = round(rss_mb(server), 1)
        figures["server_descriptors_under_abuse"] = len(os.listdir(f"/proc/{server}/fd"))
        os.kill(server, signal.SIGKILL)
        killed = time.time()
        restarted = wait_for(lambda: "served again by process" in stderr_path.read_text() and time.time(), 30,
                             "the server started again")
        wait_for(lambda: any(t > restarted for t, _ in viewer.of("samples")), 30, "the viewer's updates again")
        back = min(t for t, _ in viewer.of("samples") if t > restarted)
        figures["restart_s"] = round(restarted - killed, 2)
        figures["updates_after_restart_s"] = round(back - restarted, 2)
        assert back - restarted <= BACK_WITHIN_S, figures
        report = json.loads(abuser.communicate(timeout=120)[0])
        figures["abuse"] = report
        figures["session_rss_mb"] = [round(baseline, 1), round(rss_mb(session.pid), 1)]
        assert rss_mb(session.pid) - baseline <= MEMORY_BOUND_MB, figures

        # -- the refusals summarised in the journal, the restart said --------------------------------------
        def summary():
            return [e for e in events_of(testdir, "refused") if "requests refused" in e["message"]]
        wait_for(summary, 30, "the summary of the refusals")
        wait_for(lambda: flights_done(testdir) > flights_at_kill, 120, "a flight after the kill")
        assert session.poll() is None
        assert stand("test", "stop", testdir, timeout=300).returncode == 0
        session.communicate(timeout=120)
    finally:
        if viewer is not None:
            viewer.close()
        for proc in (abuser, session):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    assert session.returncode == 0
    with Journal.open(testdir) as j:
        status = j.status()
        done = j.flights_done
        flights = [j.flight(n) for n in range(1, done + 1)]
        kinds = [e["kind"] for e in j.events()]
    figures["flights"] = done
    assert status["state"] == "stopped" and status["reason"].startswith("operator: stopped at the end of flight")
    assert all(f is not None and f.status == "done" and f.interruptions == 0 for f in flights), flights
    assert "interrupted" not in kinds
    refused = events_of(testdir, "refused")
    figures["refused_events"] = len(refused)
    counted = sum(int(e["message"].split()[0].replace(",", "")) for e in refused if "requests refused" in e["message"])
    figures["refusals_in_summaries"] = counted
    assert len(refused) <= 10 and counted >= 1000, [e["message"] for e in refused]
    (restart,) = events_of(testdir, "live_page")
    assert f"(process {server}) ended (killed by SIGKILL); served again" in restart["message"]
    figures["stderr_bytes"] = stderr_path.stat().st_size
    assert figures["stderr_bytes"] < STDERR_BOUND_BYTES, stderr_path.read_text()[-3000:]
    assert "Traceback" not in stderr_path.read_text()
    # what the abuse met: answers (no server error), bounded streams and slow headers
    bad = report["bad"]
    assert report["bad_not_sent"] == 0 and sum(bad.values()) == 5000, report
    assert not any(code.startswith("5") for code in bad), bad
    assert sum(n for code, n in bad.items() if code.startswith("4")) >= 3000, bad
    assert report["slowloris"].get("longest held s", 0) <= 12, report
    print(json.dumps(figures))
