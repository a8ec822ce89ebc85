"""The live page's options of ``stand test start|resume`` and ``stand test watch``, and ``stand test
token`` (endurance.live; docs/endurance.md, the live page). Imported by :mod:`stand.commands.test`;
the web server's modules only when a page is served."""
from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path
from typing import Iterator

from core.errors import ParameterError

DEFAULT_WATCH = "127.0.0.1:8080"


def add_live_options(q: argparse.ArgumentParser, serve_default: str | None = None,
                     can_resume: bool = False) -> None:
    """--serve, --operator-token-file, --allow-host, --tls-cert, --tls-key; ``can_resume``: the
    page outlives the session (``stand test watch``'s), so its operator can resume a stopped test."""
    g = q.add_argument_group("the live page (docs/endurance.md)")
    g.add_argument("--serve", metavar="HOST:PORT", default=serve_default,
                   help="serve the live page on HOST:PORT (PORT alone: 127.0.0.1; 0: any free port; the URL "
                        "is printed); another address than loopback needs --allow-host"
                        + (" (default %(default)s)" if serve_default else ""))
    actions = ("pause, stop, resume" if can_resume else
               "pause, stop; a stopped test is resumed from the page of stand test watch")
    g.add_argument("--operator-token-file", metavar="FILE",
                   help=f"allow the operator's actions ({actions}) to requests with Authorization: Bearer TOKEN, "
                        "the token being this file's one line (stand test token FILE makes one); without it the "
                        "page is read-only")
    g.add_argument("--allow-host", action="append", metavar="NAME", default=None,
                   help="a name the control room uses for this computer (repeatable): a request for any other "
                        "name than these and loopback's is refused; needed to serve beyond loopback")
    g.add_argument("--tls-cert", metavar="CERT.pem", help="serve HTTPS with this certificate (PEM)")
    g.add_argument("--tls-key", metavar="KEY.pem", help="... and its private key (PEM, mode 600)")


def register_watch(tsub) -> None:
    q = tsub.add_parser("watch", help="serve the live page of a test beside it",
                        description="Serve the live page of the test in TESTDIR: the signals of whichever "
                                    "session runs it (the ring it publishes), its status, events and "
                                    "end-point trends (its journal). Runs until interrupted; it outlives "
                                    "the sessions, and with --operator-token-file it can resume the test "
                                    "(stand test resume with the options it was started with).")
    q.add_argument("testdir", metavar="TESTDIR")
    add_live_options(q, DEFAULT_WATCH, can_resume=True)
    q.set_defaults(func=watch_main)

    q = tsub.add_parser("token", help="make an operator's token file for the live page",
                        description="Write a new random token (32 characters) into FILE, readable by you alone "
                                    "(mode 600), for --operator-token-file FILE. An existing file is never "
                                    "overwritten. The operator types the token (cat FILE) into the page.")
    q.add_argument("file", metavar="FILE")
    q.set_defaults(func=token_main)


def check_live_options(args: argparse.Namespace):
    """Every live option checked before anything else happens (no traceback for a mistake);
    the page's :class:`~endurance.live.binding.Binding` and token (None, None without
    ``--serve``)."""
    from endurance.live.binding import Binding
    from endurance.live.operator import read_token_file
    given = [name for name, value in (("--operator-token-file", args.operator_token_file),
                                      ("--allow-host", args.allow_host), ("--tls-cert", args.tls_cert),
                                      ("--tls-key", args.tls_key)) if value]
    if given and not args.serve:
        raise ParameterError(f"{given[0]}: give --serve HOST:PORT too (it is the page's)")
    if not args.serve:
        return None, None
    token = read_token_file(args.operator_token_file) if args.operator_token_file else None
    binding = Binding.check(args.serve, args.allow_host, args.tls_cert, args.tls_key, token=token is not None)
    return binding, token


@contextlib.contextmanager
def live_page(args: argparse.Namespace, testdir: str | Path, kind: str) -> Iterator[None]:
    """Serve the page of ``testdir`` while inside, if ``--serve`` was given: its server in a
    process of its own, started again if it ends (:class:`endurance.live.process.PageProcess`);
    ``kind`` "session" or "watch"."""
    binding, token = check_live_options(args)
    if binding is None:
        yield
        return
    from endurance.live.process import PageProcess
    page = PageProcess(testdir, kind, binding, token, out=sys.stderr)
    url = page.start()
    how = "operator actions with the token" if token else "read-only"
    print(f"live page: {url} ({how})", flush=True)
    exposed = binding.exposure(page.port)
    if exposed:
        print(f"live page: {exposed}", flush=True)
    try:
        yield
    finally:
        page.stop()


def gateway_args(args: argparse.Namespace, add_options) -> list[str]:
    """The gateway options of ``args`` that differ from their defaults, as command-line words
    (``add_options(parser)`` adds them: the ones ``start`` and ``resume`` share), for a resume
    from the live page."""
    parser = argparse.ArgumentParser(add_help=False)
    add_options(parser)
    words: list[str] = []
    for action in parser._actions:
        if not action.option_strings:
            continue
        value = getattr(args, action.dest, action.default)
        if value == action.default:
            continue
        flag = action.option_strings[-1]
        if isinstance(action, argparse._StoreTrueAction):
            words.append(flag)
        elif isinstance(value, list):
            for v in value:
                words += [flag, str(v)]
        else:
            words += [flag, str(value)]
    return words


def watch_main(args: argparse.Namespace) -> int:
    from endurance.journal import Journal
    from stand.commands.common import sigterm_as_interrupt
    check_live_options(args)
    with Journal.open(args.testdir) as journal:          # a clear error if it holds no test
        name = journal.name
    try:
        with sigterm_as_interrupt(), live_page(args, args.testdir, "watch"):
            print(f"watching {name!r} in {args.testdir}; Ctrl-C ends the page (not the test)", flush=True)
            while True:
                time.sleep(1.0)
    except KeyboardInterrupt:
        return 0


def token_main(args: argparse.Namespace) -> int:
    from endurance.live.operator import write_token_file
    path = write_token_file(args.file)
    print(f"wrote a new operator's token to {path} (mode 600): serve with --operator-token-file {path}; "
          f"the operator types the token (cat {path}) into the page")
    return 0
