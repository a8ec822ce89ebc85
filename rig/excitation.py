r"""The excitation that identifies a rig's G in one run: Hadamard meanders (issue 41).

Every channel's valve is a ±u0 meander, all channels switching on one common grid of slots of
``slot_s``; channel j's signs over the slots follow row j of a Hadamard matrix ``H`` (m × m,
entries ±1, ``H·Hᵀ = m·I``), each entry played as a *doublet*, ``+H_jk`` for a slot then ``−H_jk``
for the next:

.. math::  u_j(t) = u_{0,j}\,D_{j,s},\qquad D_{j,2k} = H_{jk},\quad D_{j,2k+1} = -H_{jk},
           \qquad s = \lfloor t / \text{slot} \rfloor .

Why this shape (docs/rig.md, "G from one short run"):

* **orthogonal columns**: over the ``2m`` slots the channels' sign sequences are orthogonal to
  each other and to a constant (each doublet sums to zero), so on one steady stretch per slot
  the least squares of each force's rate on the commands separates every column of G and the
  trend Δ with no variance inflation: every column is known as precisely as if its channel had
  moved alone for the whole run, whatever N (``m`` is the smallest Hadamard order ≥ N, so the
  run lasts ``2m`` slots: 32 for 16 channels);
* **few, long steady stretches**: the valves reverse only on the grid, so the reversal boost
  (the paper's transitional portion) is confined to the start of each slot, where the
  estimator leaves a guard out; the rest of the slot is a main portion of every channel (a
  multisine reverses at every zero crossing of every channel and puts most of the run inside
  the boosts);
* **a small swing**: a doublet brings each force back to where it started, so a force moves at
  most one slot's worth, ``max_k |Σ_j G_ij u0_j H_jk|·slot`` (:func:`swings_kgf`), about what
  a meander of period ``2·slot`` moves.

Hadamard matrices are built by Sylvester's doubling and Paley's construction from a prime
``q ≡ 3 (mod 4)`` (order ``q + 1``), and their Kronecker products with ``[[1, 1], [1, −1]]``:
every order up to 100 but 28, 36, 52, 56, 76, 92 and 100 (the next order that is built is
taken).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import stats

#: the excitations the one-run design offers (docs/rig.md, "G from one short run")
EXCITATIONS = ("hadamard",)
#: the largest Hadamard order built (a rig of more channels than this is refused)
MAX_ORDER = 256


def _is_prime(q: int) -> bool:
    return q > 1 and all(q % d for d in range(2, math.isqrt(q) + 1))


def _paley(q: int) -> np.ndarray:
    """Paley's construction I: order ``q + 1`` from the quadratic residues of a prime
    ``q ≡ 3 (mod 4)``."""
    residues = {(x * x) % q for x in range(1, q)}
    chi = np.array([0] + [1 if a in residues else -1 for a in range(1, q)])
    idx = np.arange(q)
    S = np.zeros((q + 1, q + 1), int)
    S[0, 1:] = 1
    S[1:, 0] = -1
    S[1:, 1:] = chi[(idx[None, :] - idx[:, None]) % q]
    return S + np.eye(q + 1, dtype=int)


def hadamard(n: int) -> np.ndarray | None:
    """A Hadamard matrix of order ``n`` normalised (first row and column all +1), or None when
    this module cannot build one (module docstring)."""
    if n == 1:
        return np.ones((1, 1), int)
    if n == 2:
        return np.array([[1, 1], [1, -1]])
    if n < 1 or n % 4:
        return None
    H = None
    if _is_prime(n - 1) and (n - 1) % 4 == 3:
        H = _paley(n - 1)
    else:
        half = hadamard(n // 2)
        if half is not None:
            H = np.kron(np.array([[1, 1], [1, -1]]), half)
    if H is None:
        return None
    H = H * H[:, :1]
    return H * H[:1, :]


def hadamard_order(channels: int) -> int:
    """The smallest order ``m ≥ channels`` a Hadamard matrix is built for."""
    if channels < 1:
        raise ValueError(f"{channels} channels: a rig has at least one")
    m = channels
    while m <= MAX_ORDER:
        if hadamard(m) is not None:
            return m
        m += 1
    raise ValueError(f"{channels} channels: the one-run design is built for at most "
                     f"{MAX_ORDER} channels")


def hadamard_signs(channels: int, repeats: int = 1) -> np.ndarray:
    """Each channel's sign (±1) in each slot, ``(channels, 2·m·repeats)``: rows of the Hadamard
    matrix of order ``m = hadamard_order(channels)`` as doublets (module docstring), the pattern
    played ``repeats`` times."""
    if repeats < 1:
        raise ValueError(f"repeats {repeats}: at least 1")
    m = hadamard_order(channels)
    H = hadamard(m)[:channels]
    D = np.repeat(H, 2, axis=1) * np.tile([1, -1], m)[None, :]
    return np.tile(D, (1, repeats)).astype(int)


def swings_kgf(G: np.ndarray, amplitudes_pct: Sequence[float], signs: np.ndarray,
               slot_s: float) -> np.ndarray:
    """Each channel's largest excursion of force from where the run starts (kgf), trends left
    out: ``max_s |Σ_{s' ≤ s} Σ_j G_ij u0_j D_{j,s'}|·slot`` (the force is linear within a slot,
    so its extremes fall on the grid)."""
    G = np.asarray(G, float)
    rates = G @ (np.asarray(amplitudes_pct, float)[:, None] * signs)     # (N, slots), kgf/s
    walk = np.cumsum(rates, axis=1) * slot_s
    return np.max(np.abs(walk), axis=1) if walk.size else np.zeros(G.shape[0])


# ------------------------------------------------------------------------------------------
# the plan: how long the run must be for the accuracy asked
# ------------------------------------------------------------------------------------------
#: the spread of the channels' delays the plan allows for, s (every command change must have
#: reached the forces before a stretch starts, and none of the next may have)
DELAY_SPREAD_S = 0.05
#: the fewest degrees of freedom of each row's intervals (stretches less unknowns): the pattern
#: is repeated until a row has them (a rig of 16 channels has 32 - 17 = 15 in one pattern)
MIN_DOF = 8
#: the shortest steady stretch per slot the plan gives (room for a transitional window a little
#: longer than assumed; the estimator needs 0.1 s), s
MIN_STEADY_S = 0.2


@dataclass
class OneRunDesign:
    """A planned one-run excitation (:func:`plan_one_run`): what runs and what it promises."""

    channels: int
    amplitude_pct: list[float]          #: each channel's u0, %
    slot_s: float                       #: the grid's step, a whole number of control periods
    repeats: int                        #: the Hadamard pattern played this many times
    order: int                          #: the Hadamard matrix's order m (2·m slots a pattern)
    #: what the estimate leaves out after each slot's reversals (its guard, the delays' spread
    #: and the margins), s; the rest of each slot is a steady stretch of every force
    left_out_s: float
    steady_s: float
    #: the half-width, % of the smallest diagonal entry of G, within which every entry of G is
    #: planned to lie, all N² at once at ``level``, for ``noise_kgf`` (NaN: G unknown)
    planned_pct: float
    requested_pct: float | None         #: the accuracy asked (None: not asked)
    noise_kgf: float
    smallest_g: float                   #: the smallest diagonal entry of G, kgf/(%·s)
    level: float = 0.95
    excitation: str = "hadamard"

    @property
    def slots(self) -> int:
        return 2 * self.order * self.repeats

    @property
    def duration_s(self) -> float:
        return self.slots * self.slot_s

    def signs(self) -> np.ndarray:
        return hadamard_signs(self.channels, self.repeats)


def standard_error(steady_s: float, slots: int, amplitude_pct: float, noise_kgf: float,
                   dt: float) -> float:
    """Each entry of G's standard error (kgf/(%·s)) from one steady stretch of ``steady_s`` per
    slot with white noise ``noise_kgf``: ``σ / (u0·√(Σ_p Σ_k (t_k − t̄_p)²))`` (the orthogonal
    design: as if the channel had moved alone for every slot)."""
    n = max(2, int(steady_s / dt))
    weight = dt * dt * n * (n * n - 1) / 12.0
    return noise_kgf / (amplitude_pct * math.sqrt(slots * weight))


def _half_width_pct(steady_s: float, slots: int, unknowns: int, amplitude_pct: float,
                    noise_kgf: float, smallest_g: float, dt: float, level: float) -> float:
    """The planned half-width (% of ``smallest_g``) of every entry at once: the
    :func:`standard_error` times Student t with ``slots − unknowns`` degrees of freedom at the
    Bonferroni level over the ``(unknowns − 1)²`` entries."""
    se = standard_error(steady_s, slots, amplitude_pct, noise_kgf, dt)
    entries = (unknowns - 1) ** 2
    t = stats.t.ppf(1 - (1 - level) / (2 * entries), slots - unknowns)
    return 100.0 * t * se / smallest_g


def plan_one_run(channels: int, amplitude_pct: float | Sequence[float], period_s: float,
                 left_out_s: float, noise_kgf: float, smallest_g: float | None,
                 accuracy_pct: float | None = None, duration_s: float | None = None,
                 level: float = 0.95) -> OneRunDesign:
    """The one-run excitation's slot and length (module docstring).

    Each slot is ``left_out_s`` (the estimate's guard after a reversal, the delays' spread,
    the margins) plus a steady stretch. Without ``duration_s`` the stretch is the shortest
    (at least :data:`MIN_STEADY_S`) that puts every entry of G within ``accuracy_pct`` % of
    ``smallest_g`` at once (:func:`_half_width_pct`; its noise ``noise_kgf``, white, nothing
    else unmodelled); with it the slot is what that length gives, and ``accuracy_pct`` is
    checked against it. The pattern is played until each row has :data:`MIN_DOF` degrees of
    freedom. :class:`ValueError` says what does not fit."""
    amps = [float(a) for a in np.broadcast_to(np.asarray(amplitude_pct, float), (channels,))]
    order = hadamard_order(channels)
    repeats = max(1, math.ceil((channels + 1 + MIN_DOF) / (2 * order)))
    slots = 2 * order * repeats
    u0 = min(amps)
    known = smallest_g is not None and math.isfinite(smallest_g) and smallest_g > 0

    def planned(steady: float) -> float:
        return (_half_width_pct(steady, slots, channels + 1, u0, noise_kgf, smallest_g,
                                period_s, level) if known else math.nan)

    def slot_for(steady: float) -> float:
        return math.ceil((left_out_s + steady) / period_s - 1e-9) * period_s

    if duration_s is None:
        steady = MIN_STEADY_S
        if accuracy_pct is not None and known and planned(steady) > accuracy_pct:
            lo, hi = steady, steady
            while planned(hi) > accuracy_pct:
                hi *= 2
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if planned(mid) > accuracy_pct else (lo, mid)
            steady = hi
        slot = slot_for(steady)
    else:
        slot = math.floor(duration_s / slots / period_s + 1e-9) * period_s
        need = slot_for(MIN_STEADY_S)
        if slot < need:
            raise ValueError(
                f"--duration-s {duration_s:g}: {channels} channels take {slots} slots (a Hadamard "
                f"pattern of order {order} as doublets{f', {repeats} times' if repeats > 1 else ''}), "
                f"each at least {need:.3g} s ({left_out_s:.3g} s left out after the reversals, "
                f"{MIN_STEADY_S:g} s steady): give at least {math.ceil(slots * need):d} s")
    steady = slot - left_out_s
    design = OneRunDesign(channels, amps, round(slot, 9), repeats, order, left_out_s, steady,
                          planned(steady), accuracy_pct, noise_kgf,
                          smallest_g if known else math.nan, level)
    if duration_s is not None and accuracy_pct is not None and known \
            and design.planned_pct > accuracy_pct:
        want = plan_one_run(channels, amps, period_s, left_out_s, noise_kgf, smallest_g,
                            accuracy_pct, None, level)
        raise ValueError(
            f"--duration-s {duration_s:g} gives every entry of G within ±{design.planned_pct:.2g} "
            f"% of the smallest diagonal ({noise_kgf:g} kgf noise), not the ±{accuracy_pct:g} % "
            f"asked: give --duration-s {math.ceil(want.duration_s):d} or more, or "
            f"--accuracy-pct {math.ceil(design.planned_pct * 10) / 10:g}")
    return design
