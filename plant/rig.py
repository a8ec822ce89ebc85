r"""A rig of N loading channels on one structure: the paper's model as a matrix.

.. math::  \dot y_i = \sum_j G_{ij}\, w_j(t - \tau_j) + \Delta_i + D_i(y_i, t)

``w_j`` is channel j's flow after its own valve and flow effects (the one-channel model's
``g·q·ΠG`` is ``G_jj·w_j``), ``G`` is N×N in kgf/(%·s): ``G_ii`` the paper's g of channel i,
``G_ij`` what channel j's flow does to channel i's force through the structure. Physically
``G = K·diag(c/A)``, ``K`` the structure's stiffness at the attachment points (symmetric
positive definite, kgf/mm) and ``c_j/A_j`` actuator j's flow gain over its piston area
(mm/(%·s)); :func:`physical_check` says whether a G can be that (../shared/notes/rig.md).

Each channel is a :class:`~plant.model.PlantModel` of its own (delay, valve and flow effects,
trend, force terms, sensor) whose ``g`` is ``G_ii``. An uncoupled rig (G diagonal) simulates each
channel exactly as the one-channel model does, bit for bit; a coupled one steps the channels
together (:meth:`RigModel.advance`).

**A change of the structure** (:class:`StructureChange`: a crack at one attachment point from a
stand time on, at once or over a ramp) is a compliance in series with the structure at that
point, so the structure's flexibility ``C = K⁻¹`` gains ``δ_i`` on its diagonal:

.. math::  K' = (K^{-1} + \delta_i\,e_i e_i^T)^{-1},\qquad
           G' = K'\,\mathrm{diag}(c/A) = \Big(G^{-1} + \mathrm{diag}\big(\tfrac{1/f_i - 1}{G_{ii}}\big)\Big)^{-1}

with ``f_i = K'_ii/K_ii`` the change's ``stiffness_factor`` (``δ_i K_ii = 1/f_i − 1``). By
Sherman-Morrison ``K'_ij = f_i·K_ij`` for every j (the attachment's row and column, its own
stiffness included, times ``f_i``) and ``K'_jk = K_jk − (1 − f_i)·K_ji·K_ik/K_ii`` elsewhere (the
neighbours lose a little of their stiffness through the point: ``(1 − f)·0.09·K_jj`` at 30 %
coupling). In G the same: channel i's row and column times ``f_i``, ``G'_jk = G_jk − (1 −
f_i)·G_ji·G_ik/G_ii`` elsewhere. It needs no flow gains (``c/A`` drop out), so a rig given by G
alone takes it as well as one given by K; it stays symmetric positive definite (a compliance
added to a flexibility). Its consequence for a test: the flows that make a force change ``Δy``
are ``G'^{-1}Δy = G^{-1}Δy + (1/f_i − 1)·Δy_i/G_ii·e_i``, so *only channel i's valve* needs
more flow, ``(1/f_i − 1)`` of its own share, whatever the coupling (the end-point trends of
:mod:`endurance.trends` read it so). Several changes: each attachment's own stiffness is the
product of its changes' factors at that time (two of 0.97 make 0.9409), the attachments' added
compliances add.

The schedule counts on the **stand time**: the time the plant has advanced since it was made
(the emulator's since it started), not a run's clock, which restarts with each run
(:meth:`RigModel.advance`'s ``t_s``: the time of the block's first step; a step uses G at its
start, so a change at ``from_s`` acts from the first step that starts at ``from_s``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.signal import lfilter

from .model import Drive, PlantModel, PlantState
from .params import ModelError


# ------------------------------------------------------------------------------------------
# is there a structure behind G?
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PhysicalCheck:
    """Whether ``G = K·diag(c/A)`` with ``K`` symmetric positive definite and ``c/A > 0``.

    ``G_ij·d_j = G_ji·d_i`` with ``d_j = A_j/c_j``: the ratios of the flow gains follow from
    the pairs ``G_ij, G_ji``, and ``K = G·diag(d)`` (up to one scale per group of coupled
    channels) must then be symmetric positive definite."""

    physical: bool
    reason: str                   #: why not (empty when physical)
    #: ``d`` normalised to 1 on each group's first channel: A_j/c_j relative to it
    scales: np.ndarray = field(repr=False)
    #: ``G·diag(scales)``, symmetrised: the stiffness up to each group's unknown scale
    stiffness: np.ndarray = field(repr=False)
    #: largest |(G·D)_ij − (G·D)_ji| / max |G·D|: 0 for an exact structure (judged within
    #: bounds: what is left beyond them, ``t`` of :func:`_physical_within`)
    asymmetry: float
    #: smallest eigenvalue of the symmetrised ``G·D`` over the largest (> 0: positive definite)
    min_eigenvalue_ratio: float
    #: judged within bounds: the off-diagonal entries (row, column; 0-based) taken as zero,
    #: each pair whose two intervals both hold zero
    zeroed: tuple[tuple[int, int], ...] = ()
    #: judged within bounds: the asymmetry they allow the stiffness as a whole, a share of
    #: ``max |G·D|`` (NaN: judged exactly)
    allowed: float = math.nan

    def text(self) -> str:
        head = "physical" if self.physical else f"not physical: {self.reason}"
        return (f"{head} (asymmetry {100 * self.asymmetry:.2g} % after scaling, smallest "
                f"eigenvalue {self.min_eigenvalue_ratio:.3g} of the largest)")


def physical_check(G: np.ndarray, asymmetry_tol: float = 1e-6, lo: np.ndarray | None = None,
                   hi: np.ndarray | None = None) -> PhysicalCheck:
    """Is there a symmetric positive definite ``K`` and positive ``c/A`` with ``G = K·diag(c/A)``?
    (see :class:`PhysicalCheck`). ``asymmetry_tol``: how far from symmetric ``G·D`` may be
    (an emulated structure: numerical). An identified G carries intervals: with ``lo`` and
    ``hi`` (N×N, each entry's bounds) the question is whether some G within them is physical
    (:func:`_physical_within`), and ``asymmetry_tol`` is not used."""
    G = np.asarray(G, float)
    n = G.shape[0]
    if G.shape != (n, n) or not np.all(np.isfinite(G)):
        raise ModelError(f"G must be a square matrix of finite numbers, got shape {G.shape}")
    if lo is not None or hi is not None:
        return _physical_within(G, lo, hi)
    scales = np.ones(n)
    reasons: list[str] = []
    if np.any(np.diag(G) <= 0):
        bad = np.flatnonzero(np.diag(G) <= 0)
        reasons.append(f"G_ii <= 0 for channel(s) {', '.join(str(i + 1) for i in bad)}: a "
                       "channel's own flow must raise its own force")
    tiny = 1e-12 * max(np.max(np.abs(G)), 1e-300)
    for i in range(n):
        for j in range(i + 1, n):
            a, b = G[i, j], G[j, i]
            if (abs(a) <= tiny) != (abs(b) <= tiny):
                reasons.append(f"G[{i + 1},{j + 1}] = {a:g} but G[{j + 1},{i + 1}] = {b:g}: a "
                               "structure couples both ways or neither")
            elif abs(a) > tiny and np.sign(a) != np.sign(b):
                reasons.append(f"G[{i + 1},{j + 1}] = {a:g} and G[{j + 1},{i + 1}] = {b:g} have "
                               "opposite signs: a stiffness is symmetric, so they cannot")
    if not reasons:
        scales = _flow_gain_ratios(G, tiny)
    GD = G * scales[None, :]
    norm = float(np.max(np.abs(GD))) or 1.0
    asymmetry = float(np.max(np.abs(GD - GD.T))) / norm
    K = 0.5 * (GD + GD.T)
    eig = np.linalg.eigvalsh(K)
    ratio = float(eig[0] / eig[-1]) if eig[-1] > 0 else -math.inf
    if not reasons and asymmetry > asymmetry_tol:
        reasons.append(f"no flow gains make G·diag(A/c) symmetric: {100 * asymmetry:.2g} % "
                       "asymmetric at best (the products G_ij·G_jk·G_ki and G_ik·G_kj·G_ji of "
                       "three channels differ)")
    if not reasons and eig[0] <= 0:
        reasons.append(f"the stiffness behind G is not positive definite (smallest eigenvalue "
                       f"{ratio:.3g} of the largest): a load pattern would move the structure "
                       "with no force")
    return PhysicalCheck(not reasons, "; ".join(reasons), scales, K, asymmetry, ratio)


def _physical_within(G: np.ndarray, lo: np.ndarray | None, hi: np.ndarray | None) -> PhysicalCheck:
    r"""Is some G with ``lo ≤ G ≤ hi`` (entry by entry; a bound not given or not finite: none)
    physical? Every condition of :func:`physical_check`, each within the bounds:

    * a pair whose two intervals both hold zero is uncoupled: both are taken as zero (one taken
      as zero and the other not would be a structure that couples one way only);
    * any other pair couples both ways with one sign both intervals allow (its entry whose
      interval holds zero, weakly); a pair whose intervals reach no common sign cannot;
    * the flow-gain ratios ``d = A/c`` must make ``G'·diag(d)`` symmetric for some ``G'``
      within the bounds: pair (i, j) needs ``[lo_ij·d_j, hi_ij·d_j]`` and
      ``[lo_ji·d_i, hi_ji·d_i]`` (magnitudes, of the pair's sign) to meet, two inequalities
      linear in ``d``. A linear programme finds the ``d`` (each group of coupled channels'
      first at 1) that keeps the largest shortfall ``t`` smallest; ``t`` over the stiffness's
      scale ``max |G·D|`` is the asymmetry the intervals cannot absorb (the products of the
      entries around a loop of channels that differ, or a pair so lopsided that no flow gains
      of the other channels suit it). It must stay within what the intervals allow the
      stiffness as a whole, ``max (h_ij·d_j + h_ji·d_i) / max |G·D|`` (``h`` the half-widths:
      a pair off by less than the least precisely known pair is no sign of another structure);
      ``d`` is then the one nearest the estimate's own symmetry;
    * the stiffness ``K' = G'·diag(d)`` (each pair's entry within both intervals, nearest the
      estimate's mean) must be positive definite.
    """
    from scipy.optimize import linprog
    n = G.shape[0]

    def bound(b, fill):
        if b is None:
            return np.full((n, n), fill)
        b = np.asarray(b, float)
        if b.shape != (n, n):
            raise ModelError(f"bounds of G must be {n}x{n}, got shape {b.shape}")
        return np.where(np.isnan(b), fill, b)

    lo = np.minimum(bound(lo, -math.inf), G)
    hi = np.maximum(bound(hi, math.inf), G)
    reasons: list[str] = []
    bad = [i for i in range(n) if hi[i, i] <= 0]
    if bad:
        reasons.append(f"G_ii <= 0 within its interval for channel(s) "
                       f"{', '.join(str(i + 1) for i in bad)}: a channel's own flow must raise "
                       "its own force")
    G0 = G.copy()
    zeroed: list[tuple[int, int]] = []
    pairs = []          # (i, j, sign, |G'_ij| range, |G'_ji| range)
    for i in range(n):
        for j in range(i + 1, n):
            if lo[i, j] <= 0 <= hi[i, j] and lo[j, i] <= 0 <= hi[j, i]:
                G0[i, j] = G0[j, i] = 0.0
                zeroed += [(i, j), (j, i)]
                continue
            if hi[i, j] > 0 and hi[j, i] > 0:
                sign = 1.0
            elif lo[i, j] < 0 and lo[j, i] < 0:
                sign = -1.0
            else:
                reasons.append(f"G[{i + 1},{j + 1}] = {G[i, j]:.3g} and G[{j + 1},{i + 1}] = "
                               f"{G[j, i]:.3g} have opposite signs even within their intervals: "
                               "a stiffness is symmetric, so they cannot")
                continue
            mag = [(max(0.0, min(sign * lo[a, b], sign * hi[a, b])),
                    max(sign * lo[a, b], sign * hi[a, b])) for a, b in ((i, j), (j, i))]
            pairs.append((i, j, sign, mag[0], mag[1]))
    half = np.where(np.isfinite(hi - lo), 0.5 * (hi - lo), 0.0)
    if reasons:
        return _within_result(G, G0, np.ones(n), half, reasons, zeroed, pairs, 0.0)
    # each pair's two inequalities: ij_lo·d_j − ji_hi·d_i ≤ t, ji_lo·d_i − ij_hi·d_j ≤ t
    rows: list[np.ndarray] = []
    for i, j, _, (ij_lo, ij_hi), (ji_lo, ji_hi) in pairs:
        for a, b, a_lo, b_hi in ((j, i, ij_lo, ji_hi), (i, j, ji_lo, ij_hi)):
            if a_lo > 0 and math.isfinite(b_hi):
                r = np.zeros(n)
                r[a], r[b] = a_lo, -b_hi
                rows.append(r)
    bounds: list[tuple[float | None, float | None]] = [(1e-9, None)] * n
    for g in _groups(n, [p[:2] for p in pairs]):
        bounds[min(g)] = (1.0, 1.0)
    A = np.array(rows).reshape(len(rows), n)
    d, shortfall = np.ones(n), 0.0
    if rows:
        first = linprog(np.append(np.zeros(n), 1.0), A_ub=np.hstack([A, -np.ones((len(rows), 1))]),
                        b_ub=np.zeros(len(rows)), bounds=bounds + [(0.0, None)], method="highs")
        if first.status != 0:
            raise ModelError(f"the physical check's linear programme failed: {first.message}")
        d, shortfall = first.x[:n], float(first.x[n])
    # nearest the estimate's symmetry: minimise Σ |G_ij·d_j − G_ji·d_i| over the pairs whose
    # entries both have the pair's sign, the shortfall kept
    near = [(i, j) for i, j, sign, *_ in pairs if sign * G[i, j] > 0 and sign * G[j, i] > 0]
    if near:
        q = len(near)
        T = np.zeros((q, n))
        for k, (i, j) in enumerate(near):
            T[k, j], T[k, i] = G[i, j], -G[j, i]
        A2 = np.vstack([np.hstack([A, np.zeros((len(rows), q))]),
                        np.hstack([T, -np.eye(q)]), np.hstack([-T, -np.eye(q)])])
        b2 = np.concatenate([np.full(len(rows), shortfall * (1 + 1e-9) + 1e-12), np.zeros(2 * q)])
        second = linprog(np.concatenate([np.zeros(n), np.ones(q)]), A_ub=A2, b_ub=b2,
                         bounds=bounds + [(0.0, None)] * q, method="highs")
        if second.status == 0:
            d = second.x[:n]
    return _within_result(G, G0, d, half, reasons, zeroed, pairs, shortfall)


def _within_result(G: np.ndarray, G0: np.ndarray, d: np.ndarray, half: np.ndarray,
                   reasons: list[str], zeroed: list[tuple[int, int]], pairs: list,
                   shortfall: float) -> PhysicalCheck:
    """:func:`_physical_within`'s verdict: the shortfall against what the intervals allow, the
    stiffness within the bounds nearest the estimate (each pair's ``|K_ij|`` the mean of the
    two scaled entries, clipped into both intervals) and its smallest eigenvalue, the
    estimate's asymmetry after scaling."""
    n = G.shape[0]
    K = np.diag(np.maximum(np.diag(G), 0.0) * d)
    for i, j, sign, (ij_lo, ij_hi), (ji_lo, ji_hi) in pairs:
        a, b = max(ij_lo * d[j], ji_lo * d[i]), min(ij_hi * d[j], ji_hi * d[i])
        want = 0.5 * (max(sign * G[i, j], 0.0) * d[j] + max(sign * G[j, i], 0.0) * d[i])
        k = min(max(want, a), b) if a <= b else 0.5 * (a + b)
        K[i, j] = K[j, i] = sign * k
    norm = float(np.max(np.abs(G0 * d[None, :]))) or 1.0
    asymmetry = shortfall / norm
    hd = half * d[None, :]
    off = ~np.eye(n, dtype=bool)
    allowed = float(np.max((hd + hd.T)[off], initial=0.0)) / norm
    if not reasons and asymmetry > allowed:
        reasons.append(f"no flow gains make G·diag(A/c) symmetric within the intervals: "
                       f"{100 * asymmetry:.2g} % asymmetric at best beyond them, more than the "
                       f"{100 * allowed:.2g} % they allow (the products of the entries around a "
                       "loop of channels differ, or a pair couples one way far more than the "
                       "other channels' flow gains let it)")
    eig = np.linalg.eigvalsh(K) if n else np.zeros(1)
    ratio = float(eig[0] / eig[-1]) if eig[-1] > 0 else -math.inf
    if not reasons and eig[0] <= 0:
        reasons.append(f"the stiffness behind G is not positive definite within the intervals "
                       f"(smallest eigenvalue {ratio:.3g} of the largest): a load pattern would "
                       "move the structure with no force")
    return PhysicalCheck(not reasons, "; ".join(reasons), d, K, asymmetry, ratio,
                         tuple(zeroed), allowed)


def _groups(n: int, links: list[tuple[int, int]]) -> list[list[int]]:
    """The channels in groups joined by ``links`` (each channel alone when in none)."""
    parent = list(range(n))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for i, j in links:
        parent[find(i)] = find(j)
    out: dict[int, list[int]] = {}
    for i in range(n):
        out.setdefault(find(i), []).append(i)
    return list(out.values())


def _flow_gain_ratios(G: np.ndarray, tiny: float) -> np.ndarray:
    """``d`` with ``G_ij·d_j ≈ G_ji·d_i`` for every coupled pair: ``log d_j − log d_i =
    log(G_ji/G_ij)`` solved by least squares on each group of coupled channels, the group's
    first channel at 1."""
    n = G.shape[0]
    rows, rhs = [], []
    for i in range(n):
        for j in range(i + 1, n):
            if abs(G[i, j]) > tiny and abs(G[j, i]) > tiny:
                r = np.zeros(n)
                r[j], r[i] = 1.0, -1.0
                rows.append(r)
                rhs.append(math.log(G[j, i] / G[i, j]))
    # pin the first channel of each group at log d = 0
    group = list(range(n))

    def find(x: int) -> int:
        while group[x] != x:
            group[x] = group[group[x]]
            x = group[x]
        return x

    for r in rows:
        i, j = np.flatnonzero(r)
        group[find(int(i))] = find(int(j))
    for root in sorted({find(i) for i in range(n)}):
        first = min(i for i in range(n) if find(i) == root)
        r = np.zeros(n)
        r[first] = 1.0
        rows.append(r)
        rhs.append(0.0)
    logd, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
    return np.exp(logd)


# ------------------------------------------------------------------------------------------
# a change of the structure
# ------------------------------------------------------------------------------------------
#: a step starting this close before a change's ``from_s`` (s) counts as starting at it (stand
#: times are sums of steps: their rounding must not move a change by a step)
TIME_TOL_S = 1e-7


@dataclass(frozen=True)
class StructureChange:
    """The structure at channel ``channel``'s attachment point (G's row and column ``channel``)
    softens (``stiffness_factor`` < 1: a crack) or stiffens (> 1) to ``stiffness_factor`` of
    its own stiffness ``K_ii``: from the stand time ``from_s`` (s) at once (``ramp_s`` 0), or
    linearly in the factor over ``ramp_s`` (s) from then (the module docstring: what it does
    to K and G)."""

    channel: int
    stiffness_factor: float
    from_s: float
    ramp_s: float = 0.0

    def check(self, n: int) -> None:
        """:class:`ModelError` if the change cannot be made to a rig of ``n`` channels."""
        if not (isinstance(self.channel, (int, np.integer)) and 0 <= self.channel < n):
            raise ModelError(f"a structure change at channel index {self.channel!r}: the rig has "
                             f"{n} channel(s), 0 to {n - 1}")
        f = self.stiffness_factor
        if not (isinstance(f, (int, float)) and math.isfinite(f) and f > 0):
            raise ModelError(f"a structure change's stiffness_factor = {f!r} must be a finite "
                             "number > 0 (below 1 the attachment softens)")
        for name, v in (("from_s", self.from_s), ("ramp_s", self.ramp_s)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ModelError(f"a structure change's {name} = {v!r} must be a finite number "
                                 ">= 0 (s of stand time)")

    def share(self, t_s: np.ndarray) -> np.ndarray:
        """How much of the change is done at the stand times ``t_s`` (0 to 1)."""
        t = np.asarray(t_s, float)
        if self.ramp_s > 0:
            return np.clip((t - self.from_s) / self.ramp_s, 0.0, 1.0)
        return (t >= self.from_s - TIME_TOL_S).astype(float)

    def factor(self, t_s: np.ndarray) -> np.ndarray:
        """The attachment's stiffness over its intact one at the stand times ``t_s``."""
        return 1.0 - (1.0 - self.stiffness_factor) * self.share(t_s)

    @property
    def end_s(self) -> float:
        """When the change is complete (s of stand time)."""
        return self.from_s + self.ramp_s


def changed_structure(G: np.ndarray, factors: np.ndarray) -> np.ndarray:
    """``G`` with each attachment's own stiffness times ``factors[..., i]`` by a compliance in
    series there (module docstring): ``(G⁻¹ + diag((1/f − 1)/G_ii))⁻¹``, as one rank-one
    update per changed attachment (Sherman-Morrison: no inverse taken, the row and column of a
    single change exactly ``f`` times theirs); ``G`` itself where every factor is 1.
    ``factors``: (N,) gives (N, N); (K, N) gives (K, N, N)."""
    G = np.asarray(G, float)
    f = np.asarray(factors, float)
    if np.all(f == 1.0):
        return G if f.ndim == 1 else np.broadcast_to(G, f.shape[:1] + G.shape).copy()
    added = (1.0 / f - 1.0) / np.diag(G)           # δ_i·(c_i/A_i): the compliance, in G's units
    out = np.broadcast_to(G, f.shape[:-1] + G.shape).copy()
    for i in np.flatnonzero(np.any(f != 1.0, axis=tuple(range(f.ndim - 1)))):
        a = added[..., i, None, None]
        col, row = out[..., :, i:i + 1], out[..., i:i + 1, :]
        out = out - a * col * row / (1.0 + a * out[..., i:i + 1, i:i + 1])
    return out


# ------------------------------------------------------------------------------------------
# the rig's plant
# ------------------------------------------------------------------------------------------
class RigModel:
    """N channels' :class:`PlantModel`\\ s coupled by ``G`` (see the module docstring);
    ``changes``: the structure's scheduled changes (:class:`StructureChange`), on the stand
    time :meth:`advance` is given."""

    def __init__(self, channels: Sequence[PlantModel], G: np.ndarray | None = None,
                 names: Sequence[str] | None = None,
                 changes: Sequence[StructureChange] = ()) -> None:
        channels = list(channels)
        n = len(channels)
        if n == 0:
            raise ModelError("a rig needs at least one channel")
        if G is None:
            G = np.diag([m.g for m in channels])
        G = np.array(G, float)
        if G.shape != (n, n) or not np.all(np.isfinite(G)):
            raise ModelError(f"G must be {n}x{n} finite numbers for {n} channel(s), got shape "
                             f"{G.shape}")
        # each channel's own gain is G_ii
        self.channels = [m if m.g == G[i, i] else m.with_params({"g": float(G[i, i])})
                         for i, m in enumerate(channels)]
        self.G = G
        self.names = list(names) if names is not None else [f"ch{i + 1}" for i in range(n)]
        if len(self.names) != n:
            raise ModelError(f"{len(self.names)} names for {n} channels")
        self.coupling = G - np.diag(np.diag(G))
        self.coupled = bool(np.any(self.coupling != 0.0))
        self.changes = tuple(changes)
        for c in self.changes:
            c.check(n)
        if self.changes and np.any(np.diag(G) <= 0):
            raise ModelError("a structure change needs every G_ii > 0 (a channel's own flow "
                             "raises its own force)")
        #: channels whose models differ at most in g and Δ, each group's input side computed
        #: in one call of its trajectories (:meth:`_drives`)
        self.groups = drive_groups(self.channels)
        self._deltas = np.array([m.delta for m in self.channels], float)

    @property
    def n(self) -> int:
        return len(self.channels)

    def __repr__(self) -> str:
        return f"RigModel({', '.join(f'{n}: {m.spec}' for n, m in zip(self.names, self.channels))})"

    # -- the structure's schedule ----------------------------------------------------------------
    def factors(self, t_s: np.ndarray | float) -> np.ndarray:
        """Each attachment's stiffness over its intact one at the stand time(s) ``t_s``: (N,)
        for one time, (K, N) for K."""
        t = np.asarray(t_s, float)
        out = np.ones(t.shape + (self.n,))
        for c in self.changes:
            out[..., c.channel] *= c.factor(t)
        return out

    def structure_at(self, t_s: float) -> np.ndarray:
        """G at the stand time ``t_s`` (the intact :attr:`G` before any change)."""
        return changed_structure(self.G, self.factors(float(t_s)))

    @property
    def G_changed(self) -> np.ndarray:
        """G once every scheduled change is complete (:attr:`G` without changes)."""
        return self.structure_at(math.inf)

    def _gains_along(self, t_s: float | None, dt: float, K: int) -> np.ndarray | None:
        """G over a block of ``K`` steps from the stand time ``t_s``: None where every step has
        the intact G, (N, N) where all share one changed G, else (K, N, N) (a ramp or a change
        inside the block)."""
        if not self.changes:
            return None
        if t_s is None:
            raise ModelError("this rig's structure changes on a schedule: advancing it needs the "
                             "stand time of the block's first step (t_s)")
        f = self.factors(t_s + dt * np.arange(K))
        if np.all(f == 1.0):
            return None
        if np.all(f == f[:1]):
            return changed_structure(self.G, f[0])
        return changed_structure(self.G, f)

    def new_state(self, dt: float, y0: Sequence[float] | float = 0.0,
                  u0: Sequence[float] | float = 0.0, t0: float = 0.0) -> list[PlantState]:
        """Each channel's state (one trajectory each) at forces ``y0`` with commands ``u0``
        held before."""
        y0 = np.broadcast_to(np.asarray(y0, float), (self.n,))
        u0 = np.broadcast_to(np.asarray(u0, float), (self.n,))
        return [m.new_state(1, dt, y0[i], u0[i], t0) for i, m in enumerate(self.channels)]

    def advance(self, states: list[PlantState], u: np.ndarray, dt: float,
                t_s: float | None = None) -> np.ndarray:
        """Advance every channel by the command block ``u`` (N, K); returns the dynamometers'
        readings after each step (N, K). This is what the rig's emulator calls. ``t_s``: the
        stand time of the block's first step (needed only with scheduled :attr:`changes`)."""
        u = np.asarray(u, float)
        if u.shape[0] != self.n:
            raise ModelError(f"commands for {u.shape[0]} channels, the rig has {self.n}")
        gains = self._gains_along(t_s, dt, u.shape[1])
        if not self.coupled and gains is None and len(self.groups) == self.n:
            return np.concatenate([m.advance(st, u[i:i + 1], dt)
                                   for i, (m, st) in enumerate(zip(self.channels, states))])
        drives, grouped = self._drives(states, u, dt)
        y = self._integrate(drives, np.array([st.y[0] for st in states]), dt,
                            self.G if gains is None else gains, grouped)
        if not any(m.has_sensor_effects for m in self.channels):
            for i, st in enumerate(states):       # views: each row is its channel's own
                st.y = y[i, -1:]
                st.reading = st.y.copy()
            return y[:, 1:]
        out = np.empty((self.n, u.shape[1]))
        for i, (m, st) in enumerate(zip(self.channels, states)):
            traj = y[i:i + 1]
            st.y = traj[:, -1].copy()
            if m.has_sensor_effects:
                traj = m.sense(traj, dt, st.reading, st.effects)
            st.reading = traj[:, -1].copy()
            out[i] = traj[0, 1:]
        return out

    def simulate(self, u: np.ndarray, dt: float, y0: Sequence[float] | float = 0.0,
                 u_before: Sequence[float] | float | None = None, t_s: float = 0.0) -> np.ndarray:
        """Free-run simulation of one run of the rig: readings (N, K) for commands ``u`` (N, K),
        the commands before the run held at ``u_before`` (default: the first ones), from the
        stand time ``t_s``."""
        u = np.asarray(u, float)
        states = self.new_state(dt, y0, u[:, 0] if u_before is None else u_before)
        y0 = np.broadcast_to(np.asarray(y0, float), (self.n,))
        readings = self.advance(states, u, dt, t_s)
        return np.concatenate([y0[:, None], readings[:, :-1]], axis=1)

    def _drives(self, states: list[PlantState], u: np.ndarray, dt: float):
        """Every channel's :class:`~plant.model.Drive` for the block ``u`` (N, K), and
        ``[(indices, model, drive)]`` of the groups computed together. A group of channels whose
        models differ at most in g and Δ (:func:`drive_groups`: a chain of copies, a rig of like
        actuators) runs its input side as the trajectories of one call: an advance call of 16
        such channels cost 16 calls' numpy overhead (~0.09 ms each) before. The states are
        stacked for the call and each channel's given back its own rows; rows do not mix, so a
        channel's drive is the one it gets alone."""
        drives: list = [None] * self.n
        grouped = []
        for idx in self.groups:
            if len(idx) == 1:
                i = idx[0]
                drives[i] = self.channels[i].drive(u[i:i + 1], dt, states[i])
                continue
            m = self.channels[idx[0]]
            stacked = _stack([states[i] for i in idx])
            drv = m.drive(u[idx], dt, stacked)
            _unstack(stacked, [states[i] for i in idx])
            grouped.append((idx, m, drv))
            for j, i in enumerate(idx):
                drives[i] = _RowDrive(drv, j)
        return drives, grouped

    def _integrate(self, drives: list, y0: np.ndarray, dt: float,
                   G: np.ndarray | None = None, grouped: list = ()) -> np.ndarray:
        """The forces (N, K+1) from ``y0`` under the channels' drives, coupled: step by step,
        ``y[k+1] = y[k] + dt·(G_k·w(y[k]) + a(y[k]))`` with each channel's flow ``w`` and its own
        terms ``a`` (Δ, disturbances, force terms) from its own model; all steps at once when
        no channel's rate depends on its force but through a decay (:meth:`_integrate_linear`).
        ``G``: (N, N) for every step (default :attr:`G`), or (K, N, N) one per step (a changing
        structure)."""
        G = self.G if G is None else G
        decays = [m.force_decay() for m in self.channels]
        if all(lam is not None for lam in decays):
            return self._integrate_linear(drives, y0, dt, decays, G, grouped)
        return self._integrate_stepwise(drives, y0, dt, G)

    def _integrate_stepwise(self, drives: list, y0: np.ndarray, dt: float,
                            G: np.ndarray | None = None) -> np.ndarray:
        """:meth:`_integrate` one step at a time (any channel's laws)."""
        G = self.G if G is None else G
        n, K = self.n, drives[0].q.shape[1]
        out = np.empty((n, K + 1))
        out[:, 0] = y = y0.copy()
        for k in range(K):
            w = np.empty(n)
            a = np.empty(n)
            for i, (m, drv) in enumerate(zip(self.channels, drives)):
                yi = y[i:i + 1]
                w[i] = m.flow(drv.q[:, k], [None if x is None else x[:, k] for x in drv.aux], yi)[0]
                a[i] = m.rate_terms(None if drv.dist is None else drv.dist[:, k], yi)[0]
            y = y + dt * ((G if G.ndim == 2 else G[k]) @ w + a)
            out[:, k + 1] = y
        return out

    def _integrate_linear(self, drives: list, y0: np.ndarray, dt: float,
                          decays: list[float], G: np.ndarray, grouped: list = ()) -> np.ndarray:
        """The coupled forces when each channel's rate is linear in its own force:
        ``y_i[k+1] = (1 − λ_i·dt)·y_i[k] + dt·((G·w[k])_i + Δ_i + d_i[k])`` with the flows
        ``w`` (N, K) known in advance (no flow reads a force): one cumulative sum, or one
        first-order filter pass, per channel, as :meth:`PlantModel.integrate` does for one."""
        n = self.n
        K = (grouped[0][2] if grouped else drives[0]).q.shape[1]
        w = np.empty((n, K))
        done = np.zeros(n, bool)
        for idx, m, drv in grouped:             # a group's flows in one call
            w[idx] = m.flow(drv.q, drv.aux, None)
            done[idx] = True
        for i, (m, drv) in enumerate(zip(self.channels, drives)):
            if not done[i]:
                w[i] = m.flow(drv.q, drv.aux, None)[0]
        rate = G @ w if G.ndim == 2 else np.einsum("kij,jk->ik", G, w)
        rate += self._deltas[:, None]
        for idx, m, drv in grouped:
            if drv.dist is not None:
                rate[idx] += drv.dist
        for i, drv in enumerate(drives):
            if not done[i] and drv.dist is not None:
                rate[i] += drv.dist[0]
        out = np.empty((n, K + 1))
        out[:, 0] = y0
        plain = [i for i, lam in enumerate(decays) if lam == 0.0]
        if len(plain) == n:       # every channel a plain integrator: one pass for all
            np.cumsum(rate * dt, axis=1, out=out[:, 1:])
            out[:, 1:] += y0[:, None]
            return out
        for i, lam in enumerate(decays):
            if lam == 0.0:
                np.cumsum(rate[i] * dt, out=out[i, 1:])
                out[i, 1:] += y0[i]
            else:
                a = 1.0 - lam * dt
                out[i, 1:], _ = lfilter([dt], [1.0, -a], rate[i], zi=[a * y0[i]])
        return out


def drive_groups(models: Sequence[PlantModel]) -> list[list[int]]:
    """The channels (indices) whose models differ at most in g and Δ, in groups (single
    channels too). Only the catalogue's effects are grouped (their states and prepared signals
    are arrays of one row per trajectory); a model with a user's effect stays alone."""
    groups: dict = {}
    for i, m in enumerate(models):
        if any(not type(e).__module__.startswith("plant.effects.") for e in m.effects):
            key = ("alone", i)
        else:
            key = (m.spec, tuple(type(e) for e in m.effects),
                   tuple(sorted((k, v) for k, v in m.params().items() if k not in ("g", "delta"))))
        groups.setdefault(key, []).append(i)
    return list(groups.values())


class _RowDrive:
    """One channel's row of a group's :class:`~plant.model.Drive`, sliced only when asked
    (the step-by-step integration asks; the linear one reads the group's)."""

    __slots__ = ("_drive", "_row")

    def __init__(self, drive: Drive, row: int) -> None:
        self._drive, self._row = drive, row

    @property
    def q(self) -> np.ndarray:
        return self._drive.q[self._row:self._row + 1]

    @property
    def aux(self) -> list:
        r = self._row
        return [None if a is None else a[r:r + 1] for a in self._drive.aux]

    @property
    def dist(self) -> np.ndarray | None:
        d = self._drive.dist
        return None if d is None else d[self._row:self._row + 1]


def _stack(states: list[PlantState]) -> PlantState:
    """The trajectories of ``states`` (one each) as one state."""
    def cat(arrays):
        return None if arrays[0] is None else np.concatenate(arrays)
    effects = [{k: np.concatenate([st.effects[e][k] for st in states]) for k in states[0].effects[e]}
               for e in range(len(states[0].effects))]
    return PlantState(y=cat([st.y for st in states]), t=cat([st.t for st in states]),
                      history=cat([st.history for st in states]), effects=effects,
                      reading=cat([st.reading for st in states]),
                      valve_last=cat([st.valve_last for st in states]))


def _unstack(stacked: PlantState, states: list[PlantState]) -> None:
    """Give each of ``states`` its own row of ``stacked`` back (views: no two states share a
    row, and a state's arrays are replaced, not written into, by the next block)."""
    for j, st in enumerate(states):
        rows = slice(j, j + 1)
        st.y = stacked.y[rows]
        st.t = stacked.t[rows]
        st.history = stacked.history[rows]
        st.reading = None if stacked.reading is None else stacked.reading[rows]
        st.valve_last = None if stacked.valve_last is None else stacked.valve_last[rows]
        st.effects = [{k: v[rows] for k, v in eff.items()} for eff in stacked.effects]
