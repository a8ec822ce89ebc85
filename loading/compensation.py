r"""Peak/valley compensation that learns: per channel a correction per turning-point level (on a
station's load cases, per load case, with the shape between them).

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
  and halves the level's learning gain, down to :data:`GAIN_FLOOR_SHARE` of it (months of
  flights would otherwise halve it to nothing on noise alone). So a stand whose response to a correction is larger
  than one to one, or a correction that upsets the segments beside it, costs at most one pass
  at that level. A pass run with the best correction measures the best anew: the same
  correction can miss by more another time (an endurance test's flights start from what the
  flight before left; a session's first glides in), and a best that cannot be had again would
  send every later pass back to it, its gain halved each time, learning nothing. This memory
  lives with the object (across ``stand load --repeat`` passes); a file loaded later starts it
  afresh.

**The pass's own corrections.** Each step starts from the corrections the pass ran with.
``stand load --repeat`` learns before it builds the next pass, so those are the object's. An
endurance test prepares a flight while the one before flies: two flights of a type in a row
run the same corrections, and the second's are handed to :meth:`Compensation.learn` (``ran``).
Read from the object, its error would be counted twice and the secant read between
corrections that did not make those errors.

**By load case** (a station of several channels on load cases): every channel is judged at
every load case (:mod:`loading.report`: its peaks and valleys, and where it passes or holds its
level while others turn), and each (channel, load case) learns a correction of its own, never
one shared with, or interpolated from, another load case (a level is a different thing at each
load case: what the neighbours do there differs). The law divides by the case's
**sensitivity** ``ŝ``, how far its force moved per kgf of correction:

.. math::  c_{j+1} = c_j - \gamma\,\frac{e_j}{\hat s},\qquad
           \hat s = \operatorname{clip}\Big(\frac{e_j - e_{j-1}}{c_j - c_{j-1}},\
           s_{min}, s_{max}\Big)

(``ŝ = 1`` until two passes ran with corrections :data:`SECANT_BANDS` tolerance bands apart:
the feedforward makes the model follow its reference one to one). If the force answers a
correction by ``s``, the error after the next pass is ``(1 − γ·s/ŝ)·e_j``: with ``ŝ`` within a
factor ``β`` of ``s`` it shrinks by a factor of at most ``max(1 − γ/β, γβ − 1)`` per pass
(γ = 0.8; with ``s`` and ``ŝ`` both within [``s_min``, ``s_max``] = [0.5, 2], whatever the
secant read: 0.6; the first step, ``ŝ = 1``, wherever ``0 < s < 2/γ``), down to the tolerance
band, the sensor's noise. What the law cannot do it says, per case
(:attr:`ChannelCompensation.last`): ``band`` (within the band: kept), ``learning``, ``bound``
(the correction stopped at :data:`MAX_CORRECTION_SHARE`), ``back`` (worse than its best with no
sensitivity to trust: back to the best correction, its gain halved) and ``unreached`` (the force
moved under :data:`UNREACHED_BELOW` of its correction, or the other way, while the case was off
by more than :data:`UNREACHED_BANDS` bands): its correction is kept at its best and what can
reach the case learns instead, the segment arriving there runs :data:`STRETCH_STEP` times longer
each pass, up to :data:`STRETCH_MAX` (:meth:`Compensation.timed`).

**The shape between load cases.** A level is reached at its load case's moment; between two
the force can still run ahead and come back (a channel that moves little while its neighbours
move much, its force made by their flows; an effect the model lacks), an extra cycle of the
tracking report. Where a segment's force went back against its reference's way by more than
:data:`RETREAT_SHARE` of the range, its shape learns too: the force's deviation there, less the
haversine share of its two ends' (which the levels learn), is told in the sine series of
:func:`~loading.programme.shape_basis` (``d``, zero at both load cases), and the reference
between them gets ``a ← a − γ_s·d`` (γ_s = :data:`SHAPE_GAIN`; a sine's amplitude answers about
one to one, as a level does, and the contact of a stiffer load path made it 1.3-1.5: half the
levels' gain contracts there too), its largest offset at most :data:`MAX_CORRECTION_SHARE` of
the range.

A station's :class:`Compensation` keeps one :class:`ChannelCompensation` per channel, each
learning from its own channel's turning points, in one file: a one-channel stand's as the
tables ``[peak]`` and ``[valley]`` (:data:`SCHEMA`), a rig's with a table per channel
(``[channel.NAME.peak]``, ``[channel.NAME.valley]``; by load case ``[channel.NAME.case]``,
``"K" = {level, correction, sensitivity[, unreached]}`` for the K-th load case,
``[channel.NAME.shape]``, ``"K" = [modes]`` for the segment from load case K, and
``[stretch]``, the segments run longer: :data:`STATION_SCHEMA`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from core.errors import ParameterError

from .programme import SHAPE_MODES, STAND, shape_basis
from .report import GATE_PCT

LEARNING_GAIN = 0.8
#: a learning gain halved by going back stops at this share of its start (module docstring)
GAIN_FLOOR_SHARE = 1 / 8
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
#: by load case: the sensitivity the law divides by stays within these
SENSITIVITY_MIN, SENSITIVITY_MAX = 0.5, 2.0
#: by load case: a force that moved less than this share of its correction (or the other way)
#: did not follow its level there (``unreached``), where its error is beyond this many tolerance
#: bands (0.5 % of the range: a smaller one does not make a segment longer)
UNREACHED_BELOW = 0.1
UNREACHED_BANDS = 10
#: by load case: a sensitivity is read from two passes whose corrections differ by at least this
#: many tolerance bands (closer, the noise would be most of it)
SECANT_BANDS = 4
#: by load case: a segment's shape learns once its force went back against the reference's way
#: by this share of the range (a quarter of the extra cycles' gate)
RETREAT_SHARE = GATE_PCT / 100 / 4
#: by load case: the shapes' learning gain (module docstring)
SHAPE_GAIN = 0.4
#: by load case: what the law did at a case in the last pass (module docstring)
STATUSES = ("band", "learning", "bound", "back", "unreached")


@dataclass
class CaseLearning:
    """One channel's learning at one load case (module docstring, "By load case")."""

    level_kgf: float               #: the level asked there (a file is refused for other levels)
    correction_kgf: float = 0.0    #: commanded = level + correction
    sensitivity: float = 1.0       #: ŝ: force moved per kgf of correction
    gain: float = LEARNING_GAIN    #: γ, halved each time it goes back
    #: the force did not follow the level here: the correction stays at its best, the segment
    #: arriving here learns (module docstring)
    unreached: bool = False
    #: the pass before: (the correction it ran with, its error), None before the second pass
    before: tuple[float, float] | None = field(default=None, repr=False)
    #: the smallest |error| seen and the correction then
    best: tuple[float, float] = field(default=(math.inf, 0.0), repr=False)


@dataclass
class ChannelCompensation:
    """One channel's corrections (module docstring)."""

    learning_gain: float = LEARNING_GAIN
    resolution_kgf: float = 1.0
    #: kind ("peak", "valley", "rising", "falling") -> {level key: correction kgf}
    table: dict = field(default_factory=lambda: {"peak": {}, "valley": {}})
    #: (kind, level key) -> (smallest |error| seen, the correction then, the level's gain)
    history: dict = field(default_factory=dict, repr=False, compare=False)
    #: a station's load cases (their position from 0) -> the learning there (module docstring)
    cases: dict = field(default_factory=dict)
    #: by load case, after each learn: case -> {"error_kgf", "ran_kgf", "next_kgf",
    #: "sensitivity", "status"} (what the law did and why)
    last: dict = field(default_factory=dict, repr=False, compare=False)
    #: by load case: per segment (from load case k to k + 1) the shape added to the reference
    #: between them, in :func:`~loading.programme.shape_basis` (module docstring)
    shapes: dict = field(default_factory=dict)

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

    def levels(self, levels: np.ndarray, kinds: list[str], by_case: bool = False) -> np.ndarray:
        """The levels to command for a programme's turning points (its peaks and valleys, and
        the levels it passes at a station's load cases: 'rising', 'falling'); ``by_case``: a
        station's load cases, each with its own correction (module docstring)."""
        if by_case:
            return self._case_levels(np.asarray(levels, float))
        return np.array([lv + (self.correction(k, lv) if k in KINDS else 0.0) for lv, k in zip(levels, kinds)])

    def _case_levels(self, levels: np.ndarray) -> np.ndarray:
        out = levels.copy()
        for j, case in self.cases.items():
            if not 0 < j < len(levels) - 1:
                raise ParameterError(f"load case {j + 1}: corrections learnt on a programme of other load "
                                     f"cases (this one has {len(levels)})")
            if abs(case.level_kgf - levels[j]) > self.resolution_kgf / 2:
                raise ParameterError(f"load case {j + 1}: its correction was learnt at {case.level_kgf:g} kgf, "
                                     f"the programme asks {levels[j]:g} kgf: corrections learnt on other "
                                     "load cases")
            out[j] += case.correction_kgf
        return out

    def learn(self, points, range_kgf: float, shapes: dict | None = None, retreats: dict | None = None,
              ran: "ChannelCompensation | None" = None) -> None:
        """Update from a pass's turning points (objects with kind, commanded_kgf, error_kgf and
        case: a station's load case, learnt by case; None: by kind and level) and, by load
        case, the shapes between them (:attr:`loading.report.ChannelReport.shapes`). ``ran``:
        the corrections the pass ran with, when they are not these as they are now (None:
        these; module docstring, "The pass's own corrections")."""
        ran_with = self if ran is None else ran
        if any(getattr(p, "case", None) is not None for p in points):
            self._learn_cases(points, range_kgf, ran_with)
            self._learn_shapes(shapes or {}, retreats or {}, range_kgf, ran_with)
            return
        bound = MAX_CORRECTION_SHARE * range_kgf
        sums: dict = {}
        for p in points:
            key = (p.kind, self._key(p.commanded_kgf))
            sums.setdefault(key, []).append(p.error_kgf)
        band = TOLERANCE_SHARE * range_kgf
        # the corrections the pass ran with, all read before any is updated: a level first seen
        # in this pass ran with the interpolation of the levels known before it, not with what
        # this pass learns at its neighbours
        applied = {k: ran_with.correction(*k) for k in sums}
        for (kind, key), errs in sums.items():
            err = float(np.mean(errs))
            ran = applied[kind, key]
            best, best_c, gain = self.history.get((kind, key), (math.inf, ran, self.learning_gain))
            if abs(err) < best or ran == best_c:       # better, or the best run again
                best, best_c = abs(err), ran
            if abs(err) <= band:                       # within the tolerance band: keep it
                new = ran
            elif abs(err) > best + band:               # worse than the best seen: go back
                new, gain = best_c, max(gain / 2, GAIN_FLOOR_SHARE * self.learning_gain)
            else:
                new = ran - gain * err
            self.history[kind, key] = (best, best_c, gain)
            self.table.setdefault(kind, {})[key] = min(max(new, -bound), bound)

    def _learn_cases(self, points, range_kgf: float, ran_with: "ChannelCompensation") -> None:
        """By load case (module docstring): each case's correction from its own error and the
        correction it ran with (``ran_with``'s)."""
        bound = MAX_CORRECTION_SHARE * range_kgf
        band = TOLERANCE_SHARE * range_kgf
        self.last = {}
        for p in points:
            if p.case is None:
                continue
            case = self.cases.setdefault(p.case, CaseLearning(float(p.commanded_kgf)))
            other = ran_with.cases.get(p.case)
            ran, err = other.correction_kgf if other is not None else 0.0, float(p.error_kgf)
            status, trusted = "learning", False
            if case.before is not None:
                c0, e0 = case.before
                if abs(ran - c0) >= SECANT_BANDS * band:
                    s = (err - e0) / (ran - c0)
                    if s < UNREACHED_BELOW and abs(err) > UNREACHED_BANDS * band:
                        case.unreached = True
                    else:
                        case.sensitivity, trusted = min(max(s, SENSITIVITY_MIN), SENSITIVITY_MAX), True
            if abs(err) < case.best[0] or ran == case.best[1]:     # better, or the best run again
                case.best = (abs(err), ran)
            if abs(err) <= band:
                new, status = ran, "band"
            elif case.unreached:
                new, status = case.best[1], "unreached"
            elif abs(err) > case.best[0] + band and not trusted:
                new, status = case.best[1], "back"
                case.gain = max(case.gain / 2, GAIN_FLOOR_SHARE * self.learning_gain)
            else:
                new = ran - case.gain * err / case.sensitivity
            if abs(new) > bound:
                new, status = math.copysign(bound, new), "bound"
            case.before = (ran, err)
            case.correction_kgf = new
            self.last[p.case] = {"error_kgf": err, "ran_kgf": ran, "next_kgf": new,
                                 "sensitivity": case.sensitivity, "status": status}

    def _learn_shapes(self, shapes: dict, retreats: dict, range_kgf: float, ran_with: "ChannelCompensation") -> None:
        """By load case: the shape of each segment where the force went back against the
        reference's way (by more than :data:`RETREAT_SHARE` of the range: an extra cycle in the
        making) or that has one, ``a ← a − γ_s·d`` (``d`` the force's deviation there in the same
        modes), its largest offset at most :data:`MAX_CORRECTION_SHARE` of the range (module
        docstring; ``a`` the shape the pass ran with, ``ran_with``'s)."""
        bound = MAX_CORRECTION_SHARE * range_kgf
        for k, modes in shapes.items():
            if (k not in self.shapes and k not in ran_with.shapes
                    and retreats.get(k, 0.0) <= RETREAT_SHARE * range_kgf):
                continue
            d = np.asarray(modes, float)
            a = ran_with.shapes.get(k, np.zeros(len(d)))
            a = np.r_[a, np.zeros(max(len(d) - len(a), 0))][:len(d)] - SHAPE_GAIN * d
            largest = np.max(np.abs(shape_basis(129, len(a)) @ a))
            self.shapes[k] = a * min(1.0, bound / largest) if largest > 0 else a

    def offsets(self, programme) -> np.ndarray:
        """By load case: the shapes as offsets to one channel's reference (a
        :class:`~loading.programme.ChannelProgramme` of the station's load cases), zero at every
        load case."""
        d = np.zeros(len(programme.r_kgf))
        idx = programme.turning_idx
        for k, a in self.shapes.items():
            if k + 1 >= len(idx):
                raise ParameterError(f"segment {k + 1}: shapes learnt on a programme of other load cases "
                                     f"(this one has {len(idx)})")
            lo, hi = int(idx[k]), int(idx[k + 1])
            d[lo:hi + 1] = shape_basis(hi - lo + 1, len(a)) @ a
        return d

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
        if self.cases:
            out.append(("case", ["# load case (1: the first) = its level, correction (kgf) and sensitivity"] + [
                f'"{j + 1}" = {{level = {c.level_kgf!r}, correction = {c.correction_kgf!r}, '
                f'sensitivity = {c.sensitivity!r}' + (", unreached = true" if c.unreached else "") + "}"
                for j, c in sorted(self.cases.items())]))
        if self.shapes:
            out.append(("shape", ["# the segment from load case K to K + 1 = its shape's modes (kgf)"] + [
                f'"{k + 1}" = [{", ".join(repr(float(x)) for x in a)}]' for k, a in sorted(self.shapes.items())]))
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
            for k, v in (data.get("case") or {}).items():
                comp.cases[int(k) - 1] = CaseLearning(float(v["level"]), float(v["correction"]),
                                                      float(v.get("sensitivity", 1.0)), comp.learning_gain,
                                                      unreached=bool(v.get("unreached", False)))
            for k, v in (data.get("shape") or {}).items():
                comp.shapes[int(k) - 1] = np.array([float(x) for x in v])
        except (TypeError, ValueError, AttributeError, KeyError) as exc:
            raise ParameterError(unreadable.format(where=where, exc=exc)) from None
        values = [v for t in comp.table.values() for v in t.values()]
        values += [x for c in comp.cases.values() for x in (c.level_kgf, c.correction_kgf, c.sensitivity)]
        values += [x for a in comp.shapes.values() for x in a]
        if not all(math.isfinite(v) for v in values) or not (0 < comp.learning_gain <= 1):
            raise ParameterError(f"{where}: corrections must be finite and learning_gain in (0, 1]")
        if any(k < 0 or not SHAPE_MODES[0] <= len(a) <= SHAPE_MODES[1] for k, a in comp.shapes.items()):
            raise ParameterError(f"{where}: [shape] keys are segments from 1, each {SHAPE_MODES[0]} to "
                                 f"{SHAPE_MODES[1]} numbers")
        if any(j < 0 or not SENSITIVITY_MIN <= c.sensitivity <= SENSITIVITY_MAX for j, c in comp.cases.items()):
            raise ParameterError(f"{where}: [case] keys are load cases from 1 and each sensitivity within "
                                 f"[{SENSITIVITY_MIN:g}, {SENSITIVITY_MAX:g}]")
        return comp


#: by load case: a segment arriving at a load case some channel's level does not reach is
#: lengthened by this factor per pass, up to :data:`STRETCH_MAX` times its duration
STRETCH_STEP = 1.25
STRETCH_MAX = 2.0


@dataclass
class Compensation:
    """A station's peak/valley compensation: a :class:`ChannelCompensation` per channel, each
    learnt from its own turning points, saved in one file (module docstring)."""

    names: list[str]
    channels: dict[str, ChannelCompensation] = field(default_factory=dict)
    #: by load case: segment (from load case k to k + 1) -> the factor its duration is run at,
    #: where a channel's level at load case k + 1 was ``unreached`` (module docstring)
    stretch: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for n in self.names:
            self.channels.setdefault(n, ChannelCompensation())

    def levels(self, programme) -> list[np.ndarray]:
        """The levels to command for each channel's turning points (a
        :class:`~loading.programme.Programme`; a station's load cases by case)."""
        by_case = programme.load_cases and programme.n > 1
        out = []
        for n, p in zip(programme.names, programme.channels):
            try:
                out.append(self.channels[n].levels(p.levels_kgf, p.kinds(), by_case))
            except ParameterError as exc:
                raise ParameterError(f"channel {n}: {exc}") from None
        return out

    def learn(self, reports: Sequence, ranges_kgf: Sequence[float], ran: "Compensation | None" = None) -> None:
        """Update each channel from its pass's tracking report (in the channels' order).
        ``ran``: the compensation the pass ran with, when it is not this one as it is now (an
        endurance test prepares a flight before the flight ahead of it has taught its type;
        module docstring, "The pass's own corrections")."""
        for n, rep, rng in zip(self.names, reports, ranges_kgf):
            self.channels[n].learn(rep.turning_points, rng, getattr(rep, "shapes", None),
                                   getattr(rep, "retreats", None), None if ran is None else ran.channels[n])
        for k in sorted({j for c in self.channels.values() for j, v in c.last.items() if v["status"] == "unreached"}):
            self.stretch[k - 1] = min(self.stretch.get(k - 1, 1.0) * STRETCH_STEP, STRETCH_MAX)

    def timed(self, programme):
        """``programme`` with the segments :attr:`stretch` lengthens (load cases only; the same
        programme without any)."""
        if not self.stretch or not programme.load_cases:
            return programme
        d = programme.segment_durations_s.copy()
        for k, f in self.stretch.items():
            if k >= len(d):
                raise ParameterError(f"segment {k + 1}: stretched on a programme of other load cases "
                                     f"(this one has {len(d) + 1})")
            d[k] *= f
        return programme.with_durations(d, f"{programme.source}, {len(self.stretch)} segment(s) lengthened "
                                           "where a level was not reached")

    def learned(self, labels: Sequence[str] | None = None) -> dict:
        """By load case, what the last :meth:`learn` did: how many (channel, load case) took
        each status, and every one that did not learn (``bound``, ``back``, ``unreached``:
        channel, load case, error, status), with the segments lengthened."""
        counts = {k: 0 for k in STATUSES}
        why = []
        for n in self.names:
            for j, v in sorted(self.channels[n].last.items()):
                counts[v["status"]] += 1
                if v["status"] in ("bound", "back", "unreached"):
                    why.append({"channel": n, "case": labels[j] if labels is not None else str(j + 1),
                                "status": v["status"], "error_kgf": v["error_kgf"],
                                "sensitivity": v["sensitivity"]})
        out = {"statuses": counts, "not_learning": why}
        if self.stretch:
            out["stretched_segments"] = {str(k + 1): f for k, f in sorted(self.stretch.items())}
        return out

    def commanded(self, programme):
        """The programme to command for ``programme`` (a
        :class:`~loading.programme.Programme`): every channel's turning points moved by its
        corrections, and on a station's load cases each segment's shape added."""
        out = programme.with_levels(self.levels(programme))
        if not (programme.load_cases and programme.n > 1) or not any(c.shapes for c in self.channels.values()):
            return out
        offsets = []
        for n, p in zip(out.names, out.channels):
            try:
                offsets.append(self.channels[n].offsets(p))
            except ParameterError as exc:
                raise ParameterError(f"channel {n}: {exc}") from None
        return out.with_offsets(offsets)

    def to_toml(self) -> str:
        if self.names == [STAND]:
            return self.channels[STAND].to_toml()
        out = [f"# {STATION_SCHEMA}: peak/valley corrections learned by `stand load --rig`, per channel"]
        if self.stretch:
            out += ["", "# the segment from load case K to K + 1 runs this many times its duration", "[stretch]"]
            out += [f'"{k + 1}" = {f!r}' for k, f in sorted(self.stretch.items())]
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
        try:
            out.stretch = {int(k) - 1: float(v) for k, v in (data.get("stretch") or {}).items()}
        except (TypeError, ValueError, AttributeError) as exc:
            raise ParameterError(f"{path}: [stretch]: {exc}") from None
        if any(k < 0 or not (math.isfinite(f) and 1.0 <= f <= STRETCH_MAX) for k, f in out.stretch.items()):
            raise ParameterError(f"{path}: [stretch] keys are segments from 1, each factor from 1 to {STRETCH_MAX:g}")
        return out
