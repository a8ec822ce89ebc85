r"""The steady parts of a rig run: stretches over which every channel's delayed command is
constant and no channel is inside its transitional window after a reversal.

With ``dy_i/dt = Σ_j G_ij·w_j(t − τ_j) + Δ_i`` (``plant.rig``) and ``w_j = u_j`` away from
channel j's reversals (the paper's main portions: the reversal boost acts on ``w_j`` only in a
short window after each reversal of channel j's rod), every channel's force is a straight line
over such a stretch, of slope

.. math::  s_{i,p} = \sum_j G_{ij}\, u_{j,p} + \Delta_i                                   \tag{2'}

(``u_{j,p}``: channel j's command, τ_j before, over stretch p): eq. (2) of the paper with a
matrix gain. A change of channel j's command at sample e reaches the forces at ``t_e + τ_j``;
samples within ``margin`` of that time are left out (the fractional delay, a valve's own
smoothing, an error in τ̂), and after a *reversal* (the sign of the command turns, a zero
keeping the last direction as the rod does) the ``guard`` after it too.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from core.errors import DataError

from .record import RigRecord

#: samples left out around the time each command change reaches the forces, s
MARGIN_S = 0.02
#: the guard after a reversal is this many times the channel's transitional window (the time
#: its boost takes to add 90 % of its extra force, 2.3 decay times for an exponential one): the
#: boost is down to 1e-4 of itself there (factor 2: G 0.1-0.3 % high on a 2 kgf-noise rig, 10
#: times its interval; 3: 0.03-0.05 %; 4: within the intervals)
GUARD_FACTOR = 4.0
#: the guard of the first look (before the others' part is taken off each force and the
#: channels' own transitional windows can be read), and where no boost is found, s
FIRST_GUARD_S = 0.5
#: shortest steady stretch used, s
MIN_STRETCH_S = 0.1
#: a command that changes on more than this share of samples is not a meander (a closed loop)
MAX_CHANGE_SHARE = 0.05




def delayed(u: np.ndarray, dt: float, tau_s: float) -> np.ndarray:
    """``u(t − τ)`` at the samples (the command held before the record at its first value),
    τ rounded to whole samples."""
    m = int(round(tau_s / dt))
    if m <= 0:
        return np.asarray(u, float).copy()
    return np.concatenate([np.full(m, u[0]), u[:-m]])


def command_events(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The samples where the command changes, and whether each change is a reversal (the sign
    turns against the last non-zero command's; a change from zero after a long hold in the same
    direction is not; the first non-zero command of a record counts as one: the rod's direction
    before it is unknown). A record that starts at a non-zero command starts with such an
    event at sample 0: a meander started from a valve held the other way (after a trip, or
    a load's hold) reverses the rod there, and its boost would bias the slopes after it."""
    u = np.asarray(u, float)
    change = np.flatnonzero(np.diff(u) != 0) + 1
    if len(u) and u[0] != 0:
        change = np.concatenate([[0], change])
    reversal = np.zeros(len(change), bool)
    last = 0.0
    for k, e in enumerate(change):
        s = np.sign(u[e])
        if s != 0:
            reversal[k] = s != last
            last = s
    return change, reversal


def steady_mask(u: np.ndarray, dt: float, tau_s: Sequence[float], guard_s: Sequence[float],
                margin_s: float, usable: np.ndarray | None = None) -> np.ndarray:
    """Samples (K,) on the steady parts of a run with commands ``u`` (N, K): see the module
    docstring. ``usable``: samples allowed at all (the open-loop part); the first ``max τ +
    margin`` are left out (the commands before the record are unknown)."""
    u = np.atleast_2d(np.asarray(u, float))
    N, K = u.shape
    keep = np.ones(K, bool) if usable is None else np.asarray(usable, bool).copy()
    margin = max(1, int(np.ceil(margin_s / dt)))
    head = int(np.ceil(max(tau_s) / dt)) + margin
    keep[:min(K, head)] = False
    for j in range(N):
        lag = int(round(tau_s[j] / dt))
        guard = int(np.ceil(guard_s[j] / dt))
        changes, reversal = command_events(u[j])
        for e, rev in zip(changes, reversal):
            at = e + lag
            keep[max(0, at - margin):min(K, at + margin + (guard if rev else 0) + 1)] = False
    return keep


def stretches(mask: np.ndarray, min_samples: int) -> list[tuple[int, int]]:
    """``(start, stop)`` of the runs of True in ``mask`` at least ``min_samples`` long."""
    z = np.concatenate([[0], np.asarray(mask, np.int8), [0]])
    edges = np.flatnonzero(np.diff(z))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2]) if b - a >= min_samples]


def moving_channels(rec: RigRecord) -> list[int]:
    """The channels whose command reverses at least twice (a meander) where the run is open
    loop; :class:`DataError` for a command that is not piecewise constant there."""
    usable = open_loop(rec)
    out = []
    for j, u in enumerate(rec.u):
        changes = np.flatnonzero(np.diff(u) != 0) + 1
        changes = changes[usable[changes]]
        if len(changes) > MAX_CHANGE_SHARE * max(1, usable.sum()):
            raise DataError(f"{rec.source}: channel {rec.names[j]}'s command changes on "
                            f"{len(changes)} of {int(usable.sum())} open-loop samples: the rig "
                            "estimate needs open-loop meanders (commands held between reversals)")
        _, rev = command_events(np.where(usable, u, 0.0))
        if rev.sum() >= 3:        # the first non-zero command counts as one
            out.append(j)
    return out


def open_loop(rec: RigRecord) -> np.ndarray:
    """Samples where no channel has a reference (a set-point approach is a closed loop)."""
    return ~np.any(np.isfinite(rec.r), axis=0)


def others_off(rec: RigRecord, j: int, G: np.ndarray, taus: Sequence[float],
               moving: Sequence[int]) -> np.ndarray:
    """Channel ``j``'s force with the other moving channels' part taken off,
    ``y_j − Σ_{k≠j} G_jk ∫u_k(t − τ_k) dt``: its own turns and boost are left."""
    y = rec.y[j].copy()
    for k in moving:
        if k != j and np.isfinite(G[j, k]):
            uk = delayed(rec.u[k], rec.dt, taus[k])
            y -= G[j, k] * np.concatenate([[0.0], np.cumsum(uk[:-1])]) * rec.dt
    return y
