r"""The other channels' part of one channel's force rate, as a known input to its model.

In the rig's model (:mod:`plant.rig`) channel i's force obeys

.. math::  \dot y_i = G_{ii}\,w_i(t-\tau_i) + \Delta_i + D_i
                      + \underbrace{\sum_{j\ne i} G_{ij}\,w_j(t-\tau_j)}_{c_i(t)},

its own one-channel model (``g = G_ii``, its own delay, valve and flow effects, trend, force
terms) plus the coupling ``c_i``: the other channels' flows ``w_j`` (each through channel j's own
model: its delay, valve effects, reversal boost, ...; force-dependent flow laws read channel j's
measured force) times the structure's ``G_ij``. With the other channels' models known (a rig
model file, :mod:`plant.config`; their base models at first), ``c_i`` is a known force rate
along the run, and channel i is a one-channel record that carries it
(:attr:`~analysis.records.record.Record.known_rate_kgf_s`): the one-channel fit, comparison and
diagnosis add it to the model's rate as they add a disturbance, and find channel i's own
effects (:mod:`analysis.diagnosis.rig`).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from core.errors import DataError
from plant.rig import RigModel

from ..records.record import Record
from .record import RigRecord


def aligned(rig: RigModel, rec: RigRecord) -> list[int]:
    """For each of the record's channels, its index in the rig model; :class:`DataError` if
    the two do not name the same channels."""
    if sorted(rig.names) != sorted(rec.names):
        raise DataError(f"{rec.source}: its channels ({', '.join(rec.names)}) are not the rig "
                        f"model's ({', '.join(rig.names)}): give the rig model of this rig")
    return [rig.names.index(n) for n in rec.names]


def channel_flows(rig: RigModel, rec: RigRecord) -> np.ndarray:
    """Every channel's flow ``w_j`` (N, K), in the record's channel order: its command through
    its model's delay, valve and flow effects (the commands before the run held at the first),
    force-dependent flow laws at its measured force."""
    order = aligned(rig, rec)
    dt = rec.dt
    out = np.empty((rec.n, len(rec)))
    for i, k in enumerate(order):
        m = rig.channels[k]
        u = rec.channels[i].u
        state = m.new_state(1, dt, 0.0, u[0], 0.0)
        drv = m.drive(u[None, :], dt, state)
        out[i] = m.flow(drv.q, drv.aux, rec.channels[i].y[None, :])[0]
    return out


def coupling_rates(rig: RigModel, rec: RigRecord) -> np.ndarray:
    """``c_i = Σ_{j≠i} G_ij·w_j`` for every channel (N, K), kgf/s, in the record's order."""
    order = aligned(rig, rec)
    G = rig.G[np.ix_(order, order)]
    off = G - np.diag(np.diag(G))
    if not np.any(off):
        return np.zeros((rec.n, len(rec)))
    return off @ channel_flows(rig, rec)


def channel_records(rig: RigModel, records: Sequence[RigRecord], name: str) -> list[Record]:
    """Channel ``name`` of every record as a one-channel record carrying its coupling from the
    other channels (module docstring)."""
    out = []
    for rec in records:
        i = rec.index(name)
        c = coupling_rates(rig, rec)[i]
        ch = rec.channels[i]
        out.append(replace(ch, known_rate_kgf_s=c if np.any(c) else None, notes=list(ch.notes)))
    return out
