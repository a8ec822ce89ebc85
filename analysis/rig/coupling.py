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

Not every run tells something of channel i. A per-column campaign moves one valve per run:
channel i's own valve moves in its own column's run, its force moves through the coupling in
the runs of the channels coupled to it, and in the others it only drifts with its trend. A run
where neither its valve nor its coupling moves its force gives its windows nothing to fit (a
one-channel fit would still return a g and call the base model adequate): it is left out, with
a note (:func:`diagnosable_records`). A channel whose own valve moves in none of the runs
cannot be diagnosed at all: its g, τ and effects are not in the data.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Sequence

import numpy as np

from core.errors import DataError
from plant.rig import RigModel

from ..records.limits import noise_sigma
from ..records.record import Record
from .record import RigRecord

#: a run where the coupling's part of a channel's force swings less than this many times the
#: reading's noise (σ from its second differences), its own valve still, gives that channel's
#: windows nothing to fit (an uncoupled neighbour's 1e-5 estimate swings it by 0.05 kgf)
MOVES_SIGMAS = 10.0


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


def own_valve_moves(rec: RigRecord, name: str) -> bool:
    """Channel ``name``'s command changes in the run (its own valve moves)."""
    u = rec.channel(name).u
    return bool(len(u)) and bool(np.any(u != u[0]))


def diagnosable_records(rig: RigModel, records: Sequence[RigRecord], name: str
                        ) -> tuple[list[Record], list[str]]:
    """Channel ``name`` of the runs that give its windows something to fit (module docstring):
    those where its own valve moves, and those where its coupling moves its force by at least
    :data:`MOVES_SIGMAS` times the reading's noise (the coupling then a known input); the
    others are left out, said in the notes. No records (and a note) when its own valve moves
    in none of the runs."""
    kept, notes, left = [], [], []
    own = [own_valve_moves(rec, name) for rec in records]
    if not any(own):
        return [], [f"{name}: not diagnosed: its valve moves in none of the runs given "
                    f"({', '.join(_short(r.source) for r in records)}), so its own g, τ and "
                    "effects are not in them (give the run where its valve moves: its column's, "
                    "or a simultaneous one); its model stays as the rig model gives it"]
    for rec, moves, ch in zip(records, own, channel_records(rig, records, name)):
        if moves:
            kept.append(ch)
            continue
        c = ch.known_rate_kgf_s
        swing = 0.0 if c is None else float(np.ptp(np.cumsum(c) * rec.dt))
        if swing >= MOVES_SIGMAS * max(noise_sigma(ch.y), 0.1):
            kept.append(ch)
        else:
            left.append(_short(rec.source))
    if left:
        notes.append(f"{name}: left out {', '.join(left)}: neither its valve nor the coupling "
                     "moves its force there (nothing for its windows to fit)")
    return kept, notes


def _short(source: str) -> str:
    """A run's name as a note gives it (the directory, not its whole path)."""
    return Path(source).name or source
