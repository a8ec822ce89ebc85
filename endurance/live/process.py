r"""The live page's server as a process of its own, and the watch over it that starts it again.

::

    the session (or stand test watch)                  the page's server
    PageProcess: binds the listening sockets once,     python -m endurance.live.process
      starts the server with them, its configuration     (its configuration from stdin, which it
      on its stdin; a thread waits for it to end and      then watches: an end of file means the
      starts it again (the port stays: the kernel         session is gone, and so does it), OOM
      keeps new connections waiting meanwhile)            score 1000 (the kernel's first choice)

The session accepts no connection and holds nothing per client: a server that is overloaded,
out of descriptors or memory, crashes or is killed ends alone, and the session's watch starts a
new one within :data:`RESTART_DELAY_S` (and its start-up), saying so on stderr and in the
journal (a ``live_page`` event). A server that ends :data:`MAX_ENDS` times in a minute is
started again only every :data:`DOWN_RETRY_S`, and the session says the page is down.
"""
from __future__ import annotations

import collections
import functools
import json
import os
import selectors
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import TextIO

from core.errors import StandError

from .binding import Binding, bind_listeners
from .limits import Limits

#: after a server ended, before the next starts, s
RESTART_DELAY_S = 0.2
#: a server that ends this often in a minute ...
MAX_ENDS = 3
#: ... is started again only this often, s
DOWN_RETRY_S = 60.0
#: how long a server may take to start (its imports on a busy host), s
READY_TIMEOUT_S = 60.0
#: how long a server may take to end when asked, s
STOP_TIMEOUT_S = 5.0


def _ended(code: int) -> str:
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


class PageProcess:
    """The page's server for the test in ``testdir``, in a process of its own, watched (module
    docstring). ``kind``: "session" or "watch"; ``token``: the operator's (None: read-only);
    ``out``: where the watch says what happened (and the journal)."""

    def __init__(self, testdir: str | Path, kind: str, binding: Binding, token: str | None,
                 limits: Limits = Limits(), out: TextIO | None = None) -> None:
        self.testdir = Path(testdir)
        self.kind = kind
        self.binding = binding
        self.token = token
        self.limits = limits
        self.out = out
        self.url: str | None = None
        self.port: int | None = None
        self._sockets: list[socket.socket] = []
        self._proc: subprocess.Popen | None = None
        self._halt = threading.Event()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._ends: collections.deque[float] = collections.deque()
        #: the server processes started so far (pids)
        self.pids: list[int] = []

    @property
    def pid(self) -> int | None:
        proc = self._proc
        return proc.pid if proc is not None and proc.poll() is None else None

    def start(self) -> str:
        """Bind, start the server and wait until it accepts; the page's URL. A clear error if it
        cannot listen there or the server does not start."""
        self._sockets = bind_listeners(self.binding.address)
        self.port = self._sockets[0].getsockname()[1]
        self.url = self.binding.url(self.port)
        try:
            self._spawn()
        except StandError:
            self._close_sockets()
            raise
        self._thread = threading.Thread(target=self._watch, name="live-page-watch", daemon=True)
        self._thread.start()
        return self.url

    def stop(self) -> None:
        """End the server (asked, then killed) and stop listening."""
        self._halt.set()
        for _ in range(2):                  # the watch may have been starting one meanwhile
            with self._lock:
                proc = self._proc
            if proc is not None:
                _end(proc)
            if self._thread is not None:
                self._thread.join(timeout=STOP_TIMEOUT_S + 5.0)
        self._close_sockets()

    def _close_sockets(self) -> None:
        for sock in self._sockets:
            sock.close()
        self._sockets = []

    # -- one server --------------------------------------------------------------------------------------
    def _config(self) -> dict:
        b = self.binding
        return {"testdir": str(self.testdir), "kind": self.kind, "token": self.token,
                "serve": f"[{b.address.host}]:{b.address.port}" if ":" in b.address.host
                else f"{b.address.host}:{b.address.port}",
                "allow_hosts": list(b.allow_hosts), "tls_cert": b.tls_cert, "tls_key": b.tls_key,
                "limits": self.limits.to_dict(), "fds": [s.fileno() for s in self._sockets]}

    def _spawn(self) -> None:
        fds = [s.fileno() for s in self._sockets]
        proc = subprocess.Popen([sys.executable, "-m", "endurance.live.process"], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, pass_fds=fds, start_new_session=True)
        with self._lock:
            self._proc = proc
        try:
            proc.stdin.write((json.dumps(self._config()) + "\n").encode())
            proc.stdin.flush()
        except OSError:
            pass                                        # it ended already: said below
        with selectors.DefaultSelector() as sel:
            sel.register(proc.stdout, selectors.EVENT_READ)
            ready = sel.select(READY_TIMEOUT_S) and proc.stdout.readline().startswith(b"ready")
        proc.stdout.close()
        if not ready:
            _end(proc)
            raise StandError(f"the live page's server did not start ({_ended(proc.returncode)}; its "
                             "messages above)")
        self.pids.append(proc.pid)

    def _watch(self) -> None:
        while not self._halt.is_set():
            proc = self._proc
            code = proc.wait()
            _end(proc)
            if self._halt.is_set():
                return
            t0 = time.monotonic()
            ends = self._ends
            ends.append(t0)
            while ends and t0 - ends[0] > 60.0:
                ends.popleft()
            what = f"the live page's server (process {proc.pid}) ended ({_ended(code)})"
            delay = RESTART_DELAY_S
            if len(ends) >= MAX_ENDS:
                delay = DOWN_RETRY_S
                self._say(f"{what}, {len(ends)} times in a minute: the page is down; starting it again "
                          f"every {DOWN_RETRY_S:.0f} s")
            if self._halt.wait(delay):
                return
            try:
                self._spawn()
            except Exception as exc:               # the watch goes on whatever the start did
                self._say(f"{what}; starting it again failed: {exc}")
                continue
            self._say(f"{what}; served again by process {self._proc.pid}, "
                      f"{time.monotonic() - t0:.1f} s later")

    def _say(self, message: str) -> None:
        from endurance.inbox import record_event
        try:
            record_event(self.testdir, "live_page", message)
        except Exception as exc:                   # no journal yet: the line below says it
            message += f" (not journalled: {exc})"
        if self.out is not None:
            try:
                print(f"live page: {message}", file=self.out, flush=True)
            except (OSError, ValueError):          # a closed terminal: the journal has it
                pass


def _end(proc: subprocess.Popen) -> None:
    """Ask the server to end, kill it if it does not, and close its stdin."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    try:
        proc.stdin.close()
    except OSError:
        pass


# -- the server's process ------------------------------------------------------------------------------------
OOM_SCORE_ADJ = "/proc/self/oom_score_adj"


def _oom_score_adj(value: int | None = None) -> int | None:
    """This process's OOM score adjustment (Linux), set to ``value`` if given; None if there is
    none to read. Only system calls: it also runs in a child between fork and exec."""
    try:
        fd = os.open(OOM_SCORE_ADJ, os.O_RDWR)
    except OSError:
        return None
    try:
        if value is not None:
            os.write(fd, str(value).encode())
            return value
        return int(os.read(fd, 16) or 0)
    except (OSError, ValueError):
        return None
    finally:
        os.close(fd)


def main() -> int:
    """The server process (module docstring): its configuration is one JSON line on stdin."""
    from .operator import Operator, warm_up
    from .server import LiveServer, log_to_stderr
    line = sys.stdin.buffer.readline()
    if not line:
        print("endurance.live.process: the live page's server is started by stand test start|resume --serve "
              "or stand test watch, with its configuration on stdin", file=sys.stderr)
        return 2
    config = json.loads(line)
    was = _oom_score_adj()
    _oom_score_adj(1000)                     # the kernel's first choice when memory runs out, not the session
    limits = Limits(**config["limits"])
    log_to_stderr(limits)
    binding = Binding.check(config["serve"], config["allow_hosts"], config["tls_cert"], config["tls_key"],
                            token=config["token"] is not None)
    sockets = [socket.socket(fileno=fd) for fd in config["fds"]]
    testdir = Path(config["testdir"])
    operator = Operator(testdir, config["token"], can_resume=config["kind"] == "watch",
                        child_setup=None if was is None else functools.partial(_oom_score_adj, was))
    server = LiveServer(testdir, operator, config["kind"], binding, limits)

    def ready() -> None:
        loop = server._loop
        stdin = sys.stdin.fileno()

        def end() -> None:
            loop.remove_reader(stdin)
            loop.remove_signal_handler(signal.SIGTERM)
            loop.stop()

        def watch_stdin() -> None:
            if not os.read(stdin, 4096):         # the session is gone: so is its page
                end()
        loop.add_signal_handler(signal.SIGTERM, end)
        loop.add_reader(stdin, watch_stdin)
        sys.stdout.write("ready\n")
        sys.stdout.flush()
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        threading.Thread(target=warm_up, name="warm-up", daemon=True).start()

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    server.serve(sockets, ready)
    return 0


if __name__ == "__main__":
    sys.exit(main())
