"""The live page's options of ``stand test start|resume`` and ``stand test watch`` (endurance.live;
docs/endurance.md, the live page). Imported by :mod:`stand.commands.test`; the web server's
modules only when a page is served."""
from __future__ import annotations

import argparse
import contextlib
import time
from pathlib import Path
from typing import Iterator

from core.errors import ParameterError

DEFAULT_WATCH = "127.0.0.1:8080"


def add_live_options(q: argparse.ArgumentParser, serve_default: str | None = None,
                     can_resume: bool = False) -> None:
    """--serve and --operator-token-file; ``can_resume``: the page outlives the session (``stand
    test watch``'s), so its operator can resume a stopped test."""
    g = q.add_argument_group("the live page (docs/endurance.md)")
    g.add_argument("--serve", metavar="HOST:PORT", default=serve_default,
                   help="serve the live page on HOST:PORT (PORT alone: 127.0.0.1; 0: any free port; the URL "
                        "is printed)" + (" (default %(default)s)" if serve_default else ""))
    actions = ("pause, stop, resume" if can_resume else
               "pause, stop; a stopped test is resumed from the page of stand test watch")
    g.add_argument("--operator-token-file", metavar="FILE",
                   help=f"allow the operator's actions ({actions}) to requests with "
                        "Authorization: Bearer TOKEN, the token being this file's one line (mode 600); "
                        "without it the page is read-only")


def register_watch(tsub) -> None:
    q = tsub.add_parser("watch", help="serve the live page of a test beside it",
                        description="Serve the live page of the test in TESTDIR: the signals of whichever "
                                    "session runs it (the stream it publishes), its status, events and "
                                    "end-point trends (its journal). Runs until interrupted; it outlives "
                                    "the sessions, and with --operator-token-file it can resume the test "
                                    "(stand test resume with the options it was started with).")
    q.add_argument("testdir", metavar="TESTDIR")
    add_live_options(q, DEFAULT_WATCH, can_resume=True)
    q.set_defaults(func=watch_main)


def check_live_options(args: argparse.Namespace) -> None:
    """Every live option checked before anything else happens (no traceback for a mistake)."""
    from endurance.live.operator import read_token_file
    from endurance.live.server import serve_address
    if args.operator_token_file and not args.serve:
        raise ParameterError("--operator-token-file: give --serve HOST:PORT too (the token is the page's)")
    if args.serve:
        serve_address(args.serve)
    if args.operator_token_file:
        read_token_file(args.operator_token_file)


@contextlib.contextmanager
def live_page(args: argparse.Namespace, testdir: str | Path, source, kind: str) -> Iterator[None]:
    """Serve the page of ``testdir`` while inside, if ``--serve`` was given; ``source`` the
    signals' (:class:`endurance.live.feed.LiveFeed` or ``FeedClient``); ``kind`` "session" or
    "watch"."""
    if not args.serve:
        yield
        return
    from endurance.live.operator import Operator, read_token_file
    from endurance.live.server import LiveServer, serve_address
    token = read_token_file(args.operator_token_file) if args.operator_token_file else None
    operator = Operator(testdir, token, can_resume=kind == "watch")
    server = LiveServer(serve_address(args.serve), testdir, source, operator, kind)
    url = server.start()
    how = "operator actions with the token" if token else "read-only"
    print(f"live page: {url} ({how})", flush=True)
    try:
        yield
    finally:
        server.stop()


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
    from endurance.live.feed import FeedClient
    from stand.commands.common import sigterm_as_interrupt
    check_live_options(args)
    with Journal.open(args.testdir) as journal:          # a clear error if it holds no test
        name = journal.name
    client = FeedClient(args.testdir).start()
    try:
        with sigterm_as_interrupt(), live_page(args, args.testdir, client, "watch"):
            print(f"watching {name!r} in {args.testdir}; Ctrl-C ends the page (not the test)", flush=True)
            while True:
                time.sleep(1.0)
    except KeyboardInterrupt:
        return 0
    finally:
        client.close()
