"""The operator's actions from the live page: who may act, and what an action does.

* The **token**: ``--operator-token-file FILE`` (:func:`read_token_file`): one line of at least
  :data:`MIN_TOKEN_CHARS` characters, in a file no one but its owner can read (as ssh asks of a
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

Every action taken and every one refused is an event in the journal (``operator``,
``refused``; :func:`endurance.inbox.record_event`); refusals at most :data:`REFUSALS_PER_MINUTE`
a minute (a flood of bad requests cannot fill the journal; the next one logged says how many
were left out).
"""
from __future__ import annotations

import hmac
import json
import stat
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from core.errors import ParameterError, StandError
from endurance.inbox import record_event
from endurance.journal import Journal, lock_holder
from endurance.monitors import awaiting_inspection
from endurance.run import TEST_RECORD, SESSIONS_DIR, request_stop

MIN_TOKEN_CHARS = 16
ACTIONS = ("pause", "stop", "resume")
REFUSALS_PER_MINUTE = 10


def read_token_file(path: str | Path) -> str:
    """The operator's token from ``path`` (module docstring); a clear error for a file that
    is missing, empty, too short or readable by others."""
    path = Path(path)
    hint = ("e.g. python3 -c 'import secrets; print(secrets.token_urlsafe(24))' > FILE; "
            "chmod 600 FILE")
    try:
        mode = path.stat().st_mode
        text = path.read_text()
    except FileNotFoundError:
        raise ParameterError(f"--operator-token-file {path}: no such file; write a token into it ({hint})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ParameterError(f"--operator-token-file {path}: cannot read it ({exc})") from None
    if not stat.S_ISREG(mode):
        raise ParameterError(f"--operator-token-file {path}: not a file")
    if mode & 0o077:
        raise ParameterError(f"--operator-token-file {path}: others may read it (mode {stat.S_IMODE(mode):04o}); "
                             f"chmod 600 {path}")
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    if not lines:
        raise ParameterError(f"--operator-token-file {path}: it is empty; write a token into it ({hint})")
    if len(lines) > 1:
        raise ParameterError(f"--operator-token-file {path}: give one line (the token), not {len(lines)}")
    token = lines[0]
    if len(token) < MIN_TOKEN_CHARS or any(c.isspace() for c in token):
        raise ParameterError(f"--operator-token-file {path}: the token must be at least {MIN_TOKEN_CHARS} "
                             f"characters without spaces ({hint})")
    return token


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


class Operator:
    """The actions on the test in ``testdir`` (module docstring); ``token`` None: read-only.
    ``can_resume``: False where the page is served by the running session itself (it ends with
    it: a resume is for ``stand test watch``)."""

    def __init__(self, testdir: str | Path, token: str | None, can_resume: bool = True) -> None:
        self.testdir = Path(testdir)
        self._token = token.encode() if token else None
        self.can_resume = can_resume
        self._refusals: list[float] = []
        self._left_out = 0

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

    def log_refusal(self, what: str, why: str, client: str) -> None:
        """A refused request as a ``refused`` event (rate-limited: module docstring)."""
        now = time.monotonic()
        self._refusals = [t for t in self._refusals if now - t < 60.0]
        if len(self._refusals) >= REFUSALS_PER_MINUTE:
            self._left_out += 1
            return
        self._refusals.append(now)
        more = f" ({self._left_out} more refused before it not logged)" if self._left_out else ""
        self._left_out = 0
        record_event(self.testdir, "refused", f"{what} from {client} refused: {why}{more}")

    # -- the actions -----------------------------------------------------------------------------------
    def act(self, action: str, client: str) -> Done:
        """Take ``action`` (authorized already); :class:`Refused` when it cannot be taken now."""
        if action == "resume":
            return self._resume(client)
        at_once = action == "stop"
        try:
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
                                    start_new_session=True)
        return Done("resume", f"resume started (process {proc.pid}; its output in sessions/{log.name})")


def resume_command(testdir: Path) -> list[str]:
    """``stand test resume TESTDIR`` with the gateway options the test was started with."""
    try:
        args = json.loads((testdir / TEST_RECORD).read_text()).get("gateway_args", [])
    except (OSError, ValueError):
        args = []
    return [sys.executable, "-m", "stand", "test", "resume", str(testdir.resolve()), *map(str, args)]
