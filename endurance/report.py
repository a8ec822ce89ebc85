r"""What ``stand test plan``, ``status`` and ``report`` print: a test before it runs, while it
runs, and what it has done.

* :func:`plan`: every flight type's time at its rate beside its valve-limited minimum
  (:mod:`loading.minimum_time`), the block, the time per flight and the test's duration, and
  the storage estimate (:func:`endurance.storage.storage_estimate`); the flights' checks are
  :func:`endurance.run.check_test`'s. Flights are flown back to back (the next one's lead-in is
  the landing of the one before), so a flight's time is its programme's.
* :func:`status_text`: ``Journal.status()`` in a few lines.
* :func:`report`: the sessions (how each began and ended, the time from a resume to loading
  again), the stops and interruptions, and the end points' accuracy from the turning-point log
  (every peak and valley of every channel, % of the channel's range in its flight's programme),
  over the whole test and over the last complete block.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from core.errors import DataError, StandError

from .journal import JOURNAL_FILE, Journal
from .storage import read_turning_points, storage_estimate

SCHEMA = "hydrostand-test-report/1"


# -- plan --------------------------------------------------------------------------------------------
@dataclass
class FlightTypePlan:
    name: str
    per_block: int
    load_cases: int
    time_s: float          #: at its rate
    minimum_s: float       #: valve-limited


@dataclass
class Plan:
    name: str
    channels: list[str]
    types: list[FlightTypePlan]
    block_size: int
    flights: int
    storage: Any

    @property
    def per_flight_s(self) -> float:
        return sum(t.per_block * t.time_s for t in self.types) / self.block_size

    @property
    def per_flight_minimum_s(self) -> float:
        return sum(t.per_block * t.minimum_s for t in self.types) / self.block_size

    def to_dict(self) -> dict:
        return {"name": self.name, "channels": self.channels, "block_size": self.block_size,
                "flights": self.flights,
                "flight_types": [vars(t) for t in self.types],
                "per_flight_s": self.per_flight_s, "per_flight_minimum_s": self.per_flight_minimum_s,
                "duration_s": self.per_flight_s * self.flights,
                "minimum_duration_s": self.per_flight_minimum_s * self.flights,
                "storage_bytes": {"per_1000_flights": self.storage.per_1000_flights,
                                  "rolling_window": self.storage.rolling_window,
                                  "event_window": self.storage.event_window, "total": self.storage.total}}

    def text(self) -> str:
        lines = [f"test {self.name!r}: {self.flights:,} flights on {len(self.channels)} channel(s) "
                 f"({', '.join(self.channels)}); checked: every level within its channel's force limit, "
                 "every valve's feedforward within 90 % of its command limit",
                 f"block of {self.block_size} flights:",
                 "  type  per block  load cases    time s  minimum s  (valve-limited)"]
        for t in self.types:
            lines.append(f"  {t.name:<4}  {t.per_block:9d}  {t.load_cases:10d}  {t.time_s:8.2f}  "
                         f"{t.minimum_s:9.2f}  ({t.time_s / t.minimum_s:.2f}x)")
        d = self.to_dict()
        lines += [f"per flight: {self.per_flight_s:.2f} s at the chosen rates, {self.per_flight_minimum_s:.2f} s "
                  "at the valve-limited minimum (flights back to back: no approach or unload between them)",
                  f"the test: {_duration(d['duration_s'])} of loading ({_duration(d['minimum_duration_s'])} at "
                  "the minimum), stops and inspections not counted",
                  self.storage.text()]
        return "\n".join(lines)


def plan(test, config) -> Plan:
    """The test's plan (module docstring); ``config`` the gateway's for its station (the
    command limit)."""
    from loading.minimum_time import programme_timing

    from .run import check_test
    check_test(test, config)
    limit = min(test.controller.command_limit_pct, config.limits.command_limit_pct)
    types = []
    for name, ft in test.flight_types.items():
        timing = programme_timing(ft.programme, test.controller.model, limit)
        types.append(FlightTypePlan(name, int(test.block.counts[name]), ft.load_cases,
                                    float(timing.programme_time_s), float(timing.minimum_time_s)))
    flight_s = sum(t.per_block * t.time_s for t in types) / test.block.size
    return Plan(test.name, list(test.station.names), types, test.block.size, test.flights,
                storage_estimate(test, flight_s=flight_s))


def _duration(s: float) -> str:
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.1f} min"
    if s < 3 * 86400:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:.1f} days"


# -- status ------------------------------------------------------------------------------------------
def status(journal: Journal, events: int = 10) -> dict:
    """:meth:`Journal.status`, the next flight's type, block and position filled in from the
    test file the journal keeps when that flight is not begun yet (the journal knows a flight
    once begun; the sequence is the block's)."""
    import tomllib

    from .spectrum import Block, FlightSequence
    s = journal.status(events=events)
    f = s.get("flight")
    if f and f.get("type") is None:
        try:
            block = tomllib.loads(journal.test_file or "")["block"]
            slot = FlightSequence(Block(block["flights"], block.get("seed", 0))).slot(f["number"])
            f.update(type=slot.flight_type, block=slot.block, position=slot.position)
        except (tomllib.TOMLDecodeError, KeyError, TypeError, ValueError, StandError):
            pass
    return s


def status_of(testdir: str | Path, events: int = 10) -> dict:
    """:func:`status` of the test in ``testdir``: what ``stand test status --json`` prints
    (:func:`status_json`) and the live page's ``/status.json``."""
    with Journal.open(testdir) as journal:
        return status(journal, events)


def status_json(s: dict) -> str:
    """A status as ``stand test status --json`` prints it."""
    return json.dumps(s, indent=2) + "\n"


def status_text(s: dict) -> str:
    """:meth:`Journal.status` in a few lines."""
    lines = [f"{s['name']}: {s['state']}" + (f" ({s['reason']})" if s.get("reason") else ""),
             f"flights {s['flights_done']:,} of {s['flights_target']:,}"]
    f = s.get("flight")
    if f:
        lines[-1] += (f"; {'in progress' if f.get('attempt') else 'next'}: flight {f['number']} "
                      f"(type {f['type']}, block {f['block']}, position {f['position']}), load case "
                      f"{s['load_case']}")
    if s.get("pace_flights_per_h"):
        eta = s.get("eta_s")
        lines.append(f"pace {s['pace_flights_per_h']:.0f} flights/h"
                     + (f", {_duration(eta)} to the target" if eta else ""))
    holder = s.get("holder")
    if holder:
        lines.append(f"run by process {holder.get('pid')} on {holder.get('host')}")
    if s.get("events"):
        lines.append("latest events:")
        for e in s["events"]:
            lines.append(f"  {time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(e['time']))}  {e['kind']:<14}"
                         + (f" [{e['channel']}]" if e.get("channel") else "") + f" {e['message']}")
    return "\n".join(lines)


# -- the end points' accuracy ------------------------------------------------------------------------------
def end_point_errors(table: pa.Table) -> dict[str, np.ndarray]:
    """Every peak and valley of the turning-point log (``table``: its columns flight, block,
    attempt, load_case, channel, level_kgf, reached_kgf): per row its flight, block, channel
    and error as % of the channel's range in its flight (the range of the flight's levels),
    and its flight_type and flow_pct where the table has them. A load case is a peak (valley)
    of a channel where its level is above (below) the ones before and after it in the flight."""
    extra = [c for c in ("flight_type", "flow_pct") if c in table.column_names]
    if table.num_rows == 0:
        return {k: np.array([]) for k in ("flight", "block", "channel", "error_pct", *extra)}
    cols = {c: table.column(c).to_numpy(zero_copy_only=False) for c in
            ("flight", "block", "attempt", "load_case", "channel", "level_kgf", "reached_kgf", *extra)}
    order = np.lexsort((cols["load_case"], cols["attempt"], cols["flight"], cols["channel"]))
    c = {k: v[order] for k, v in cols.items()}
    channel = c["channel"].astype(str)
    group = np.r_[True, (c["flight"][1:] != c["flight"][:-1]) | (c["attempt"][1:] != c["attempt"][:-1])
                  | (channel[1:] != channel[:-1])]
    starts = np.flatnonzero(group)
    gid = np.cumsum(group) - 1
    lv = c["level_kgf"]
    rng = (np.maximum.reduceat(lv, starts) - np.minimum.reduceat(lv, starts))[gid]
    prev_same = np.r_[False, ~group[1:]]
    next_same = np.r_[~group[1:], False]
    before = np.r_[np.nan, lv[:-1]]
    after = np.r_[lv[1:], np.nan]
    inner = prev_same & next_same
    peak = inner & (lv > before) & (lv > after)
    valley = inner & (lv < before) & (lv < after)
    keep = peak | valley
    err = 100 * (c["reached_kgf"] - lv) / np.maximum(rng, 1e-9)
    return {"flight": c["flight"][keep], "block": c["block"][keep], "channel": channel[keep],
            "error_pct": err[keep], **{k: c[k][keep] for k in extra}}


def accuracy(errors: dict[str, np.ndarray], mask: np.ndarray | None = None) -> dict[str, dict]:
    """Per channel the p95 and max of |error| (% of range) and the number of peaks and valleys."""
    out = {}
    ch = errors["channel"] if mask is None else errors["channel"][mask]
    e = np.abs(errors["error_pct"] if mask is None else errors["error_pct"][mask])
    for name in sorted(set(ch.tolist())):
        x = e[ch == name]
        out[name] = {"p95": float(np.percentile(x, 95)), "max": float(x.max()), "points": int(len(x))}
    return out


def test_end_points(testdir: Path, journal: Journal, first_flight: int = 1) -> pa.Table:
    """The turning-point log with the journal's end points it does not hold yet (a live or
    interrupted test), done flights only; from ``first_flight`` on."""
    import pyarrow.dataset as ds

    from .storage import _turning_point_table
    table = read_turning_points(testdir, filter=ds.field("flight") >= first_flight if first_flight > 1 else None)
    last = int(pc.max(table.column("flight")).as_py() or 0) if table.num_rows else first_flight - 1
    done = journal.flights_done
    if done > last:
        extra = _turning_point_table(journal.end_points(last + 1, done))
        table = pa.concat_tables([table, extra]) if table.num_rows else extra
    return table


def report(testdir: str | Path) -> dict:
    """What the test has done (module docstring), as a dict (schema :data:`SCHEMA`)."""
    testdir = Path(testdir)
    with Journal.open(testdir) as journal:
        status = journal.status(events=0)
        events = journal.events()
        table = test_end_points(testdir, journal)
        block_size = _block_size(journal)
    sessions = session_records(testdir)
    for i, s in enumerate(sessions):        # begun at loading, never completed: killed (or running)
        if "ended_at" not in s and not (status["state"] == "running" and i == len(sessions) - 1):
            s.update(state="killed", reason="the process died; its record is what it wrote when it loaded")
    errors = end_point_errors(table)
    done = status["flights_done"]
    last_block = None
    if block_size and done >= block_size:
        b = done // block_size
        last_block = {"block": b, "flights": [(b - 1) * block_size + 1, b * block_size],
                      "accuracy": accuracy(errors, errors["block"] == b)}
    kinds = {}
    for e in events:
        kinds[e["kind"]] = kinds.get(e["kind"], 0) + 1
    return {"schema": SCHEMA, "name": status["name"], "state": status["state"], "reason": status["reason"],
            "flights_done": done, "flights_target": status["flights_target"],
            "end_points": int(table.num_rows), "accuracy": accuracy(errors), "last_block": last_block,
            "sessions": [{k: s.get(k) for k in ("kind", "first_flight", "flights_flown", "status", "end_reason",
                                                 "state", "reason", "loading", "unload", "started_at", "ended_at")}
                         for s in sessions],
            "interruptions": kinds.get("interrupted", 0), "stops": kinds.get("stopped", 0),
            "events": events}


# -- what the stops did to the ratios --------------------------------------------------------------------
def ratio_deviation_pct(Y: np.ndarray, y0: np.ndarray, ranges_kgf) -> float:
    """The largest deviation of the forces ``Y`` (K, N) from the load ratios of ``y0`` (each
    row's nearest multiple of ``y0``, safety.md's σ), % of each channel's range."""
    Y, y0 = np.atleast_2d(np.asarray(Y, float)), np.asarray(y0, float)
    if not len(Y) or not float(y0 @ y0):
        return 0.0
    sigma = (Y @ y0) / float(y0 @ y0)
    return float(np.max(np.abs(Y - sigma[:, None] * y0[None, :]) / np.asarray(ranges_kgf, float)[None, :]) * 100)


def stop_deviation(window: str | Path, names: list[str], ranges_kgf) -> dict:
    """What a stop or a trip did to the load ratios, from its event window (the recorded
    signals, :class:`endurance.storage.SignalWindow`): the largest deviation of the forces from
    the moment the stand was acted on (the event's ``acted``, else its time: a heartbeat's loss
    is acted on a timeout after its onset, the programme going on meanwhile) from the ratios of
    the last reading before that moment (the reading at the event's time is left out: a spike
    is a reading, not a force), % of a channel's range. ``rows_after``: the readings it saw (in
    lockstep a trip's hold ends the session and the stand stands still: none)."""
    from gateway.runs import load_run
    run = load_run(window)
    meta = json.loads((Path(window) / "run.json").read_text())["event"]
    t = np.asarray(run.signals["sync_time"], float)
    Y = np.array([run.signals[f"y.{n}"] for n in names], float).T
    at = max(meta["time"], meta.get("acted") or meta["time"])
    reading = np.abs(t - meta["time"]) <= 1e-6
    before, after = (t < at - 1e-6) & ~reading, (t >= at - 1e-6) & ~reading
    if not before.any() and not after.any():
        raise DataError(f"{window}: no reading around its event")
    y0 = Y[before][-1] if before.any() else Y[after][0]
    return {"kind": meta["kind"], "message": meta.get("message", ""), "channel": meta.get("channel"),
            "pct_of_range": ratio_deviation_pct(Y[after], y0, ranges_kgf), "rows_after": int(after.sum()),
            "acted_after_s": at - meta["time"], "forces_at_kgf": y0.tolist(), "time": float(meta["time"])}


def session_records(testdir: str | Path) -> list[dict]:
    """The sessions' records (``TESTDIR/sessions/NNNN.json``), oldest first; one that cannot be
    read is left out."""
    records = []
    for path in sorted((Path(testdir) / "sessions").glob("*.json")):
        try:
            records.append(json.loads(path.read_text()))
        except (OSError, ValueError):
            continue
    return records


def found_at_resume(testdir: str | Path, after_s: float) -> dict | None:
    """The forces the first resume after ``after_s`` (epoch s) found when it began (its
    session's record: ``loading.forces_found_kgf``, read after the valves' settling hold): what
    a stop or a trip left. Beside :func:`stop_deviation`, the deviation across the hold
    (:func:`held_deviation`), also where the hold ended the session and its event window saw no
    reading after it (in lockstep the emulated stand stands still without SYNCs). None: no
    resume after it, or the first one wrote no record (killed before it loaded: what it found is
    not known, and a later resume's forces are not the hold's but the next stop's)."""
    testdir = Path(testdir)
    later = sorted((r for r in session_records(testdir) if r.get("kind") == "resume" and (r.get("started_at") or 0) > after_s),
                   key=lambda r: r["started_at"])
    first = _first_start_after(testdir, after_s)
    if first is not None:           # a record's start (the command's) comes before its journal's
        later = [r for r in later if r["started_at"] <= first]
    if not later or not (later[0].get("loading") or {}).get("forces_found_kgf"):
        return None
    loading = later[0]["loading"]
    return {"time": float(loading.get("began_at") or later[0]["started_at"]),
            "forces_kgf": [float(f) for f in loading["forces_found_kgf"]]}


def _first_start_after(testdir: Path, after_s: float) -> float | None:
    """When the first session after ``after_s`` started the test (its journal's ``started``
    event; None: none, or no journal)."""
    if not (testdir / JOURNAL_FILE).exists():
        return None
    with Journal.open(testdir) as journal:
        starts = [e["time"] for e in journal.events() if e["kind"] == "started" and e["time"] > after_s]
    return min(starts) if starts else None


def held_deviation(stop: dict, resume: dict, ranges_kgf) -> dict:
    """The deviation from the load ratios across a stop (:func:`stop_deviation`'s result) to
    the forces the next resume found (:func:`found_at_resume`), % of a channel's range."""
    return {"pct_of_range": ratio_deviation_pct(np.asarray(resume["forces_kgf"])[None, :],
                                                np.asarray(stop["forces_at_kgf"]), ranges_kgf),
            "after_s": resume["time"] - stop.get("time", resume["time"])}


def _block_size(journal: Journal) -> int | None:
    """The block's size from the test file the journal keeps (None if it cannot be read)."""
    import tomllib
    try:
        counts = tomllib.loads(journal.test_file or "")["block"]["flights"]
        return int(sum(counts.values()))
    except (tomllib.TOMLDecodeError, KeyError, TypeError, AttributeError):
        return None


def report_text(r: dict) -> str:
    lines = [f"{r['name']}: {r['state']}" + (f" ({r['reason']})" if r.get("reason") else ""),
             f"flights {r['flights_done']:,} of {r['flights_target']:,}; {r['end_points']:,} end points; "
             f"{len(r['sessions'])} session(s), {r['stops']} stop(s), {r['interruptions']} interruption(s)"]
    for i, s in enumerate(r["sessions"], start=1):
        flown = f"{s['flights_flown']} flown, ended" if s.get("flights_flown") is not None else "its end not recorded:"
        line = f"  session {i}: {s['kind']} at flight {s['first_flight']}, {flown} " \
               f"{s['state']}" + (f" ({s['reason']})" if s.get("reason") else "")
        if s.get("loading"):
            line += f"; loading {s['loading']['to_loading_s']:.2f} s after the {s['kind']}"
        if s.get("unload") and s["unload"].get("largest_deviation"):
            big = s["unload"]["largest_deviation"]
            line += f"; unloaded keeping the ratios, largest deviation {big['pct_of_range']:.2f} % of a range"
        lines.append(line)
    for label, acc in (("all flights", r["accuracy"]),
                       (f"last block ({r['last_block']['block']})" if r.get("last_block") else None,
                        r["last_block"]["accuracy"] if r.get("last_block") else None)):
        if not label or not acc:
            continue
        lines.append(f"peaks and valleys, {label}, % of each channel's range:")
        for name, a in acc.items():
            lines.append(f"  {name:<10} p95 {a['p95']:.3f}  max {a['max']:.3f}  ({a['points']:,} points)")
    return "\n".join(lines)
