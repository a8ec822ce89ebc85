"""Whether a rig's structure can exist: G from a symmetric positive definite stiffness and
positive flow gains (:func:`plant.rig.physical_check`), and, when the file gives the stiffness
K itself, K symmetric (a G alone says K only up to the flow gains: a chain of channels with an
asymmetric K still has *some* symmetric stiffness behind it, but not the one the file states).
A scheduled change of the structure (``[[structure.change]]``) is judged again as each change
completes: a compliance added at a point keeps the flexibility ``K⁻¹ + δ·e_i e_iᵀ`` positive
definite, one taken away (a factor above 1) gives ``K + c·K e_i e_iᵀ K`` with ``c > 0``, so no
change makes the structure impossible; this checks the numbers.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plant.rig import PhysicalCheck, changed_structure, physical_check

from .config import RigConfig

#: how far from symmetric a given K may be, relative to its largest entry (FE exports round)
K_SYMMETRY_TOL = 1e-6


@dataclass(frozen=True)
class StructureVerdict:
    """The structure of a rig judged: ``check`` (None: the rig gives no G) and what is wrong
    (empty: nothing)."""

    check: PhysicalCheck | None
    reason: str

    @property
    def physical(self) -> bool:
        return self.check is not None and not self.reason


def judge_structure(rig: RigConfig) -> StructureVerdict:
    if rig.G is None:
        return StructureVerdict(None, "")
    check = physical_check(rig.G)
    reasons = [check.reason] if not check.physical else []
    if rig.K is not None:
        K = np.asarray(rig.K, float)
        scale = float(np.max(np.abs(K))) or 1.0
        i, j = np.unravel_index(np.argmax(np.abs(K - K.T)), K.shape)
        if abs(K[i, j] - K[j, i]) > K_SYMMETRY_TOL * scale:
            a, b = sorted((int(i), int(j)))
            reasons.insert(0, f"K is not symmetric: K[{a + 1},{b + 1}] = {K[a, b]:g} but "
                              f"K[{b + 1},{a + 1}] = {K[b, a]:g} ({rig.names[a]}, {rig.names[b]}): "
                              "a stiffness is")
    if check.physical and rig.changes:
        reasons += _changes_reasons(rig)
    return StructureVerdict(check, "; ".join(reasons))


def _changes_reasons(rig: RigConfig) -> list[str]:
    """Why the structure could not exist once one of the scheduled changes is complete (each
    in the order they complete, with those complete by then)."""
    factors = np.ones(len(rig.channels))
    for c in sorted(rig.changes, key=lambda c: c.end_s):
        factors[c.channel] *= c.stiffness_factor
        after = physical_check(changed_structure(rig.G, factors))
        if not after.physical:
            return [f"once the change {rig.change_text(c)} is complete: {after.reason}"]
    return []
