"""The live page served by the running session (``stand test start --serve``), read as a browser
reads it (its stream over plain HTTP): the example's test on the emulated example rig (4
channels, ``stand emulate --rig --lockstep`` in its own process on private loopback buses).
The stream brings every channel's force, reference and command at 10 updates a second or more,
moving; /status.json says what the CLI says; a wrong token is refused and the refusal reaches
the journal through the running session; a resume is not this page's; a pause with the token
stops the test at the end of its flight, and the page goes with the session."""
from __future__ import annotations

import json
import time

import numpy as np
import pytest

from endurance.journal import Journal, lock_holder
from tests.support.endurance_run import copy_short_test
from endurance.live.feed import LIVE_FILE
from endurance.live.viewer import StreamViewer
from tests.support.live import GATEWAY, TOKEN, flights_done, request, serving, stand, token_file, wait_for

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


def test_a_page_served_by_the_running_session(tmp_path, start_rig_emulator):
    rig = start_rig_emulator()
    test_file = copy_short_test(tmp_path / "t", rig.read_text())
    testdir = tmp_path / "T"
    token = token_file(tmp_path / "token")
    proc, url = serving("test", "start", test_file, "--out", testdir, "--flights", 200, *GATEWAY,
                        "--serve", "127.0.0.1:0", "--operator-token-file", token)
    reader = None
    try:
        assert url.startswith("http://127.0.0.1:")
        wait_for(lambda: flights_done(testdir) >= 1, 120, "a flight counted")
        reader = StreamViewer(url)
        time.sleep(4.0)
        samples = reader.of("samples")[1:]                     # the first: the window so far
        rate = reader.updates_per_s(last_s=3.0)
        assert rate >= 10.0, rate
        (_, page), = reader.of("page")
        assert page["channels"] == ["root", "inner", "outer", "tip"] and page["kind"] == "session"
        assert page["actions"] == ["pause", "stop"] and page["session"]["sample_hz"] == pytest.approx(50.0)
        t = np.concatenate([d["t"] for _, d in samples])
        assert np.all(np.diff(t) > 0) and 2.0 < t[-1] - t[0] < 8.0
        for i in range(4):
            y = np.concatenate([d["y"][i] for _, d in samples]).astype(float)
            u = np.concatenate([d["u"][i] for _, d in samples]).astype(float)
            assert np.ptp(y) > 50.0 and np.ptp(u) > 0.5, i          # moving

        # /status.json: what the CLI prints, a flight apart at most (the test runs)
        served = json.loads(request(url + "status.json")[2])
        cli = json.loads(stand("test", "status", testdir, "--json").stdout)
        for key in ("name", "testdir", "state", "flights_target", "channels", "fingerprint", "holder"):
            assert served[key] == cli[key], key
        assert abs(served["flights_done"] - cli["flights_done"]) <= 1

        # refused, and logged through the running session (its inbox)
        status, _, body = request(url + "pause", "POST", {"Authorization": "Bearer wrong-token-0123456789"}, b"")
        assert status == 403 and json.loads(body)["refused"] == "wrong token"
        wait_for(lambda: any(e["kind"] == "refused" for e in _events(testdir)), 10,
                 "the refusal in the journal")
        status, _, body = request(url + "resume", "POST", {"Authorization": f"Bearer {TOKEN}"}, b"")
        assert status == 409 and "served by the running session" in json.loads(body)["refused"]
        assert lock_holder(testdir) is not None and not (testdir / "stop.json").exists()

        # a pause with the token: the test stops at the end of its flight
        status, _, body = request(url + "pause", "POST", {"Authorization": f"Bearer {TOKEN}"}, b"")
        assert status == 200 and json.loads(body)["action"] == "pause"
        out, err = proc.communicate(timeout=180)
        assert proc.returncode == 0 and "Traceback" not in err, err
        with Journal.open(testdir) as j:
            assert j.state() == "stopped" and j.status()["reason"].startswith("operator: stopped at the end of flight")
        kinds = [e["kind"] for e in _events(testdir)]
        assert kinds.count("operator") == 1 and "stop_requested" in kinds
        assert not (testdir / LIVE_FILE).exists()
        print(json.dumps({"updates_per_s": round(rate, 1)}))
    finally:
        if reader is not None:
            reader.close()
        if proc.poll() is None:
            proc.terminate()
            proc.wait(timeout=60)


def _events(testdir) -> list[dict]:
    with Journal.open(testdir) as j:
        return j.events()
