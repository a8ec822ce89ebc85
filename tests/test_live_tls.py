"""The live page beyond loopback (``--serve 0.0.0.0:PORT``), in a network namespace of its own
that has only ``lo`` (nothing outside this test can reach it; needs root): with a certificate
made here (openssl, self-signed for ``rig.example``) it answers HTTPS for its allowed name, with
the token acting; a foreign name in ``Host`` is refused, and plain HTTP gets nothing; without a
certificate, a token on that address is refused at start with what to do."""
from __future__ import annotations

import ctypes
import json
import os
import shutil
import socket
import ssl
import subprocess
import sys
import threading

import pytest

from endurance.live.viewer import StreamViewer
from tests.support.live import TOKEN, events_of, journal_of_flights, token_file, wait_for

CLONE_NEWNET = 0x40000000
PORT = 8443
IN_NAMESPACE = ["unshare", "--net", "--", "sh", "-c", 'ip link set lo up && exec "$@"', "sh"]

pytestmark = pytest.mark.skipif(os.geteuid() != 0 or not shutil.which("unshare") or not shutil.which("openssl"),
                                reason="needs root (a network namespace), unshare and openssl")


def in_namespace_of(pid: int, work):
    """``work()`` on a thread inside the network namespace of process ``pid``; its result."""
    out: dict = {}

    def run() -> None:
        libc = ctypes.CDLL(None, use_errno=True)
        fd = os.open(f"/proc/{pid}/ns/net", os.O_RDONLY)
        try:
            if libc.setns(fd, CLONE_NEWNET) != 0:
                raise OSError(ctypes.get_errno(), "setns")
            out["value"] = work()
        except BaseException as exc:          # handed to the caller
            out["error"] = exc
        finally:
            os.close(fd)
    thread = threading.Thread(target=run)
    thread.start()
    thread.join(60)
    if "error" in out:
        raise out["error"]
    return out["value"]


def https(context: ssl.SSLContext, method: str, path: str, host: str, headers: dict | None = None) -> tuple[int, dict]:
    with socket.create_connection(("127.0.0.1", PORT), timeout=10) as raw:
        with context.wrap_socket(raw, server_hostname="rig.example") as sock:
            lines = [f"{method} {path} HTTP/1.0", f"Host: {host}", "Content-Length: 0",
                     *(f"{k}: {v}" for k, v in (headers or {}).items())]
            sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
            data = b""
            while chunk := sock.recv(65536):
                data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    return int(head.split()[1]), json.loads(body) if body else {}


def test_beyond_loopback_the_page_is_https_for_its_names_alone(tmp_path):
    testdir = journal_of_flights(tmp_path / "T")
    token = token_file(tmp_path / "token")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
                    "-days", "1", "-subj", "/CN=rig.example", "-addext", "subjectAltName=DNS:rig.example",
                    "-keyout", str(key), "-out", str(cert)], check=True, capture_output=True)
    key.chmod(0o600)
    stand = [sys.executable, "-m", "stand", "test", "watch", str(testdir), "--serve", f"0.0.0.0:{PORT}",
             "--allow-host", "rig.example", "--operator-token-file", str(token)]

    # plain HTTP with a token on that address: refused at start, saying how to give a certificate
    res = subprocess.run(IN_NAMESPACE + stand, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "the token would cross the network in clear" in res.stderr
    assert "--tls-cert CERT.pem --tls-key KEY.pem" in res.stderr and "Traceback" not in res.stderr

    watch = subprocess.Popen(IN_NAMESPACE + stand + ["--tls-cert", str(cert), "--tls-key", str(key)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first, second = watch.stdout.readline(), watch.stdout.readline()
        assert first == f"live page: https://rig.example:{PORT}/ (operator actions with the token)\n", \
            first + second + (watch.stderr.read() if watch.poll() is not None else "")
        assert f"listening on every interface port {PORT} for rig.example (HTTPS)" in second
        context = ssl.create_default_context(cafile=str(cert))

        def session():
            ok = https(context, "GET", "/status.json", f"rig.example:{PORT}")
            foreign = https(context, "GET", "/status.json", "evil.example")
            bearer = {"Authorization": f"Bearer {TOKEN}"}
            acted = https(context, "POST", "/pause", f"rig.example:{PORT}", bearer)
            wrong = https(context, "POST", "/pause", f"rig.example:{PORT}", {"Authorization": "Bearer x" * 3})
            viewer = StreamViewer(f"https://127.0.0.1:{PORT}/", context=context, host=f"rig.example:{PORT}")
            try:
                wait_for(lambda: viewer.of("status"), 10, "the stream over HTTPS")
            finally:
                viewer.close()
            with socket.create_connection(("127.0.0.1", PORT), timeout=10) as sock:    # plain HTTP
                sock.sendall(b"GET /status.json HTTP/1.0\r\nHost: rig.example\r\n\r\n")
                try:
                    plain = sock.recv(100)
                except ConnectionResetError:
                    plain = b""
            return ok, foreign, acted, wrong, plain

        ok, foreign, acted, wrong, plain = in_namespace_of(watch.pid, session)
        assert ok[0] == 200 and ok[1]["state"] == "stopped"
        assert foreign == (403, {"refused": "this server answers only to its own names, not evil.example"})
        assert acted[0] == 409 and "no session runs the test" in acted[1]["refused"]     # the token acts
        assert wrong[0] == 403 and wrong[1]["refused"] == "wrong token"
        assert not plain.startswith(b"HTTP")
        watch.terminate()
        out, err = watch.communicate(timeout=60)
        assert "SSL Error" not in err and "Traceback" not in err, err       # counted, not logged
        refused = " / ".join(e["message"] for e in events_of(testdir, "refused"))
        assert "GET /status.json from 127.0.0.1 refused: Host not allowed" in refused, refused
        assert "POST /pause from 127.0.0.1 refused: wrong token" in refused
        assert "1 request refused from 127.0.0.1 in the last" in refused and "TLS handshake failed 1" in refused
    finally:
        watch.terminate()
        watch.wait(timeout=60)
