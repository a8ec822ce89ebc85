r"""Time scaling: each segment as short as it can be while every turning point holds the accuracy.

``stand load PROGRAMME --accuracy 0.5`` (or ``--fastest``) runs the programme pass by pass and
scales each segment's duration on its own (a small gust cycle can go faster than a
ground-air-ground swing). After a pass, the segment that arrives at a turning point

* **lands** when the turning point's error is within ``land_share`` (½) of the accuracy ``a``
  (% of the range), it made no extra cycle near it and the programme did not have to wait or
  slow for it (null pacing): it is shortened;
* **misses** when the error is beyond ``miss_share`` (0.8) of ``a``, or an extra cycle rang near
  it, or the programme paced for it: it is lengthened (the margin below ``a`` keeps the p95 of
  a whole pass within ``a`` when each turning point scatters a little from pass to pass);
* **holds** in between: it keeps its duration.

Per segment this is a bisection between the longest duration known to miss ``d_miss`` and the
shortest known to land ``d_land``, floored at the valve-limited minimum ``d_min``
(:mod:`loading.minimum_time`):

.. math::  d \leftarrow \begin{cases}
              \max(d_{min},\ \sigma\,d) & \text{lands, no miss known} \\
              \max\big(d_{min},\ \sqrt{d_{land}\,d_{miss}}\big) & \text{lands or misses, both known} \\
              \lambda\,d & \text{misses, no landing known}
           \end{cases}

(``σ = shorten``, ``λ = lengthen``), and a segment is settled once it lands at its floor, holds,
or its two bounds are within ``resolution`` of each other (it then runs at ``d_land``). A
segment that misses where it had landed (the turning point's noise, or its neighbours changed)
is settled ``2·resolution`` longer: a bisection would chase the noise. No segment gets longer
than :data:`CEILING` times its start. The
programme is done when a pass with (nearly: :data:`SETTLED_SHARE`) every segment settled meets
the accuracy as a whole: p95 of
``|e|`` ≤ ``a``, max ≤ ``2a``, no extra cycle. The fastest schedule whose pass met it is the
result (``schedule.toml``), which a production run replays (``stand load --schedule``).

The duration a segment is given is rounded to whole loop periods, never below the floor's.
Before a pass the feedforward's check may still find a segment the valve cannot follow (a lag,
a slew limit the minimum does not count): :func:`stretch_to_valve` lengthens it by the excess.

**A station of channels**: between two load cases every channel moves (one common duration, so
the load case's ratios hold at its turning point), so a segment's verdict is the worst of its
channels' at the load case it arrives at (:meth:`TimeScaler.station_verdicts`): it lands only
when every channel lands, misses when one misses. A pass meets the accuracy when every channel
does (:func:`meets`). The floors are each segment's valve-limited minimum through the station's
model (:mod:`loading.minimum_time`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from core.errors import ParameterError

from .programme import ChannelProgramme, Programme, as_programme, turning_points
from .report import GATE_PCT, ChannelReport, TrackingReport

SCHEMA = "hydrostand-schedule/1"
LAND, HOLD, MISS = "land", "hold", "miss"
_WORSE = {LAND: 0, HOLD: 1, MISS: 2}
#: a segment is never made longer than this many times its start (or twice its floor)
CEILING = 4.0
#: the programme counts as settled when this share of its segments are
SETTLED_SHARE = 0.98


@dataclass(frozen=True)
class ScalingOptions:
    """How the segments are scaled (module docstring)."""

    accuracy_pct: float = 0.5
    shorten: float = 0.6
    lengthen: float = 1.5
    land_share: float = 0.5
    miss_share: float = 0.8
    resolution: float = 0.05
    #: a segment the programme paced for longer than this share of it misses
    paced_share: float = 0.02

    def check(self) -> None:
        if not (math.isfinite(self.accuracy_pct) and 0.01 <= self.accuracy_pct <= 10):
            raise ParameterError(f"accuracy {self.accuracy_pct} %: give a share of the range from 0.01 "
                                 "to 10 % (e.g. --accuracy 0.5)")
        if not (0 < self.shorten < 1 and self.lengthen > 1 and 0 < self.land_share <= self.miss_share <= 1
                and 0 < self.resolution < 1):
            raise ParameterError("time scaling: shorten in (0, 1), lengthen > 1, 0 < land_share <= "
                                 "miss_share <= 1, resolution in (0, 1)")


@dataclass
class Schedule:
    """Segment durations for a programme's load cases (``schedule.toml``): a one-channel
    stand's has its turning points' levels; a rig's (``stand load --rig``) names its
    ``channels`` and has a row of levels per channel."""

    levels_kgf: np.ndarray
    durations_s: np.ndarray
    period_s: float
    accuracy_pct: float = math.nan
    minimum_time_s: float = math.nan
    source: str = ""
    #: True when a pass with exactly these durations met the accuracy
    verified: bool = False
    notes: list[str] = field(default_factory=list)
    #: a rig's schedule: its channels, in the order of the rows of ``levels_kgf``
    channels: list[str] | None = None
    #: the peak/valley corrections the pass that met the accuracy ran with: a compensation file
    #: beside the schedule (its name), which a replay starts from
    compensation: str | None = None
    #: where the schedule was read from (a compensation file is named relative to it)
    path: Path | None = field(default=None, compare=False)

    @property
    def time_s(self) -> float:
        return float(np.sum(self.durations_s))

    @classmethod
    def of(cls, programme: Programme, durations_s: np.ndarray, accuracy_pct: float, minimum_time_s: float,
           verified: bool, notes: list[str]) -> "Schedule":
        """The schedule of a station's programme with these durations (a one-channel stand's
        in the one-channel form)."""
        stand = programme.stand
        return cls(programme.levels_kgf[0] if stand else programme.levels_kgf, np.asarray(durations_s, float),
                   programme.period_s, accuracy_pct, minimum_time_s, programme.source, verified, notes,
                   None if stand else list(programme.names))

    def apply(self, programme: Programme | ChannelProgramme) -> Programme:
        """The station's programme with these durations; refused if its channels or load
        cases are not these."""
        programme = as_programme(programme)
        what = self.source or "schedule.toml"
        if self.channels is not None and programme.stand:
            raise ParameterError(f"the schedule ({what}) is a rig's (channels {', '.join(self.channels)}): "
                                 "replay it with --rig")
        if self.channels is None and not programme.stand:
            raise ParameterError(f"the schedule ({what}) is one channel's: it cannot time a rig's load "
                                 "cases; make one with stand load --rig --fastest")
        if self.channels is not None and list(self.channels) != list(programme.names):
            raise ParameterError(f"the schedule ({what}) is for the channels {', '.join(self.channels)}, "
                                 f"the rig has {', '.join(programme.names)}")
        if not programme.load_cases:
            raise ParameterError(f"{programme.source}: per-channel sequences have no load cases to "
                                 "time; a schedule times a load-case CSV")
        lv = programme.levels_kgf[0] if self.channels is None else programme.levels_kgf
        if lv.shape != self.levels_kgf.shape or not np.allclose(lv, self.levels_kgf, atol=0.05):
            if self.channels is None:
                where = (f"it has {len(lv)} turning points, the schedule {len(self.levels_kgf)}"
                         if lv.shape != self.levels_kgf.shape else f"turning point {self._first_difference(lv)} differs")
                raise ParameterError(f"the schedule ({what}) was made for another programme than "
                                     f"{programme.source}: {where}; run --fastest or --accuracy on this "
                                     "programme to make its schedule")
            where = (f"it has {lv.shape[1]} load cases, the schedule {self.levels_kgf.shape[1]}"
                     if lv.shape != self.levels_kgf.shape else f"load case {self._first_difference(lv)} differs")
            raise ParameterError(f"the schedule ({what}) was made for other load cases than "
                                 f"{programme.source}: {where}; run --fastest or --accuracy on these "
                                 "load cases to make their schedule")
        return self._timed(programme)

    def _first_difference(self, levels: np.ndarray) -> int:
        """The first turning point (load case: every channel's) that is not the schedule's, from 1."""
        close = np.isclose(levels, self.levels_kgf, atol=0.05)
        return int(np.flatnonzero(~close.reshape(-1, close.shape[-1]).all(axis=0))[0]) + 1

    def _timed(self, programme):
        if abs(self.period_s - programme.period_s) > 1e-12:
            raise ParameterError(f"the schedule was made at a period of {self.period_s * 1e3:g} ms, the "
                                 f"loop runs at {programme.period_s * 1e3:g} ms")
        return programme.with_durations(self.durations_s, f"{programme.source}, scheduled "
                                                          f"({self.time_s:.1f} s)")

    def to_toml(self) -> str:
        out = [f"# {SCHEMA}: segment durations made by `stand load --accuracy/--fastest`",
               "# (replay with `stand load PROGRAMME --schedule THIS_FILE`)",
               f"source = {_quote(self.source)}", f"period_s = {self.period_s!r}",
               f"accuracy_pct = {float(self.accuracy_pct)!r}", f"verified = {str(self.verified).lower()}",
               f"time_s = {self.time_s!r}", f"minimum_time_s = {float(self.minimum_time_s)!r}"]
        out += [f"notes = [{', '.join(_quote(n) for n in self.notes)}]"]
        if self.channels is not None:
            rows = ("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in self.levels_kgf)
            out += [f"channels = [{', '.join(_quote(n) for n in self.channels)}]",
                    "levels_kgf = [" + ", ".join(rows) + "]"]
        else:
            out += ["levels_kgf = [" + ", ".join(repr(float(v)) for v in self.levels_kgf) + "]"]
        out += ["durations_s = [" + ", ".join(f"{v:.9g}" for v in self.durations_s) + "]"]
        if self.compensation is not None:
            out += [f"compensation = {_quote(self.compensation)}"]
        return "\n".join(out) + "\n"

    @property
    def compensation_path(self) -> Path | None:
        """The compensation file the schedule's pass ran with (None: it ran without one)."""
        if self.compensation is None:
            return None
        return (self.path.parent if self.path is not None else Path(".")) / self.compensation

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_text(self.to_toml())
        return path

    @classmethod
    def load(cls, path: str | Path) -> "Schedule":
        from plant.config import read_toml
        from plant.params import ModelError
        try:
            d = read_toml(path)
            s = cls(np.asarray(d["levels_kgf"], float), np.asarray(d["durations_s"], float),
                    float(d["period_s"]), float(d.get("accuracy_pct", math.nan)),
                    float(d.get("minimum_time_s", math.nan)), str(d.get("source", path)),
                    bool(d.get("verified", False)), list(d.get("notes", [])),
                    [str(n) for n in d["channels"]] if "channels" in d else None,
                    str(d["compensation"]) if "compensation" in d else None, Path(path))
        except (ModelError, KeyError, TypeError, ValueError) as exc:
            raise ParameterError(f"{path}: not a schedule file ({exc}); write one with stand load "
                                 "--fastest or --accuracy") from None
        if s.channels is not None and (s.levels_kgf.ndim != 2 or s.levels_kgf.shape[0] != len(s.channels)):
            raise ParameterError(f"{path}: a rig's schedule has a row of levels_kgf per channel "
                                 f"({len(s.channels)} channels)")
        if s.channels is None and s.levels_kgf.ndim != 1:
            raise ParameterError(f"{path}: levels_kgf is a table but the schedule names no channels")
        if (s.durations_s.shape != (s.levels_kgf.shape[-1] - 1,) or not np.isfinite(s.durations_s).all()
                or not (s.durations_s > 0).all()):
            raise ParameterError(f"{path}: one positive duration per segment (levels - 1) is expected")
        return s


def _quote(text: str) -> str:
    return '"' + str(text).replace("\\", "\\\\").replace('"', '\\"') + '"'


def ringing_turning_points(programme: ChannelProgramme, t_s: np.ndarray, y_kgf: np.ndarray,
                           gate_pct: float = GATE_PCT) -> set[int]:
    """The turning points (their sample in the programme) near which the force reversed more
    than once beyond the gate: where an extra cycle rang. Each turning point's window runs from
    half way after the one before to half way before the one after, on the programme's clock."""
    t = np.asarray(t_s, float)
    y = np.asarray(y_kgf, float)
    inside = (t >= 0) & (t <= programme.duration_s)
    t, y = t[inside], y[inside]
    if len(y) < 3:
        return set()
    rev = turning_points(y, gate_pct / 100 * programme.range_kgf)[1:-1]
    idx = programme.turning_idx
    edges = programme.t_s[np.r_[0, (idx[:-1] + idx[1:]) // 2, idx[-1]]]
    counts = np.bincount(np.searchsorted(edges, t[rev], "right") - 1, minlength=len(idx))
    return {int(idx[j]) for j in range(1, len(idx) - 1) if counts[j] > 1}


class TimeScaler:
    """The per-segment bisection of the module docstring, pass after pass."""

    def __init__(self, programme: Programme | ChannelProgramme, minimum_s: np.ndarray, start_s: np.ndarray,
                 options: ScalingOptions) -> None:
        options.check()
        T = programme.period_s
        self.programme = programme
        self.options = options
        self.floor = np.maximum(np.ceil(np.asarray(minimum_s, float) / T - 1e-9), 1) * T
        self.durations = np.maximum(_whole(np.asarray(start_s, float), T), self.floor)
        #: a segment is never made longer than this (its start, or twice its floor, times 4)
        self.ceiling = CEILING * np.maximum(self.durations, 2 * self.floor)
        self.landed = np.full(len(self.floor), np.inf)      # shortest duration that landed
        self.missed = np.zeros(len(self.floor))             # longest duration that missed
        self.settled = np.zeros(len(self.floor), bool)
        self.last: dict[str, int] = {}

    def verdicts(self, programme: ChannelProgramme, report: ChannelReport, ringing: set[int] = frozenset(),
                 paced_s: dict[int, float] | None = None) -> list[str]:
        """Per segment: land, hold or miss (module docstring), from one channel's ``report``
        of the pass that ran ``programme`` (the scaled one: turning points by its samples); a
        segment arriving at no peak or valley (the last) lands."""
        a = self.options.accuracy_pct
        idx = programme.turning_idx
        arriving = {int(s): j for j, s in enumerate(idx[1:])}
        out = [LAND] * len(self.durations)
        for tp in report.turning_points:
            j = arriving.get(tp.index)
            if j is None:
                continue
            err = abs(tp.error_pct)
            paced = (paced_s or {}).get(tp.index, 0.0) > self.options.paced_share * self.durations[j]
            if err > self.options.miss_share * a or tp.index in ringing or paced:
                out[j] = MISS
            elif err > self.options.land_share * a:
                out[j] = HOLD
        self.last = {v: out.count(v) for v in (LAND, HOLD, MISS)}
        return out

    def station_verdicts(self, programme: Programme, report: TrackingReport, t_s: np.ndarray,
                         y_kgf: np.ndarray, paced_s: dict[int, float] | None = None) -> list[str]:
        """Per segment between load cases: land, hold or miss, the worst of the channels'
        (module docstring), from the pass that ran ``programme`` and recorded the forces
        ``y_kgf`` (N, K) at ``t_s`` (the programme's clock); ``paced_s``: the time the programme
        waited heading to each load case (its sample): a segment it waited for misses."""
        per_channel = [self.verdicts(p, r, ringing_turning_points(p, t_s, y), paced_s)
                       for p, r, y in zip(programme.channels, report.channels, np.asarray(y_kgf, float))]
        out = [max(v, key=_WORSE.__getitem__) for v in zip(*per_channel)]
        self.last = {v: out.count(v) for v in (LAND, HOLD, MISS)}
        return out

    def update(self, verdicts: list[str]) -> np.ndarray:
        """The next pass's durations from this pass's verdicts."""
        o = self.options
        T = self.programme.period_s
        d = self.durations.copy()
        for j, v in enumerate(verdicts):
            dj = self.durations[j]
            land, miss = self.landed[j], self.missed[j]
            if v == MISS and dj >= land - T / 2:
                # it missed where it had landed: the turning point's noise, or its neighbours
                # changed; one small step longer and no more (a bisection would chase the noise)
                d[j], self.settled[j] = dj * (1 + 2 * o.resolution), True
                self.landed[j] = d[j]
                continue
            if v == MISS:
                self.missed[j] = miss = max(miss, dj)
            else:
                self.landed[j] = land = min(land, dj)
            if v == HOLD or (v == LAND and dj <= self.floor[j] * (1 + 1e-9)):
                d[j], self.settled[j] = dj, True
            elif math.isfinite(land) and miss > 0:
                close = land / miss <= 1 + o.resolution or land - miss <= T
                d[j] = land if close else max(self.floor[j], math.sqrt(land * miss))
                self.settled[j] = close
            elif v == LAND:
                d[j], self.settled[j] = max(self.floor[j], dj * o.shorten), False
            else:
                d[j], self.settled[j] = dj * o.lengthen, False
        self.durations = np.minimum(np.maximum(_whole(d, T), self.floor), self.ceiling)
        return self.durations

    #: what :meth:`state` keeps, per segment
    _STATE = ("floor", "durations", "ceiling", "landed", "missed", "settled")

    def state(self) -> dict[str, list]:
        """The bisection's state per segment (JSON- and TOML-ready; ``landed`` may be inf):
        what a search stopped between passes needs to go on (:meth:`from_state`)."""
        return {k: getattr(self, k).tolist() for k in self._STATE}

    @classmethod
    def from_state(cls, programme: Programme | ChannelProgramme, options: ScalingOptions,
                   state: dict) -> "TimeScaler":
        """The scaler :meth:`state` saved, for ``programme``'s segments."""
        new = cls.__new__(cls)
        new.programme, new.options, new.last = programme, options, {}
        for k in cls._STATE:
            v = np.asarray(state[k], bool if k == "settled" else float)
            if v.shape != (len(programme.turning_idx) - 1,):
                raise ParameterError(f"time scaling: a state of {v.shape[0]} segments for a programme "
                                     f"of {len(programme.turning_idx) - 1}")
            setattr(new, k, v)
        return new

    @property
    def all_settled(self) -> bool:
        """(Nearly) every segment settled: at least :data:`SETTLED_SHARE` of them (a few
        turning points scatter across the bands from pass to pass)."""
        return bool(self.settled.mean() >= SETTLED_SHARE)


def meets(report: TrackingReport, accuracy_pct: float) -> bool:
    """On every channel: p95 of the peak/valley error within the accuracy, max within twice
    it, no extra cycle."""
    return all(channel_meets(r, accuracy_pct) for r in report.channels)


def channel_meets(report: ChannelReport, accuracy_pct: float) -> bool:
    """One channel's p95 of the peak/valley error within the accuracy, max within twice it, no
    extra cycle."""
    pv = report.peak_valley_error_pct
    return pv["p95"] <= accuracy_pct and pv["max"] <= 2 * accuracy_pct and report.extra_cycles == 0


def stretch_to_valve(durations_s: np.ndarray, peak_command_pct: np.ndarray,
                     limit_pct: float) -> np.ndarray | None:
    """The durations with every segment whose feedforward needs more than ``limit_pct``
    (``peak_command_pct``: each segment's largest feedforward command, %) stretched by the
    excess (plus 1 %); None when none needs it."""
    peaks = np.asarray(peak_command_pct, float)
    over = peaks > limit_pct
    if not over.any():
        return None
    d = np.asarray(durations_s, float).copy()
    d[over] *= peaks[over] / limit_pct * 1.01
    return d


def _whole(d: np.ndarray, period_s: float) -> np.ndarray:
    return np.maximum(np.round(d / period_s), 1) * period_s
