"""The operator's actions from the live page: who may act, and what an action does.

* The **token**: ``--operator-token-file FILE`` (:func:`read_token_file`; ``stand test token
  FILE`` makes one, :func:`write_token_file`): one line of at least :data:`MIN_TOKEN_CHARS`
  printable ASCII characters, in a plain file no one but its owner can read (as ssh asks of a
  private key). Without it the server is read-only. A request acts only with
  ``Authorization: Bearer TOKEN`` (compared in constant time, :meth:`Operator.refusal`).
* **pause**: stop at the end of the flight in progress, as ``stand test stop`` (it writes
  ``TESTDIR/stop.json``: :func:`endurance.run.request_stop`); **stop**: ``stand test stop
  --at-once`` (every channel unloads keeping the load ratios). Both only while a session runs.
* **resume**: ``stand test resume TESTDIR`` with the gateway options the test was started with
  (``TESTDIR/test.json``, :data:`endurance.run.TEST_RECORD`) as its own process, in its own
  session (it outlives the page's server), its output in ``TESTDIR/sessions/resume-*.log``;
  refused while a session runs, once the test is finished (the target is raised from the
  command line, ``stand test resume --flights N``) and while the trend's alarm that stopped it
  waits for what the inspection found (``--inspected`` or ``--repaired``, the command line's:
  :func:`endurance.monitors.after_inspection`).

Every action taken is an ``operator`` event in the journal (:func:`endurance.inbox.record_event`);
refusals are counted by the server and journalled as ``refused`` events, a flood as one summary
(:class:`endurance.live.limits.RefusalTally`).
"""
from __future__ import annotations

import hmac
import json
import os
import secrets
import stat
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from core.errors import ParameterError, StandError
from endurance.inbox import record_event
from endurance.journal import Journal, lock_holder

MIN_TOKEN_CHARS = 16
#: the random bytes of a token :func:`write_token_file` makes (32 characters)
TOKEN_BYTES = 24
ACTIONS = ("pause", "stop", "resume")


#: how a token file is made (``stand test token FILE`` does it: :func:`write_token_file`)
TOKEN_HINT = "make one with stand test token FILE"
#: a token file longer than this is not a token file, bytes
MAX_TOKEN_FILE_BYTES = 1024


def _printable(token: str) -> bool:
    """Printable ASCII without spaces: what an HTTP header carries as it was typed (a header is
    latin-1; a token of other characters could never match)."""
    return all(0x21 <= ord(c) <= 0x7E for c in token)


def read_token_file(path: str | Path) -> str:
    """The operator's token from ``path`` (module docstring); a clear error for a file that
    is missing, not a plain file (checked before it is read: a FIFO would block), empty, too
    short, not printable ASCII or readable by others."""
    path = Path(path)
    where = f"--operator-token-file {path}"
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
    except FileNotFoundError:
        raise ParameterError(f"{where}: no such file ({TOKEN_HINT})") from None
    except OSError as exc:
        raise ParameterError(f"{where}: cannot open it ({exc.strerror or exc})") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise ParameterError(f"{where}: not a plain file ({TOKEN_HINT})")
        if info.st_mode & 0o077:
            raise ParameterError(f"{where}: others may read it (mode {stat.S_IMODE(info.st_mode):04o}); "
                                 f"chmod 600 {path}")
        if info.st_size > MAX_TOKEN_FILE_BYTES:
            raise ParameterError(f"{where}: {info.st_size:,} bytes is not a token file (one line; {TOKEN_HINT})")
        data = os.read(fd, MAX_TOKEN_FILE_BYTES + 1)
    except OSError as exc:
        raise ParameterError(f"{where}: cannot read it ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        raise ParameterError(f"{where}: the token must be printable ASCII (a header carries nothing else; "
                             f"{TOKEN_HINT})") from None
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    if not lines:
        raise ParameterError(f"{where}: it is empty ({TOKEN_HINT})")
    if len(lines) > 1:
        raise ParameterError(f"{where}: give one line (the token), not {len(lines)}")
    token = lines[0]
    if len(token) < MIN_TOKEN_CHARS or not _printable(token):
        raise ParameterError(f"{where}: the token must be at least {MIN_TOKEN_CHARS} printable ASCII "
                             f"characters without spaces ({TOKEN_HINT})")
    return token


def write_token_file(path: str | Path) -> Path:
    """A new operator's token (:data:`TOKEN_BYTES` random bytes, URL-safe text) in a new file
    at ``path``, mode 600; an existing file is never overwritten."""
    path = Path(path)
    token = secrets.token_urlsafe(TOKEN_BYTES)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    except FileExistsError:
        raise ParameterError(f"{path}: it exists; give a new file's name (a token file is never "
                             "overwritten: the pages that use it would stop working)") from None
    except OSError as exc:
        raise ParameterError(f"{path}: cannot make it ({exc.strerror or exc})") from None
    with os.fdopen(fd, "w") as fh:
        os.fchmod(fh.fileno(), 0o600)
        fh.write(token + "\n")
    return path


class Refused(StandError):
    """An action refused: ``status`` the HTTP status (403 no right, 409 not now)."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


@dataclass
class Done:
    """An action taken: what the page shows."""

    action: str
    message: str


def warm_up() -> None:
    """Import what the actions need (the session's modules, seconds on a busy host): the page's
    server does it on a thread once it serves, so that its first action does not wait."""
    import endurance.monitors  # noqa: F401
    import endurance.run  # noqa: F401


class Operator:
    """The actions on the test in ``testdir`` (module docstring); ``token`` None: read-only.
    ``can_resume``: False where the page is served by the running session itself (it ends with
    it: a resume is for ``stand test watch``)."""

    def __init__(self, testdir: str | Path, token: str | None, can_resume: bool = True,
                 child_setup: Callable[[], None] | None = None) -> None:
        self.testdir = Path(testdir)
        self._token = token.encode() if token else None
        self.can_resume = can_resume
        #: run in a resume's process before it starts (the page's server undoes what it set for
        #: itself: the test's session is not the kernel's first choice when memory runs out)
        self.child_setup = child_setup

    @property
    def read_only(self) -> bool:
        return self._token is None

    # -- who may act ---------------------------------------------------------------------------------
    def refusal(self, authorization: str | None) -> str | None:
        """Why a request with this ``Authorization`` header may not act (None: it may)."""
        if self._token is None:
            return "the page is read-only (its server was started without --operator-token-file)"
        if not authorization:
            return "no Authorization header (give Authorization: Bearer TOKEN)"
        scheme, _, given = authorization.strip().partition(" ")
        if scheme.lower() != "bearer" or not given.strip():
            return "the Authorization header is not Bearer TOKEN"
        if not hmac.compare_digest(given.strip().encode(), self._token):
            return "wrong token"
        return None

    # -- the actions -----------------------------------------------------------------------------------
    def act(self, action: str, client: str) -> Done:
        """Take ``action`` (authorized already); :class:`Refused` when it cannot be taken now."""
        if action == "resume":
            return self._resume(client)
        at_once = action == "stop"
        try:
            from endurance.run import request_stop
            request_stop(self.testdir, at_once=at_once)
        except StandError as exc:
            raise Refused(409, str(exc)) from None
        how = ("at once: every channel unloads keeping the load ratios" if at_once
               else "at the end of the flight in progress")
        record_event(self.testdir, "operator", f"{action} from the live page ({client}): stop {how}")
        return Done(action, f"stop requested {how}")

    def _resume(self, client: str) -> Done:
        if not self.can_resume:
            raise Refused(409, "this page is served by the running session; resume a stopped test from "
                               "stand test watch TESTDIR --serve HOST:PORT")
        from endurance.monitors import awaiting_inspection
        from endurance.run import SESSIONS_DIR
        holder = lock_holder(self.testdir)
        if holder is not None:
            raise Refused(409, f"a session runs the test (process {holder.get('pid')} on {holder.get('host')})")
        with Journal.open(self.testdir) as journal:
            if journal.state() == "finished":
                raise Refused(409, f"the test is finished ({journal.flights_done} flights); raise its target "
                                   f"with stand test resume {self.testdir} --flights N")
            waiting = awaiting_inspection(journal)
        if waiting:
            raise Refused(409, f"the trend's alarm on {', '.join(waiting)} stopped the test: say what the "
                               f"inspection found on the command line, stand test resume {self.testdir} "
                               "--inspected (nothing to repair) or --repaired")
        command = resume_command(self.testdir)
        log = self.testdir / SESSIONS_DIR / f"resume-{time.strftime('%Y%m%dT%H%M%S')}.log"
        log.parent.mkdir(exist_ok=True)
        record_event(self.testdir, "operator", f"resume from the live page ({client}): "
                     f"{' '.join(command[2:])}; its output in {log.name}")
        with open(log, "ab") as out:
            proc = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                    start_new_session=True, preexec_fn=self.child_setup)
        return Done("resume", f"resume started (process {proc.pid}; its output in sessions/{log.name})")


def resume_command(testdir: Path) -> list[str]:
    """``stand test resume TESTDIR`` with the gateway options the test was started with."""
    try:
        from endurance.run import TEST_RECORD
        args = json.loads((testdir / TEST_RECORD).read_text()).get("gateway_args", [])
    except (OSError, ValueError):
        args = []
    return [sys.executable, "-m", "stand", "test", "resume", str(testdir.resolve()), *map(str, args)]
