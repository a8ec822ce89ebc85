"""The crash test's child: writes an endurance journal load case by load case in a tight loop
until it is killed (``python -m tests.support.journal_writer TESTDIR``).

It creates the journal or opens it for writing (after a kill: the interruption), prints
``resume FLIGHT ATTEMPT LOAD_CASE`` (the position it continues from) and then, for every load
case it commits, appends ``FLIGHT ATTEMPT INDEX`` to ``TESTDIR/acks.log`` once the commit has
returned (a write(2) the kernel keeps when the process is killed). Flight n has
``3 + n % 5`` load cases; a flight caught in progress continues at its next load case, or with
``--rerun`` runs again from its first (a new attempt). With ``--storage`` every flight
that finished is exported to the turning-point log and each finished block compacted
(blocks of 7 flights), so kills land in Parquet writes too.
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path

from endurance.journal import EndPoint, Journal

CHANNELS = ["root", "inner", "outer", "tip"]
BLOCK = 7


def load_cases_of(flight: int) -> int:
    return 3 + flight % 5


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("testdir")
    ap.add_argument("--storage", action="store_true")
    ap.add_argument("--rerun", action="store_true")
    args = ap.parse_args()
    testdir = Path(args.testdir)
    if (testdir / "journal.sqlite").exists():
        journal = Journal.open(testdir, write=True)
    else:
        journal = Journal.create(testdir, "crash test", 10 ** 9, CHANNELS, "fingerprint")
    log = None
    if args.storage:
        from endurance.storage import TurningPointLog
        log = TurningPointLog(testdir, flights_per_block=BLOCK)
        log.export(journal)
    journal.start()
    pos = journal.position()
    print(f"resume {pos.flight} {pos.attempt} {pos.load_case}", flush=True)
    acks = os.open(testdir / "acks.log", os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    n, start = pos.flight, pos.load_case
    attempt = pos.attempt
    if attempt is not None and args.rerun:
        attempt, start = None, 0                 # this one runs again from its first load case
    while True:
        m = load_cases_of(n)
        if attempt is None:
            attempt = journal.begin_flight(n, "AB"[n % 2], (n - 1) // BLOCK + 1, (n - 1) % BLOCK + 1, m)
        for k in range(start, m):
            points = [EndPoint(c, 1000.0 * (i + 1) + k, 1000.0 * (i + 1) + k + 0.5, 10.0 + i)
                      for i, c in enumerate(CHANNELS)]
            journal.commit_load_case(n, k, points)
            os.write(acks, f"{n} {attempt} {k}\n".encode())
        journal.finish_flight(n, compensation={"root": f"# after flight {n}\n"} if n % 4 == 0 else None)
        if log is not None:
            log.export(journal)
        n, start, attempt = n + 1, 0, None


if __name__ == "__main__":
    main()
