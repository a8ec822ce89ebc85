r"""Meander periods that let one simultaneous run tell the channels apart.

In a simultaneous run every channel j is a square wave ``±u0_j`` of its own period ``P_j``, and
G's row i is the regression of channel i's force rate on all the (delayed) commands (eq. (2'),
:mod:`.steady`). The columns are told apart when the commands are not collinear; how far from it
is each column's variance inflation (its interval is √VIF times what it would be if the
commands were orthogonal, :func:`.regression.collinearity`). Two square waves:

* of **equal periods** are the same wave: in phase fully collinear (refused), a quarter period
  apart orthogonal;
* whose ratio is one of **odd numbers**, ``P_a/P_b = p/q`` (lowest terms, both odd), share the
  odd harmonics ``p/P_a = q/P_b``…: over their common period their correlation is ``1/(p·q)``
  (1:3 → 1/3, VIF 1.13), whatever the run's length;
* otherwise (the powers of two in ``P_a`` and ``P_b`` differ) are **orthogonal over their common
  period**, and over a shorter run correlated only by the beat not yet averaged out: 8 and 8.1 s
  over 48 s are 85 % correlated (VIF 3.6), over 360 s, a third of their 649 s beat, 9 %.

The estimator leaves out a guard after every reversal (4 times the channel's transitional
window: 1.4 s for a boost decaying in 0.15 s); half periods only a few times that long lose
whole phases of the pattern to the guards: 8, 10, 12 and 15 s over 120 s planned a VIF of 1.00
and measured 3.2 on the steady parts, 12, 15, 18 and 22.5 s 1.9. So: half periods several times
the guard, then a good set gives every channel a period with its own power of two, all within a
factor of two of each other (each has about as many reversals), far enough apart that the run
lasts at least about one beat
``1/|1/P_a − 1/P_b|`` of every pair: four channels from 8 s get 8, 10, 12 and 15 s (``2³, 2·5,
2²·3, 3·5``; beats 17-60 s; over 120 s every VIF ≤ 1.01), from 12 s 12, 15, 18 and 22.5 s.
:func:`separating_periods` gives such
a set, :func:`sharing_pairs` names the pairs of a set that share harmonics, and
:func:`planned_inflation` says what a plan gives before it is run.

The plan is a design; what decides is the data: the estimator measures each column's variance
inflation on the run's steady parts and refuses a run that cannot separate two columns.
"""
from __future__ import annotations

import math
from fractions import Fraction
from typing import Sequence

from core.errors import ParameterError

from .regression import inflation


def _two_power(x: Fraction) -> int:
    """The power of two in a positive rational."""
    k = 0
    num, den = x.numerator, x.denominator
    while num % 2 == 0:
        num //= 2
        k += 1
    while den % 2 == 0:
        den //= 2
        k -= 1
    return k


def shares_harmonics(period_a_s: float, period_b_s: float) -> bool:
    """True if square waves of these periods share an odd harmonic (their ratio is a ratio of
    odd numbers), to the millisecond."""
    a = Fraction(round(period_a_s * 1000), 1)
    b = Fraction(round(period_b_s * 1000), 1)
    return _two_power(a / b) == 0


def sharing_pairs(periods_s: Sequence[float]) -> list[tuple[int, int]]:
    """The pairs (indices) of a set of periods whose square waves share harmonics."""
    return [(i, j) for i in range(len(periods_s)) for j in range(i + 1, len(periods_s))
            if shares_harmonics(periods_s[i], periods_s[j])]


def separating_periods(n: int, shortest_s: float = 8.0, cycle_s: float = 0.002) -> list[float]:
    """``n`` periods from ``shortest_s`` up to below twice it whose square waves are pairwise
    orthogonal (module docstring): ``P_k = 2^k·o_k·unit`` for ``k = n−1 … 0`` with ``o_k`` odd,
    the unit ``shortest_s / 2^(n−1)`` rounded up to a whole number of ``2·cycle_s`` (so every
    half period is a whole number of control cycles). Each ``o_k`` is chosen, the fewest
    choices first, to keep the periods as far apart as it can (the largest smallest ratio to
    those already chosen: short beats). Four channels from 8 s: 8, 10, 12 and 15 s. Many
    channels need long periods (``2^(n−1)`` units): sixteen need at least 131 s at 2 ms;
    refused with that figure."""
    if n < 1:
        raise ParameterError(f"{n} channels: give at least one")
    step = 2 * cycle_s
    units = max(1, math.ceil(shortest_s / 2 ** (n - 1) / step - 1e-9))
    if 2 ** (n - 1) * units * step >= 2 * shortest_s:
        need = 2 ** (n - 1) * step
        raise ParameterError(
            f"{n} channels need periods with {n} different powers of two: at a {cycle_s * 1e3:g} "
            f"ms control period the shortest is at least {need:g} s (asked for {shortest_s:g} s); "
            "or identify G column by column (one meander per channel, the others at zero)")
    unit = units * step
    lo, hi = shortest_s / unit - 1e-9, 2 * shortest_s / unit
    chosen: list[int] = []
    for k in range(n - 1, -1, -1):
        first = math.ceil(lo / 2 ** k)
        options = [2 ** k * o for o in range(first | 1, math.ceil(hi / 2 ** k) + 1, 2)
                   if 2 ** k * o < hi]
        if not options:
            raise ParameterError(f"no period for the {n - k}th channel between {shortest_s:g} "
                                 f"and {2 * shortest_s:g} s: give a longer shortest period")
        chosen.append(max(options, key=lambda v: (min((abs(math.log(v / c)) for c in chosen),
                                                      default=0.0), -v)))
    return sorted(round(v * unit, 9) for v in chosen)


def planned_inflation(periods_s: Sequence[float], duration_s: float,
                      cycle_s: float = 0.002) -> list[float]:
    """Each channel's variance inflation (1: orthogonal) for square waves of ``periods_s`` run
    together for ``duration_s`` (as the gateway's meander starts them), the trend's constant
    column included: what a plan gives before the reversals' guards are cut out."""
    import numpy as np
    n = int(round(duration_s / cycle_s))
    t = np.arange(n) * cycle_s
    cols = [np.where(np.floor((t + p / 4) / (p / 2) + 1e-9) % 2 == 0, 1.0, -1.0)
            for p in periods_s]
    X = np.column_stack(cols + [np.ones(n)])
    M = X.T @ X
    d = np.sqrt(np.diag(M))
    return [float(v) for v in inflation(M / np.outer(d, d))[:len(periods_s)]]
