"""The end points' trends the live page plots, flight by flight and channel by channel.

From the end points the journal and the turning-point log hold (:func:`endurance.report.
test_end_points`), per flight and channel, over the flight's peaks and valleys:

* ``error_pct``: the largest |reached − level|, % of the channel's range in the flight (as
  ``stand test report`` judges them: :func:`endurance.report.end_point_errors`);
* ``flow_pct``: the mean |valve command| that reached them (the flow), and ``flow_rise_pct``:
  how far it is above its flight type's baseline (the mean of the type's first
  :data:`BASELINE_FLIGHTS` flights the page has seen), % of the baseline. A softer structure (a
  crack) needs more flow for the same end points (docs/endurance.md, end-point trends); the
  trend monitor's statistic (:mod:`endurance.trends`) judges it, this shows it.
"""
from __future__ import annotations

import collections
from pathlib import Path

import numpy as np

from endurance.journal import Journal
from endurance.report import end_point_errors, test_end_points

#: flights of history the page keeps
TREND_FLIGHTS = 500
#: flights of a type whose mean flow is its baseline
BASELINE_FLIGHTS = 10


class TrendHistory:
    """The last :data:`TREND_FLIGHTS` flights' trend rows (module docstring), brought up to
    date from the journal with :meth:`update`."""

    def __init__(self, testdir: str | Path) -> None:
        self.testdir = Path(testdir)
        self.rows: collections.deque[dict] = collections.deque(maxlen=TREND_FLIGHTS)
        self.through = 0                  #: the last flight in the history
        self._baseline: dict[tuple[str, str], list[float]] = {}

    def update(self, journal: Journal) -> list[dict]:
        """The flights done since the last call (the last :data:`TREND_FLIGHTS` at first),
        added to :attr:`rows` and returned."""
        done = journal.flights_done
        if done <= self.through:
            return []
        first = max(self.through + 1, done - TREND_FLIGHTS + 1, 1)
        table = test_end_points(self.testdir, journal, first_flight=first)
        new = self._rows(end_point_errors(table), first)
        self.rows.extend(new)
        self.through = done
        return new

    def _rows(self, e: dict[str, np.ndarray], first: int) -> list[dict]:
        out = []
        if not len(e["flight"]):
            return out
        keep = e["flight"] >= first
        flights, channels = e["flight"][keep], e["channel"][keep]
        errors, flows, types = np.abs(e["error_pct"][keep]), np.abs(e["flow_pct"][keep]), e["flight_type"][keep]
        for number in np.unique(flights):
            here = flights == number
            row = {"flight": int(number), "type": str(types[here][0]), "channels": {}}
            for name in sorted(set(channels[here].tolist())):
                mine = here & (channels == name)
                flow = float(np.nanmean(flows[mine])) if np.isfinite(flows[mine]).any() else None
                row["channels"][name] = {"error_pct": float(errors[mine].max()), "flow_pct": flow,
                                         "flow_rise_pct": self._rise(row["type"], name, flow)}
            out.append(row)
        return out

    def _rise(self, flight_type: str, channel: str, flow: float | None) -> float | None:
        if flow is None:
            return None
        base = self._baseline.setdefault((flight_type, channel), [])
        if len(base) < BASELINE_FLIGHTS:
            base.append(flow)
        mean = float(np.mean(base))
        return 100.0 * (flow / mean - 1.0) if mean > 0 else None
