r"""A force held at a hydraulic limit: stretches the model must not be asked to explain.

A relief valve, a stroke end or the stand's pressure limit stops the force at a level for
seconds while the valve command keeps pushing; the dynamometer's noise stays on top, so it is
not the dynamometer's flat clip (:func:`clipped_mask`, left out too, with a note of its own). No effect of the plant
model should bend to explain it: the diagnosis would add wrong effects (a direction-dependent
delay, a load-pressure law) and call the rest unexplained. Such stretches are left out of the
error like clipped readings (the command history runs on through them) and said in a note.

A stretch is taken for a limit when, while the command pushes one way (``|u| >= push_pct`` of
one sign):

* the force stays within a band of ``BAND_SIGMAS`` times its noise (estimated robustly from
  second differences) over windows of ``hold_s`` (0.1 s) around it, and
* the force **arrived** there moving that way under the same command and stopped: in the
  ``hold_s`` (0.1 s) before, the command pushed the same way and the force moved by several
  bands toward the level; had it gone on at that rate it would have moved ``ARRIVAL_BANDS``
  bands further while held (so the hold may be short: a meander's force that reaches the limit
  just before the command turns is held for a few tens of ms under the push, then for the
  delay after the turn); while held it moves at most a tenth as fast (a slow ramp that goes on
  is not held), under a command at least half the arrival's (a command that eased off into a
  dead zone is not pushing). A hold from the record's very start (a relay asked for a force
  beyond the limit) counts when it lasts ten times ``hold_s`` and the force leaves the level
  once the command lets go;
* the force stays at the level as long as the command pushes, and does not go on past it after
  (a limit cannot be passed, nor left while pushed against; a force that only paused, an
  oscillation on top of a ramp cancelling its rise for a moment, does both).

The held stretch runs on while the force stays at the level after the command turns (the
delay and the valve's lag still push). The arrival tells a limit from what looks alike: a dead
zone holds the force wherever it was when the command became small (it did not arrive moving),
a rod that sticks after a reversal was moving the other way, a hold at zero command does not
push, and a meander's corner is never flat while the command still pushes (the force rises at
full rate until the turn has come through the delay).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter1d, minimum_filter1d

#: the window of flatness and of the arrival, s: the force stays within its band over windows
#: this long, and must have moved toward the level over the one before
HOLD_S = 0.1
#: the command must push at least this much, %
PUSH_PCT = 0.5
#: the flat band, in noise standard deviations (peak to peak of Gaussian noise over a second of
#: samples is about 6-7 sigma)
BAND_SIGMAS = 9.0
#: the force must have arrived moving by at least this many bands over ``HOLD_S``, and at that
#: rate would have moved this many bands further while held
ARRIVAL_BANDS = 3.0
#: ... and stopped there: its rate while held at most this share of its rate before
STOP_SHARE = 0.1
#: ... under a command at least this share of the arrival's (the median of |u|)
PUSH_SHARE = 0.5
#: a hold from the record's start (arrival unknown) counts when this many ``HOLD_S`` long
ARRIVAL_HOLDS = 10


@dataclass(frozen=True)
class HeldStretch:
    start: int            #: first sample
    stop: int             #: one past the last sample
    level_kgf: float
    command_pct: float    #: the median command while held
    t0_s: float
    t1_s: float

    def describe(self) -> str:
        way = "up" if self.command_pct > 0 else "down"
        return (f"force held at {self.level_kgf:.0f} kgf from t = {self.t0_s:.2f} to {self.t1_s:.2f} s "
                f"while the command pushed {way} ({self.command_pct:+.1f} %)")


def noise_sigma(y: np.ndarray) -> float:
    """The force reading's noise, from the median absolute second difference (robust to ramps
    and reversals): a white noise of σ has second differences of σ·√6."""
    if len(y) < 5:
        return 0.0
    d2 = np.diff(np.asarray(y, float), 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def held_stretches(u: np.ndarray, y: np.ndarray, dt: float, hold_s: float = HOLD_S,
                   push_pct: float = PUSH_PCT) -> list[HeldStretch]:
    """The stretches of a record where the force is held at a limit (module docstring)."""
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    w = int(round(hold_s / dt))
    n = len(y)
    if w < 5 or n < 2 * w:
        return []
    wf = w | 1                       # odd: the flat windows are centred on their sample
    band = max(BAND_SIGMAS * noise_sigma(y), 1.0)
    centres = (maximum_filter1d(y, wf) - minimum_filter1d(y, wf)) <= band
    flat = maximum_filter1d(centres.astype(np.uint8), wf).astype(bool)   # every sample of a flat window
    spans = []
    for sign in (1.0, -1.0):         # the part of a flat stretch under a push one way
        held = flat & (u * sign >= push_pct)
        edges = np.flatnonzero(np.diff(np.r_[0, held.astype(np.int8), 0]))
        spans += [(a, b, sign) for a, b in zip(edges[::2], edges[1::2])]
    out = []
    for a, b, sign in sorted(spans):
        seg = y[a:b]
        if b - a < 5 or max(np.mean(seg == seg.max()), np.mean(seg == seg.min())) > 0.5:
            continue        # too short to tell; or the dynamometer's flat clip (clipped_mask)
        if a < w:
            # held from the record's start: how it got there is unknown; a long hold under a
            # push is taken for a limit (a relay or a loop asked for a force beyond it)
            if b - a < ARRIVAL_HOLDS * w:
                continue
            if b < n:       # it must leave the level once the command lets go (a dead zone does not)
                level = float(np.median(seg))
                after = y[b:min(n, b + 2 * w)]
                if (level - after.min() if sign > 0 else after.max() - level) < ARRIVAL_BANDS * band:
                    continue
        else:
            before = slice(a - w, a)
            rate_before = _slope(y[before], dt) * sign
            arrived = (np.all(u[before] * sign >= push_pct)
                       and rate_before * min(w, b - a) * dt >= ARRIVAL_BANDS * band
                       and abs(_slope(seg, dt)) <= STOP_SHARE * rate_before
                       and np.median(np.abs(u[a:b])) >= PUSH_SHARE * np.median(np.abs(u[before])))
            if not arrived:
                continue
        level = float(np.median(seg))
        if b < n and (u[b] * sign >= push_pct or (y[b:b + w] * sign).max() > level * sign + band):
            continue        # it left the level while pushed, or went on past it: not a limit
        command = float(np.median(u[a:b]))
        # the force stays at the level for the delay after the command turns: still held
        while b < n and abs(y[b] - level) <= band / 2:
            b += 1
        out.append(HeldStretch(int(a), int(b), level, command, float(a * dt), float(b * dt)))
    return out


def clipped_mask(y: np.ndarray, run: int = 5) -> np.ndarray:
    """Samples where the dynamometer sits at the record's extreme value for ``run`` or more
    samples in a row: a reading clipped at its range (the true force is unknown there)."""
    y = np.asarray(y, float)
    mask = np.zeros(len(y), bool)
    if not len(y):
        return mask
    for extreme in (y.max(), y.min()):
        at = np.isclose(y, extreme, rtol=0, atol=1e-9 * max(1.0, abs(extreme)))
        edges = np.flatnonzero(np.diff(np.r_[0, at.astype(np.int8), 0]))
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a >= run:
                mask[a:b] = True
    return mask


def clipped_note(t: np.ndarray, y: np.ndarray, mask: np.ndarray) -> str:
    """What a record's note says of its readings clipped at the dynamometer's range."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    starts = edges[::2]
    levels = " and ".join(f"{v:+.0f}" for v in sorted({float(y[a]) for a in starts}))
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    return (f"force reading clipped at the dynamometer's range ({levels} kgf) in {len(starts)} "
            f"stretch(es), {mask.sum() * dt:.3g} s in all from t = {t[starts[0]] - t[0]:.2f} s: the "
            "true force is unknown there, left out of the model's error (to keep such stretches, "
            "load within the range: a smaller command or reference)")


def _slope(x: np.ndarray, dt: float) -> float:
    """Least-squares slope of ``x`` per second."""
    k = np.arange(len(x)) - (len(x) - 1) / 2
    return float(np.dot(k, x - x.mean()) / np.dot(k, k) / dt) if len(x) > 1 else 0.0


def held_mask(u: np.ndarray, y: np.ndarray, dt: float) -> np.ndarray:
    """True where the force is held at a limit."""
    mask = np.zeros(len(y), bool)
    for s in held_stretches(u, y, dt):
        mask[s.start:s.stop] = True
    return mask
