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
from typing import Sequence

import numpy as np

#: the excitations the one-run design offers (docs/rig.md, "G from one short run")
EXCITATIONS = ("hadamard",)
#: the name a one-run campaign's run gives its experiment (run.json), by which the estimate
#: knows it
EXPERIMENT = "one-run"
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
