"""``stand test plan|start|status|stop|resume|report|watch|token``: an endurance test, flight by flight, on a
station (endurance.run; docs/endurance.md)."""
from __future__ import annotations

import argparse
import json
import sys
import time

from core.errors import ParameterError
from standbus.spec import DEFAULT_BUS

from .common import add_gateway, gateway_config, programme_error_limit, sigterm_as_interrupt
from .live_page import add_live_options, check_live_options, gateway_args, live_page, register_watch


def register(sub) -> None:
    p = sub.add_parser("test", help="an endurance test: plan, start, status, stop, resume, report",
                       description="An endurance test of a station (a rig, or a stand as a station of one "
                                   "channel): the flights of a test file (test.toml, docs/endurance.md) "
                                   "flown back to back, the count kept in TESTDIR's journal through stops, "
                                   "kills and resumes.")
    tsub = p.add_subparsers(dest="test_command", metavar="ACTION", required=True)

    q = tsub.add_parser("plan", help="check a test file and print its block, times and storage",
                        description="Check everything before anything moves (the station, the controller, "
                                    "every flight type's levels and feedforward) and print the block, each "
                                    "flight type's time at its rate and at the valve-limited minimum, the "
                                    "test's duration and its storage estimate. Touches no bus.")
    q.add_argument("test_file", metavar="TEST.toml")
    q.add_argument("--command-limit", type=float, default=100.0, metavar="PCT",
                   help="the valves' command limit the times are computed at (default %(default)s)")
    q.add_argument("--json", action="store_true", help="print the plan as JSON")
    q.set_defaults(func=plan_main)

    q = tsub.add_parser("start", help="start a test in a new directory and run it",
                        description="Create TESTDIR (its journal, locked while a session runs) and fly the "
                                    "test's flights back to back until the target, an inspection, a stop "
                                    "(stand test stop TESTDIR) or a fault.")
    q.add_argument("test_file", metavar="TEST.toml")
    q.add_argument("--out", required=True, metavar="TESTDIR", help="the test's directory (must not hold a test)")
    q.add_argument("--flights", type=int, metavar="N", help="the target instead of the test file's")
    _gateway_options(q)
    add_live_options(q)
    q.set_defaults(func=start_main)

    q = tsub.add_parser("resume", help="take a stopped or interrupted test up again",
                        description="Take the test in TESTDIR up where its journal says (the load case "
                                    "before the interrupted one, approached along the ratio-keeping line "
                                    "from the forces found), refused if the test file changed since the "
                                    "start (naming what), or if the trend's alarm stopped it and the "
                                    "operator has not said what the inspection found (--inspected or "
                                    "--repaired).")
    q.add_argument("testdir", metavar="TESTDIR")
    q.add_argument("--test", metavar="TEST.toml", dest="test_file",
                   help="the test file, if it moved since the start (default: the one it was started from)")
    q.add_argument("--flights", type=int, metavar="N", help="a new target (at least the flights done)")
    found = q.add_mutually_exclusive_group()
    found.add_argument("--inspected", dest="found", action="store_const", const="inspected",
                       help="after the trend's alarm: inspected, nothing to repair (the alarmed channels are "
                            "watched again against their baselines)")
    found.add_argument("--repaired", dest="found", action="store_const", const="repaired",
                       help="after a repair (an alarm's or an inspection's): the structure is a new one, every "
                            "flight type's baseline is learnt again")
    _gateway_options(q)
    add_live_options(q)
    q.set_defaults(func=resume_main)

    q = tsub.add_parser("status", help="the test's state, count, position, pace and latest events",
                        description="Read TESTDIR's journal, while the test runs or after, and print its "
                                    "state (running, stopped, interrupted: its process died, or "
                                    "finished) and why, the flights done of the target, the flight and "
                                    "load case in progress or next, the pace over the last hour and the "
                                    "time to the target, and the latest events. --json prints the same "
                                    "object the live page serves as /status.json "
                                    "(docs/reference/test-status-json.md). Touches no bus.")
    q.add_argument("testdir", metavar="TESTDIR")
    q.add_argument("--events", type=int, default=10, metavar="N", help="the latest N events (default %(default)s)")
    q.add_argument("--json", action="store_true", help="print the status as JSON")
    q.set_defaults(func=status_main)

    q = tsub.add_parser("stop", help="stop the running test: at the end of the flight, or at once",
                        description="Ask the session running TESTDIR to stop at the end of the flight in "
                                    "progress (the valves then hold at the ground level), or with --at-once "
                                    "now, every channel unloading keeping the load ratios; waits until it "
                                    "has stopped.")
    q.add_argument("testdir", metavar="TESTDIR")
    q.add_argument("--at-once", action="store_true",
                   help="stop now: every channel unloads keeping the load ratios, then holds")
    q.add_argument("--no-wait", action="store_true", help="ask and return at once")
    q.add_argument("--timeout", type=float, default=600.0, metavar="S",
                   help="how long to wait for the stop (default %(default)s)")
    q.set_defaults(func=stop_main)

    q = tsub.add_parser("report", help="what the test has done: sessions, stops, end points' accuracy",
                        description="Summarise TESTDIR: every session (how it began and ended, the time "
                                    "from a resume to loading again), the stops and interruptions, and "
                                    "the end points' accuracy (every peak and valley of every channel, "
                                    "% of its range) over the whole test and over the last complete "
                                    "block. --json: schema hydrostand-test-report/1. Touches no bus.")
    q.add_argument("testdir", metavar="TESTDIR")
    q.add_argument("--json", action="store_true", help="print the report as JSON")
    q.set_defaults(func=report_main)

    register_watch(tsub)


def _gateway_options(q: argparse.ArgumentParser) -> None:
    add_gateway(q, programme_error_limit("each channel's largest range over the flight types"))
    q.add_argument("--fault-action", choices=("hold", "unload"), default="hold",
                   help="a rig: what a channel's communication or valve fault does to the others: hold "
                        "every channel, or unload them keeping the load ratios (default %(default)s)")
    q.add_argument("--no-progress", action="store_true", help="no line per flight")


def _config(args: argparse.Namespace, test):
    """The gateway's configuration for the test's station: a rig's buses and limits are its
    file's, a stand's limit and period the test file's."""
    from endurance.run import station_config
    st = test.station
    if args.force_limit is not None:
        raise ParameterError("--force-limit: the test file sets the station's force limits (a rig file's "
                             "force_limit_kgf, a stand's [stand] force_limit_kgf); leave it out")
    if st.kind == "rig":
        if args.bus != DEFAULT_BUS:
            raise ParameterError(f"--bus: the rig's buses are its file's ({st.path}); leave --bus out")
        args.rig = str(st.path)
    else:
        args.rig = None
        if args.period_ms is not None and abs(args.period_ms / 1e3 - st.period_s) > 1e-9:
            raise ParameterError(f"--period-ms {args.period_ms:g}: the stand runs at {st.period_s * 1e3:g} ms "
                                 "([stand] period_ms in the test file); leave --period-ms out")
    return station_config(test, gateway_config(args))


def _on_flight(args):
    if args.no_progress:
        return None

    def show(end, line: str) -> None:
        print(line, flush=True)
    return show


def _flights(args) -> int | None:
    if args.flights is not None and args.flights < 1:
        raise ParameterError(f"--flights {args.flights}: give a whole number >= 1")
    return args.flights


def _finish(result) -> int:
    print(result.text())
    print(f"-> {result.testdir} (stand test status|report {result.testdir})")
    tripped = result.status == "stopped" and result.end_reason not in (None, "operator_stop")
    return 1 if tripped or result.status == "aborted" else 0


def plan_main(args: argparse.Namespace) -> int:
    from endurance.report import plan
    from endurance.testfile import load_test_file
    from gateway.config import GatewayConfig
    from gateway.limits import SafetyLimits
    test = load_test_file(args.test_file)
    config = GatewayConfig(period_s=test.station.period_s, rig=test.station.rig,
                           limits=SafetyLimits(command_limit_pct=args.command_limit))
    p = plan(test, config)
    if args.json:
        json.dump(p.to_dict(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(p.text())
    return 0


def start_main(args: argparse.Namespace) -> int:
    from endurance.live.feed import LiveFeed
    from endurance.run import start
    from endurance.testfile import load_test_file
    started = time.time()
    flights = _flights(args)
    check_live_options(args)
    test = load_test_file(args.test_file)
    config = _config(args, test)
    feed = LiveFeed()
    with sigterm_as_interrupt(), live_page(args, args.out, "session"):
        result = start(test, args.out, config, flights, on_flight=_on_flight(args), started_at=started,
                       publisher=feed, gateway_args=gateway_args(args, _gateway_options))
    return _finish(result)


def resume_main(args: argparse.Namespace) -> int:
    from endurance.live.feed import LiveFeed
    from endurance.run import resume, test_file_of
    from endurance.testfile import load_test_file
    from pathlib import Path
    started = time.time()
    flights = _flights(args)
    check_live_options(args)
    test = load_test_file(args.test_file or test_file_of(Path(args.testdir)))
    config = _config(args, test)
    feed = LiveFeed()
    with sigterm_as_interrupt(), live_page(args, args.testdir, "session"):
        result = resume(args.testdir, config, test, flights, on_flight=_on_flight(args), started_at=started,
                        publisher=feed, found=args.found)
    return _finish(result)


def status_main(args: argparse.Namespace) -> int:
    from endurance.report import status_json, status_of, status_text
    s = status_of(args.testdir, args.events)
    if args.json:
        sys.stdout.write(status_json(s))
    else:
        print(status_text(s))
    return 0


def stop_main(args: argparse.Namespace) -> int:
    from endurance.journal import Journal, lock_holder
    from endurance.run import request_stop
    holder = request_stop(args.testdir, args.at_once)
    how = "at once (every channel unloads keeping the load ratios)" if args.at_once else \
        "at the end of the flight in progress"
    print(f"stop requested {how} of process {holder.get('pid')} on {holder.get('host')}", flush=True)
    if args.no_wait:
        return 0
    deadline = time.monotonic() + args.timeout
    while lock_holder(args.testdir) is not None:
        if time.monotonic() > deadline:
            print(f"stand test: the test did not stop within {args.timeout:g} s; it is still running",
                  file=sys.stderr)
            return 1
        time.sleep(0.2)
    with Journal.open(args.testdir) as journal:
        s = journal.status(events=0)
    print(f"{s['state']}" + (f" ({s['reason']})" if s.get("reason") else "")
          + f"; flights {s['flights_done']} of {s['flights_target']}")
    return 0


def report_main(args: argparse.Namespace) -> int:
    from endurance.report import report, report_text
    r = report(args.testdir)
    if args.json:
        json.dump(r, sys.stdout, indent=2, default=str)
        sys.stdout.write("\n")
    else:
        print(report_text(r))
    return 0
