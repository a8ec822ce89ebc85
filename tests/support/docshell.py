"""Running a page's blocks as a reader would: one directory, one private bus namespace.

A page is the unit: its blocks run in order in a fresh directory holding a copy of the
repository's ``examples/`` (and ``.venv`` linked, for ``.venv/bin/stand``), so a workflow spread
over several blocks (identify, diagnose, design, load) works as on the page. ``stand`` is the
checkout's. Every command is a ``bash -c`` of its own in that directory; a command ending in
``&`` starts a background process (its own process group, its output in ``.docs-test/``) that
runs until the block ends and is then stopped (SIGINT, SIGTERM, SIGKILL, by its group's id): a
block that needs the emulator a block above started says so (``run: stand emulate ... &``).
The runner waits for a background process's first line (``stand emulate``'s ready line) before
the next command, as a reader would.

Every udp_loopback bus the commands open is private: the page runs in its own
``HYDROSTAND_LOOPBACK_NAMESPACE`` (standbus/loopback.py), so ``udp_loopback:stand0``, the
default the docs show, and a rig file's ``udp_loopback:rig-can0`` are this page's buses only,
with the text of the commands and of what they print as the reader sees it. Nothing else is
opened: blocks that need vcan or a bench are marked ``skip``.
"""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: a command's own time limit (a stuck command fails its block, with its output)
COMMAND_TIMEOUT_S = 600.0
#: how long the runner waits for a background process's first line
READY_TIMEOUT_S = 30.0


class CommandFailed(AssertionError):
    """A documented command exited with an error (or did not end in time)."""


@dataclass
class Background:
    """A process a block started with ``&``."""

    command: str
    proc: subprocess.Popen
    log: Path

    def tail(self, lines: int = 15) -> str:
        text = self.log.read_text(errors="replace") if self.log.exists() else ""
        return "\n".join(text.splitlines()[-lines:])


@dataclass
class PageRun:
    """The directory, environment and background processes of one page's run."""

    page: str
    directory: Path
    env: dict[str, str] = field(default_factory=dict)
    background: list[Background] = field(default_factory=list)

    @classmethod
    def start(cls, page: str, directory: Path) -> "PageRun":
        directory.mkdir(parents=True, exist_ok=True)
        shutil.copytree(ROOT / "examples", directory / "examples")
        venv = Path(sys.executable).parent.parent
        (directory / ".venv").symlink_to(venv, target_is_directory=True)
        (directory / ".docs-test").mkdir()
        tag = re.sub(r"[^\w]+", "-", page).strip("-")
        env = dict(os.environ,
                   PATH=f"{venv / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
                   HYDROSTAND_LOOPBACK_NAMESPACE=f"docs-{os.getpid()}-{tag}-{uuid.uuid4().hex[:6]}",
                   MPLBACKEND="Agg", PYTHONUNBUFFERED="1")
        return cls(page, directory, env)

    def given(self, name: str, source: str) -> None:
        """Put the repository's ``source`` in the page's directory as ``name``."""
        target = self.directory / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / source, target)

    def write(self, name: str, text: str) -> None:
        target = self.directory / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(text + "\n")

    def run(self, command: str, where: str) -> str:
        """Run one documented command; its output (stdout and stderr) when it succeeds."""
        body, background = _split_background(command)
        if background:
            self._start_background(body, where)
            return ""
        proc = subprocess.Popen(["bash", "-c", body], cwd=self.directory, env=self.env,
                                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, errors="replace",
                                start_new_session=True)
        try:
            output, _ = proc.communicate(timeout=COMMAND_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            _signal_group(proc.pid, signal.SIGKILL)
            output, _ = proc.communicate()
            raise CommandFailed(f"{where}: `{command}` did not end in {COMMAND_TIMEOUT_S:g} s:\n"
                                f"{_tail(output)}{self._background_logs()}") from None
        finally:
            _signal_group(proc.pid, signal.SIGTERM)     # anything it left behind
        if proc.returncode != 0:
            raise CommandFailed(f"{where}: `{command}` exited with {proc.returncode}:\n"
                                f"{_tail(output)}{self._background_logs()}")
        return output

    def _start_background(self, command: str, where: str) -> None:
        log = self.directory / ".docs-test" / f"background-{len(self.background) + 1}.log"
        with log.open("w") as out:
            proc = subprocess.Popen(["bash", "-c", command], cwd=self.directory,
                                    env=self.env, stdin=subprocess.DEVNULL, stdout=out,
                                    stderr=subprocess.STDOUT, start_new_session=True)
        started = Background(command, proc, log)
        self.background.append(started)
        deadline = time.monotonic() + READY_TIMEOUT_S
        while time.monotonic() < deadline and proc.poll() is None and not log.read_text().strip():
            time.sleep(0.05)
        if proc.poll() is not None:
            raise CommandFailed(f"{where}: `{command} &` exited with {proc.returncode} at once:\n"
                                f"{started.tail()}")

    def _background_logs(self) -> str:
        return "".join(f"\n--- background `{b.command} &` (exit {b.proc.poll()}), its last lines:\n"
                       f"{b.tail()}" for b in self.background)

    def stop(self) -> None:
        """Stop every background process started so far, gently first (by process group id)."""
        for sig, wait_s in ((signal.SIGINT, 5.0), (signal.SIGTERM, 3.0), (signal.SIGKILL, 3.0)):
            alive = [b for b in self.background if b.proc.poll() is None]
            for b in alive:
                _signal_group(b.proc.pid, sig)
            deadline = time.monotonic() + wait_s
            while alive and time.monotonic() < deadline:
                alive = [b for b in alive if b.proc.poll() is None]
                time.sleep(0.05)
        self.background.clear()


def _split_background(command: str) -> tuple[str, bool]:
    """The command without a trailing comment and ``&``, and whether it had the ``&``."""
    body = re.sub(r"\s+#[^'\"]*$", "", command).rstrip()
    if body.endswith("&") and not body.endswith("&&"):
        return body[:-1].rstrip(), True
    return body, False


def _signal_group(pgid: int, sig: signal.Signals) -> None:
    """Signal the process group a command of ours leads (its id is the command's pid)."""
    try:
        os.killpg(pgid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def _tail(text: str, lines: int = 40) -> str:
    kept = text.splitlines()
    return "\n".join((["..."] if len(kept) > lines else []) + kept[-lines:])
