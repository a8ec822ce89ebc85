"""Glitches in the force reading: one to three samples far off the trend, which then resumes.

A dynamometer channel picks up electrical interference, and a bus can carry a corrupted value;
either shows as a sample (or a few) hundreds of kgf away from its neighbours. The force of a
hydraulic stand cannot jump and come back within milliseconds, so such a blip is not plant
behaviour. Left in, one 300 kgf glitch per thousand samples made every model look 4.6× worse
than the noise allows (`stand diagnose` then said "unexplained" about a perfect model).

A block of ``w`` samples (w = 1, 2, 3) is a glitch when every sample in it is off, on the same
side, by more than :data:`THRESHOLD` robust spreads both from the line through the two samples
before the block and from the line through the two samples after it, and the trend before it
resumes after it. A corner of the force (a reversal) lies on the incoming line and on the
outgoing one, and a step (an offset jump) does not come back: neither is touched. Glitches
are replaced by the straight line between their neighbours, and counted in the record's notes.

The spread is the robust standard deviation (1.4826·MAD) of the second differences, which is
also the standard deviation of a two-point extrapolation's error under white noise (√6·σ).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a glitch sample is at least this many robust spreads of the second differences off both
#: extrapolations (8 × √6·σ ≈ 20σ: never reached by Gaussian noise)
THRESHOLD = 8.0
#: longest glitch handled, samples
MAX_WIDTH = 3
#: passes over the record at most (a pass finds no more glitches: done)
ROUNDS = 4


@dataclass
class Glitches:
    count: int = 0              #: glitches replaced
    samples: int = 0            #: samples replaced
    largest_kgf: float = 0.0    #: the largest deviation from the trend
    threshold_kgf: float = 0.0  #: the deviation it took to count

    def note(self) -> str:
        return (f"replaced {self.count} glitch(es) in the force ({self.samples} samples, "
                f"{self.threshold_kgf:.3g} kgf or more off the trend on both sides, the largest "
                f"{self.largest_kgf:.3g} kgf) by straight lines between their neighbours")


def remove_glitches(y: np.ndarray) -> tuple[np.ndarray, Glitches]:
    """``y`` with its glitches replaced (a copy if any were found), and what was replaced."""
    y = np.asarray(y, float)
    found = Glitches()
    if len(y) < 2 * MAX_WIDTH + 4:
        return y, found
    d2 = np.diff(y, 2)
    spread = 1.4826 * float(np.median(np.abs(d2 - np.median(d2))))
    if spread == 0.0:   # quantized and mostly flat: one resolution step stands in for the noise
        steps = np.abs(np.diff(y))
        steps = steps[steps > 0]
        if not len(steps):
            return y, found
        spread = float(steps.min())
    thr = THRESHOLD * spread
    found.threshold_kgf = thr
    out = y
    for _ in range(ROUNDS):   # glitches a few samples apart spoil each other's lines: go again
        before = found.count
        for w in range(1, MAX_WIDTH + 1):
            starts = _glitch_starts(out, w, thr)
            if not len(starts):
                continue
            if out is y:
                out = y.copy()
            last_end = -1
            for k in starts:
                if k <= last_end:      # overlaps one just replaced
                    continue
                a, b = out[k - 1], out[k + w]
                line = a + (b - a) * np.arange(1, w + 1) / (w + 1)
                found.largest_kgf = max(found.largest_kgf, float(np.max(np.abs(out[k:k + w] - line))))
                out[k:k + w] = line
                found.count += 1
                found.samples += w
                last_end = k + w + 1   # its neighbours' lines went through it
        if found.count == before:
            break
    return out, found


def _glitch_starts(y: np.ndarray, w: int, thr: float) -> np.ndarray:
    """Indices ``k`` where ``y[k:k+w]`` is a glitch (see the module text)."""
    n = len(y)
    k = np.arange(2, n - w - 1)
    before_slope = y[k - 1] - y[k - 2]
    after_slope = y[k + w + 1] - y[k + w]
    sign = None
    ok = np.ones(len(k), bool)
    for j in range(w):
        back = y[k + j] - (y[k - 1] + (j + 1) * before_slope)
        fwd = y[k + j] - (y[k + w] - (w - j) * after_slope)
        s = np.sign(back)
        sign = s if sign is None else sign
        ok &= (np.abs(back) > thr) & (np.abs(fwd) > thr) & (np.sign(fwd) == s) & (s == sign)
    # the trend before the block resumes after it
    rejoin = y[k + w] - (y[k - 1] + (w + 1) * before_slope)
    ok &= np.abs(rejoin) <= thr * w
    return k[ok]
