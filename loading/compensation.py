r"""Peak/valley compensation that learns: per channel a correction per turning-point level.

As commercial peak/valley compensators do, the command's turning points are moved so that the
force reaches the programme's: after each pass, for every peak and valley ``i`` with level
``L_i`` reached at ``A_i``,

.. math::  c(L_i) \leftarrow c(L_i) - \gamma\,(A_i - L_i),\qquad 0 < \gamma \le 1,

and the next pass commands ``L_i + c(L_i)``. Corrections are kept per (kind, level) rounded to
:attr:`Compensation.resolution_kgf`, so a constant-amplitude programme's peaks share one, and a
level never seen before gets the correction of the nearest known levels of its kind
(interpolated linearly). A learning gain below 1 keeps the learning stable when the stand's
response to a correction is not one to one. Saved as TOML (``stand load --compensation``).

Two guards, as commercial compensators have (a tolerance band, and never worse):

* an error within the **tolerance band** (:data:`TOLERANCE_SHARE` of the range, about the
  peak detector's noise) leaves its correction as it is, so the corrections do not chase noise;
* **never worse than the best seen**: each level remembers the smallest error it had and the
  correction it had then (the first pass's is the uncorrected one, or the one loaded). A pass
  whose error at a level is worse than that by more than the band goes back to that correction
  and halves the level's learning gain. So a stand whose response to a correction is larger
  than one to one, or a correction that upsets the segments beside it, costs at most one pass
  at that level. This memory lives with the object (across ``stand load --repeat`` passes);
  a file loaded later starts it afresh.

A station's :class:`Compensation` keeps one :class:`ChannelCompensation` per channel, each
learning from its own channel's turning points, in one file: a one-channel stand's as the
tables ``[peak]`` and ``[valley]`` (:data:`SCHEMA`), a rig's with a table per channel
(``[channel.NAME.peak]``, ``[channel.NAME.valley]``, :data:`STATION_SCHEMA`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from core.errors import ParameterError

from .programme import STAND

LEARNING_GAIN = 0.8
#: a correction is at most this share of the programme's range: compensation trims turning
#: points, it does not rewrite the programme (a larger error is the controller's or the model's)
MAX_CORRECTION_SHARE = 0.05
#: errors within this share of the programme's range leave their correction as it is
TOLERANCE_SHARE = 0.0005
SCHEMA = "hydrostand-compensation/1"
#: the turning points corrected: a channel's own peaks and valleys, and the levels it passes
#: on the way at a station's load cases (rising or falling)
KINDS = ("peak", "valley", "rising", "falling")
#: a rig's file: a table per channel
STATION_SCHEMA = "hydrostand-rig-compensation/1"


@dataclass
class ChannelCompensation:
    """One channel's corrections (module docstring)."""

    learning_gain: float = LEARNING_GAIN
    resolution_kgf: float = 1.0
    #: kind ("peak", "valley", "rising", "falling") -> {level key: correction kgf}
    table: dict = field(default_factory=lambda: {"peak": {}, "valley": {}})
    #: (kind, level key) -> (smallest |error| seen, the correction then, the level's gain)
    history: dict = field(default_factory=dict, repr=False, compare=False)

    def _key(self, level: float) -> float:
        return round(level / self.resolution_kgf) * self.resolution_kgf

    def correction(self, kind: str, level: float) -> float:
        known = self.table.get(kind) or {}
        if not known:
            return 0.0
        key = self._key(level)
        if key in known:
            return known[key]
        xs = np.array(sorted(known))
        return float(np.interp(key, xs, [known[x] for x in xs]))

    def levels(self, levels: np.ndarray, kinds: list[str]) -> np.ndarray:
        """The levels to command for a programme's turning points (its peaks and valleys, and
        the levels it passes at a station's load cases: 'rising', 'falling')."""
        return np.array([lv + (self.correction(k, lv) if k in KINDS else 0.0) for lv, k in zip(levels, kinds)])

    def learn(self, points, range_kgf: float) -> None:
        """Update from a pass's turning points (objects with kind, commanded_kgf, error_kgf)."""
        bound = MAX_CORRECTION_SHARE * range_kgf
        sums: dict = {}
        for p in points:
            key = (p.kind, self._key(p.commanded_kgf))
            sums.setdefault(key, []).append(p.error_kgf)
        band = TOLERANCE_SHARE * range_kgf
        # the corrections the pass ran with, all read before any is updated: a level first seen
        # in this pass ran with the interpolation of the levels known before it, not with what
        # this pass learns at its neighbours
        applied = {k: self.correction(*k) for k in sums}
        for (kind, key), errs in sums.items():
            err = float(np.mean(errs))
            ran = applied[kind, key]
            best, best_c, gain = self.history.get((kind, key), (math.inf, ran, self.learning_gain))
            if abs(err) < best:
                best, best_c = abs(err), ran
            if abs(err) <= band:                       # within the tolerance band: keep it
                new = ran
            elif abs(err) > best + band:               # worse than the best seen: go back
                new, gain = best_c, gain / 2
            else:
                new = ran - gain * err
            self.history[kind, key] = (best, best_c, gain)
            self.table.setdefault(kind, {})[key] = min(max(new, -bound), bound)

    def to_toml(self) -> str:
        out = [f"# {SCHEMA}: peak/valley corrections learned by `stand load`"]
        for kind, lines in self.toml_tables():
            out += ([] if kind is None else ["", f"[{kind}]"]) + lines
        return "\n".join(out) + "\n"

    def toml_tables(self) -> list[tuple[str | None, list[str]]]:
        """The file's content as (table, lines): the settings (table None), then the peak and
        valley corrections (a station's file writes each channel's under its own tables)."""
        out: list[tuple[str | None, list[str]]] = [
            (None, [f"learning_gain = {self.learning_gain!r}", f"resolution_kgf = {self.resolution_kgf!r}"])]
        for kind in KINDS:
            if kind in ("peak", "valley") or self.table.get(kind):
                out.append((kind, [f'"{k:g}" = {v!r}' for k, v in sorted(self.table.get(kind, {}).items())]))
        return out

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_text(self.to_toml())
        return path

    @classmethod
    def load(cls, path: str | Path) -> "ChannelCompensation":
        from plant.config import read_toml
        from plant.params import ModelError
        try:
            data = read_toml(path)
        except ModelError as exc:
            raise ParameterError(f"{path}: not a compensation file ({exc})") from None
        return cls.from_mapping(data, f"{path}", "{where}: not a compensation file ({exc})")

    @classmethod
    def from_mapping(cls, data, where: str, unreadable: str = "{where}: {exc}") -> "ChannelCompensation":
        """From a file's tables (``learning_gain``, ``resolution_kgf``, ``peak``, ``valley``);
        a value that is not a number is :class:`ParameterError` ``unreadable`` (formatted with
        ``where`` and the error), corrections not finite or a gain outside (0, 1] one naming
        ``where``."""
        try:
            comp = cls(float(data.get("learning_gain", LEARNING_GAIN)), float(data.get("resolution_kgf", 1.0)))
            for kind in KINDS:
                if kind in ("peak", "valley") or data.get(kind):
                    comp.table[kind] = {float(k): float(v) for k, v in (data.get(kind) or {}).items()}
        except (TypeError, ValueError, AttributeError) as exc:
            raise ParameterError(unreadable.format(where=where, exc=exc)) from None
        values = [v for t in comp.table.values() for v in t.values()]
        if not all(math.isfinite(v) for v in values) or not (0 < comp.learning_gain <= 1):
            raise ParameterError(f"{where}: corrections must be finite and learning_gain in (0, 1]")
        return comp


@dataclass
class Compensation:
    """A station's peak/valley compensation: a :class:`ChannelCompensation` per channel, each
    learnt from its own turning points, saved in one file (module docstring)."""

    names: list[str]
    channels: dict[str, ChannelCompensation] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for n in self.names:
            self.channels.setdefault(n, ChannelCompensation())

    def levels(self, programme) -> list[np.ndarray]:
        """The levels to command for each channel's turning points (a
        :class:`~loading.programme.Programme`)."""
        return [self.channels[n].levels(p.levels_kgf, p.kinds())
                for n, p in zip(programme.names, programme.channels)]

    def learn(self, reports: Sequence, ranges_kgf: Sequence[float]) -> None:
        """Update each channel from its pass's tracking report (in the channels' order)."""
        for n, rep, rng in zip(self.names, reports, ranges_kgf):
            self.channels[n].learn(rep.turning_points, rng)

    def to_toml(self) -> str:
        if self.names == [STAND]:
            return self.channels[STAND].to_toml()
        out = [f"# {STATION_SCHEMA}: peak/valley corrections learned by `stand load --rig`, per channel"]
        for n in self.names:
            for kind, lines in self.channels[n].toml_tables():
                out += (["", f"[channel.{n}]"] if kind is None else [f"[channel.{n}.{kind}]"]) + lines
        return "\n".join(out) + "\n"

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_text(self.to_toml())
        return path

    @classmethod
    def load(cls, path: str | Path, names: Sequence[str]) -> "Compensation":
        """A compensation file for the station's channels ``names``: a rig's (a table per
        channel, each a channel of the station), or for one channel a one-channel file."""
        from plant.config import read_toml
        from plant.params import ModelError
        names = list(names)
        try:
            data = read_toml(path)
        except ModelError as exc:
            raise ParameterError(f"{path}: not a compensation file ({exc})") from None
        tables = data.get("channel")
        if not isinstance(tables, dict):
            if len(names) == 1:
                return cls(names, {names[0]: ChannelCompensation.from_mapping(
                    data, f"{path}", "{where}: not a compensation file ({exc})")})
            raise ParameterError(f"{path}: not a rig compensation file (no [channel.NAME] tables; a "
                                 f"one-channel file ({SCHEMA}) is for one stand)")
        unknown = [n for n in tables if n not in names]
        if unknown:
            raise ParameterError(f"{path}: [channel.{unknown[0]}] is not a channel of the rig")
        out = cls(names)
        for n, t in tables.items():
            out.channels[n] = ChannelCompensation.from_mapping(t, f"{path}: [channel.{n}]")
        return out
