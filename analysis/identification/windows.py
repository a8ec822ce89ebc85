"""The data set cut for the windowed free-run simulation, and that simulation.

The error of a model is its *free-run* simulation against the measurement over windows (default
2 s), each window started from the measured force; the command history (delay line, valve and
reversal states) runs continuously through the record. A record becomes one :class:`Piece`, or
one per stretch whose force reading is neither clipped at the dynamometer's range nor held at a
hydraulic limit; its first :data:`LEAD_S` only prime the command history. Here: the pieces (all
windows, or an evenly spread subset for screening), their simulation (pieces with the same
sample time and window integrated side by side), the residual (window starts measured, or
re-estimated as the fit's objective does) and its sums per window.

A record may carry a known force rate from outside the channel's own model (a rig's coupling
from the other channels, :attr:`Record.known_rate_kgf_s`): it is added to the model's rate as
the model's own disturbances are (``dy/dt = g·w + Δ + D + c``), so the same fit, comparison and
diagnosis work on one channel of a rig.
"""
from __future__ import annotations

import math
from collections import OrderedDict
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from gateway.errors import DataError
from plant import PlantModel
from plant.model import Drive

from ..records.limits import clipped_mask, held_mask
from ..records.record import Record

#: default window of the free-run error, s
from ..defaults import WINDOW_S  # noqa: E402  (re-exported)
#: lead-in at the start of every record, s: the commands before a record are unknown, so its
#: first samples only prime the command history (delay line, valve and reversal states)
LEAD_S = 0.5


@dataclass
class Piece:
    """A contiguous stretch of one record, simulated in one pass.

    The first ``warmup`` samples only prime the command history (delay line, valve and
    reversal states); the error is taken from there on, in windows of ``window`` samples each
    started from the measured force."""

    u: np.ndarray
    y: np.ndarray
    dt: float
    window: int
    warmup: int = 0
    record: int = 0           #: index of the record in the data set
    start: int = 0            #: index of u[0] in the record
    t0: float = 0.0           #: time of u[0] since the record's first sample, s
    #: a known force rate added to the model's (kgf/s, one per sample of u), or None
    known: np.ndarray | None = None

    @property
    def n_eval(self) -> int:
        return len(self.u) - self.warmup

    @property
    def n_windows(self) -> int:
        return -(-self.n_eval // self.window)

    def window_index(self) -> np.ndarray:
        """Window number (within the piece) of every evaluated sample."""
        return np.arange(self.n_eval) // self.window

    def horizon(self) -> np.ndarray:
        """Samples since the start of the window, for every evaluated sample."""
        return np.arange(self.n_eval) % self.window


def window_samples(dt: float, window_s: float) -> int:
    return max(2, int(round(window_s / dt)))


def lead_samples(n: int, dt: float, window: int, lead_s: float = LEAD_S) -> int:
    """Lead-in of a record: ``lead_s``, but at most a quarter window and a tenth of the record."""
    return int(min(round(lead_s / dt), window // 4, n // 10))


def valid_stretches(rec: Record, min_samples: int) -> list[tuple[int, int]]:
    """``(start, stop)`` of the stretches of a record whose force reading is not clipped and not
    held at a hydraulic limit (:mod:`analysis.records.limits`), at least ``min_samples`` long."""
    bad = clipped_mask(rec.y) | held_mask(rec.u, rec.y, rec.dt)
    if not bad.any():
        return [(0, len(rec.y))]
    z = np.concatenate([[1], bad.astype(int), [1]])
    edges = np.flatnonzero(np.diff(z))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2]) if b - a >= min_samples]


def pieces_from_records(records: Sequence[Record], window_s: float = WINDOW_S,
                        lead_s: float = LEAD_S) -> list[Piece]:
    """The evaluated pieces of a data set: one per record, after its lead-in, or one per
    unclipped stretch when the force reading hits the dynamometer's range (the clipped samples
    only carry the command history into the next stretch)."""
    if not records:
        raise DataError("no data to fit")
    out = []
    for i, rec in enumerate(records):
        n = len(rec.u)
        w = window_samples(rec.dt, window_s)
        lead = lead_samples(n, rec.dt, w, lead_s)
        known = rec.known_rate_kgf_s
        if known is not None and len(known) != n:
            raise DataError(f"{rec.source}: the known force rate has {len(known)} samples, the "
                            f"record {n}")
        stretches = valid_stretches(rec, max(2, w // 4))
        if stretches == [(0, n)]:
            out.append(Piece(rec.u, rec.y, rec.dt, max(2, min(w, n - lead)), lead, i, 0, 0.0,
                             known))
            continue
        for a, b in stretches:
            first = max(a, lead)
            if b - first < 2:
                continue
            s0 = max(0, first - max(lead, int(round(lead_s / rec.dt))))
            out.append(Piece(rec.u[s0:b], rec.y[s0:b], rec.dt, max(2, min(w, b - first)),
                             first - s0, i, s0, float(rec.t[s0] - rec.t[0]),
                             None if known is None else known[s0:b]))
    if not out:
        raise DataError("no usable data: every record is too short or its force reading is "
                        "clipped at the dynamometer's range throughout")
    return out


def screening_pieces(records: Sequence[Record], window_s: float = WINDOW_S,
                     max_windows: int = 150, chunk_windows: int = 10,
                     warmup_s: float = 1.0) -> tuple[list[Piece], bool]:
    """A subset of windows for fast screening: all windows if there are at most ``max_windows``,
    else evenly spread chunks of ``chunk_windows`` windows, each with ``warmup_s`` of command
    history before it. Returns ``(pieces, is_subset)``."""
    return subset_pieces(pieces_from_records(records, window_s), max_windows, chunk_windows,
                         warmup_s)


def subset_pieces(full: Sequence[Piece], max_windows: int = 150, chunk_windows: int = 10,
                  warmup_s: float = 1.0) -> tuple[list[Piece], bool]:
    """See :func:`screening_pieces` (same, from prepared pieces)."""
    full = list(full)
    total = sum(p.n_windows for p in full)
    if total <= max_windows:
        return full, False
    n_chunks = max(1, max_windows // chunk_windows)
    # chunks per piece in proportion to its windows, one at least (every record is screened)
    share = np.array([p.n_windows for p in full], float)
    alloc = np.maximum(np.floor(n_chunks * share / share.sum()).astype(int), 1)
    out: list[Piece] = []
    for p, n in zip(full, alloc):
        if n <= 0:
            continue
        W = p.window
        span = chunk_windows * W
        warm = int(round(warmup_s / p.dt))
        N = len(p.u)
        if N - p.warmup <= span or n * span >= N - p.warmup:
            out.append(p)
            continue
        starts = np.linspace(p.warmup, N - span, n).astype(int)
        for s in starts:
            a = max(0, s - warm)
            out.append(Piece(p.u[a:s + span], p.y[a:s + span], p.dt, W, s - a, p.record,
                             p.start + a, p.t0 + a * p.dt,
                             None if p.known is None else p.known[a:s + span]))
    return (out, True) if out else (full, False)


#: the drives of the last pieces simulated, by piece and :meth:`PlantModel.drive_key`: a fit
#: simulates the same pieces hundreds of times, and most of its Jacobian's columns move a
#: parameter the drive does not read (g, Δ, a force-dependent law, a sensor)
_DRIVES: "OrderedDict[tuple, tuple[Piece, Drive, Drive]]" = OrderedDict()
_DRIVES_KEPT = 64
#: the last force trajectories of groups of pieces whose model depends on the force, by the
#: pieces, with the recursion's growth factors along them: where the next simulation's
#: integration starts, and what a Jacobian's columns are linearised about
_FORCES: dict[tuple, tuple[list, np.ndarray, np.ndarray | None]] = {}
#: while a Jacobian's columns are simulated (:func:`linearised_columns`): the trajectories of
#: the point they are taken at, by group, as :data:`_FORCES` held them
_BASES: dict[tuple, tuple[list, np.ndarray, np.ndarray | None]] | None = None


def _measured_windows(group: Sequence[Piece]) -> np.ndarray:
    """The measured force along the windows of ``group`` side by side, (n, W + 1) as the
    simulation's trajectories (each window's last point the next sample, the record's last
    one repeated past its end): where a simulation with no last solution starts solving, the
    same for every process (:func:`fresh_solutions`)."""
    W = group[0].window
    out = []
    for p in group:
        first = p.warmup + np.arange(p.n_windows)[:, None] * p.window
        out.append(p.y[np.minimum(first + np.arange(W + 1)[None, :], len(p.y) - 1)])
    return np.concatenate(out, axis=0) if len(out) > 1 else out[0]


def fresh_solutions() -> None:
    """Forget the last solutions (:data:`_FORCES`): a fit that starts here solves its first
    simulation from the measured force (:func:`_measured_windows`), so its answer does not
    depend on what the process simulated before (a guess changes a solution only within the
    integration's tolerance, but a fit in a flat valley can carry such a difference far). With
    it, a fit gives the same numbers in a worker process as in this one, whatever ran there
    before."""
    _FORCES.clear()


@contextmanager
def linearised_columns():
    """Within: the simulations are a Jacobian's finite-difference columns at the parameters
    simulated last (each moves one parameter by a step of ~1e-6). A model whose rate depends on
    the force is then not solved by Newton passes but linearised about that last solution
    (:meth:`PlantModel.integrate_linearised`, one rate evaluation and one compiled pass instead
    of two to six evaluations and two or three passes): exact to first order in the step, so
    the column differs from the solved one by the step's second-order terms, the size of the
    forward difference's own error. Models whose rate does not depend on the force, and groups
    of pieces not simulated last, are simulated as always. The last solutions stay those of
    the point itself (where the next trial starts)."""
    global _BASES
    _BASES = dict(_FORCES)
    try:
        yield
    finally:
        _BASES = None


def _piece_drive(model: PlantModel, piece: Piece) -> tuple[Drive, Drive]:
    """The piece's drive (delay, valve, flow preparation over the whole piece, so the command
    history runs through), whole and cut into its evaluated windows (arrays not to be
    modified: they are shared by later simulations with the same drive)."""
    key = (id(piece), model.drive_key())
    hit = _DRIVES.get(key)
    if hit is not None and hit[0] is piece:
        _DRIVES.move_to_end(key)
        return hit[1], hit[2]
    u, dt, W, a = piece.u, piece.dt, piece.window, piece.warmup
    state = model.new_state(1, dt, 0.0, u[0], piece.t0)
    drv = model.drive(u[None, :], dt, state)
    if piece.known is not None:      # a known rate from outside the model: as a disturbance
        known = np.asarray(piece.known, float)[None, :]
        drv = Drive(q=drv.q, aux=drv.aux, dist=known if drv.dist is None else drv.dist + known)
    n = len(u) - a
    nw = -(-n // W)
    pad = nw * W - n

    def cut(arr):
        if arr is None:
            return None
        arr = arr[0, a:]
        if pad:
            arr = np.concatenate([arr, np.repeat(arr[-1:], pad)])
        return arr.reshape(nw, W)

    wdrv = Drive(q=cut(drv.q), aux=[cut(x) for x in drv.aux], dist=cut(drv.dist))
    for d in (drv, wdrv):     # shared from now on: a hook that wrote into them would raise
        for arr in (d.q, d.dist, *d.aux):
            if isinstance(arr, np.ndarray):
                arr.flags.writeable = False
    _DRIVES[key] = (piece, drv, wdrv)
    if len(_DRIVES) > _DRIVES_KEPT:
        _DRIVES.popitem(last=False)
    return drv, wdrv


def _window_starts(piece: Piece, n_windows: int) -> np.ndarray:
    """The steps of the piece where its evaluated windows start."""
    return piece.warmup + np.arange(n_windows) * piece.window


def _cut_windows(model: PlantModel, piece: Piece) -> tuple[Drive, np.ndarray, list[dict] | None]:
    """The piece's drive cut into its evaluated windows (:func:`_piece_drive`), the measured
    starts, and the sensor filters' states at the starts (None without SENSOR effects)."""
    drv, wdrv = _piece_drive(model, piece)
    steps = _window_starts(piece, wdrv.q.shape[0])
    sensor = (model.window_filter_states(drv, piece.y, piece.dt, steps)
              if model.has_sensor_effects else None)
    return wdrv, piece.y[steps], sensor


#: the windows of groups of pieces side by side, by the pieces and the drive's key
#: (:func:`_group_drive`)
_GROUPS: "OrderedDict[tuple, tuple[list, Drive, np.ndarray]]" = OrderedDict()
_GROUPS_KEPT = 16


def _group_drive(model: PlantModel, group: Sequence[Piece]) -> tuple[Drive, np.ndarray]:
    """The windows of several pieces (same sample time and window) side by side: their drives
    cut into windows (:func:`_piece_drive`) and stacked, and the measured starts; kept by the
    pieces and :meth:`PlantModel.drive_key` as the pieces' drives are (read-only arrays)."""
    key = (tuple(id(p) for p in group), model.drive_key())
    hit = _GROUPS.get(key)
    if hit is not None and all(a is b for a, b in zip(hit[0], group)):
        _GROUPS.move_to_end(key)
        return hit[1], hit[2]
    wdrvs = [_piece_drive(model, p)[1] for p in group]

    def cat(arrs):
        return None if arrs[0] is None else np.concatenate(arrs, axis=0)
    # a disturbance some pieces have and others not (a rig channel's coupling is a known rate
    # only in the runs where another channel moves): zero in the others
    dists = [d.dist for d in wdrvs]
    dist = None if all(d is None for d in dists) else np.concatenate(
        [np.zeros_like(w.q) if d is None else d for w, d in zip(wdrvs, dists)], axis=0)
    drv = Drive(q=np.concatenate([w.q for w in wdrvs], axis=0),
                aux=[cat([w.aux[j] for w in wdrvs]) for j in range(len(wdrvs[0].aux))],
                dist=dist)
    starts = np.concatenate([p.y[_window_starts(p, w.q.shape[0])] for p, w in zip(group, wdrvs)])
    for arr in (drv.q, drv.dist, starts, *drv.aux):
        if isinstance(arr, np.ndarray):
            arr.flags.writeable = False
    _GROUPS[key] = (list(group), drv, starts)
    if len(_GROUPS) > _GROUPS_KEPT:
        _GROUPS.popitem(last=False)
    return drv, starts


def simulate_pieces(model: PlantModel, pieces: Sequence[Piece]) -> list[np.ndarray]:
    """Windowed free-run simulation of several pieces: ŷ for the evaluated samples of each.

    Pieces with the same sample time and window length are integrated together, all their
    windows side by side (one pass of the integrator, however many pieces)."""
    out: list[np.ndarray | None] = [None] * len(pieces)
    groups: dict[tuple[float, int], list[int]] = {}
    for i, p in enumerate(pieces):
        groups.setdefault((p.dt, p.window), []).append(i)
    for (dt, W), idx in groups.items():
        group = [pieces[i] for i in idx]
        if len(idx) == 1:
            drv, starts, sensor = _cut_windows(model, group[0])
            sizes = [drv.q.shape[0]]
        else:
            drv, starts = _group_drive(model, group)
            sizes = [p.n_windows for p in group]
            sensor = None
            if model.has_sensor_effects:
                states = [model.window_filter_states(_piece_drive(model, p)[0], p.y, p.dt,
                                                     _window_starts(p, p.n_windows))
                          for p in group]
                sensor = [{k: np.concatenate([s[j][k] for s in states]) for k in states[0][j]}
                          for j in range(len(states[0]))]
        if model.depends_on_force:
            # solved from the last solution for these windows: a fit's next simulation moves
            # one parameter a little (the answer does not depend on where it starts)
            key = (tuple(id(p) for p in group), dt, W)
            y0 = model.force_under(starts, sensor)
            base = _BASES.get(key) if _BASES is not None else None
            if (base is not None and base[2] is not None and base[1].shape == (len(y0), W + 1)
                    and all(a is b for a, b in zip(base[0], group))):
                force = model.integrate_linearised(drv, y0, dt, base[1], base[2])
            else:
                hit = _FORCES.get(key)
                growth: list = []
                guess = (hit[1] if hit is not None and all(a is b for a, b in zip(hit[0], group))
                         else _measured_windows(group))
                force = model.integrate(drv, y0, dt, guess=guess, growth=growth)
                if _BASES is None:
                    _FORCES[key] = (group, force, growth[0] if growth else None)
                    if len(_FORCES) > _DRIVES_KEPT:
                        _FORCES.pop(next(iter(_FORCES)))
            yy = force if sensor is None else model.sense(force, dt, starts, sensor)
        else:
            yy = model.integrate_from_readings(drv, starts, dt, sensor)
        yy = yy[:, :-1]
        row = 0
        for i, k in zip(idx, sizes):
            out[i] = yy[row:row + k].reshape(-1)[:pieces[i].n_eval]
            row += k
    return out  # type: ignore[return-value]


def simulate_piece(model: PlantModel, piece: Piece) -> np.ndarray:
    """Windowed free-run simulation of one piece: ŷ for the evaluated samples (after warm-up).

    Same computation as :meth:`PlantModel.simulate_windows` (which it equals for
    ``warmup = 0``), with the windows starting after the warm-up."""
    return simulate_pieces(model, [piece])[0]


def window_means(r: np.ndarray, W: int) -> np.ndarray:
    """Mean of ``r`` over consecutive windows of ``W`` samples (the last may be shorter)."""
    n = len(r)
    full = n // W
    nw = -(-n // W)
    out = np.empty(nw)
    if full:
        out[:full] = r[:full * W].reshape(full, W).mean(axis=1)
    if nw > full:
        out[-1] = r[full * W:].mean()
    return out


def demean_windows(r: np.ndarray, W: int) -> np.ndarray:
    """``r`` minus its mean in each window of ``W`` samples."""
    m = window_means(r, W)
    out = np.array(r, float, copy=True)
    full = len(r) // W
    if full:
        out[:full * W].reshape(full, W)[:] -= m[:full, None]
    if len(m) > full:
        out[full * W:] -= m[-1]
    return out


def residual(model: PlantModel, pieces: Sequence[Piece], adjust_start: bool = True) -> np.ndarray:
    """ŷ − y over all evaluated samples of all pieces, concatenated.

    ``adjust_start=True`` (the fit's objective): each window's starting force is re-estimated,
    i.e. the window's mean residual is removed. The measured start carries one noise draw
    ``e_0`` that the whole window inherits; fitting through it biases the parameters toward that
    draw (five to ten times larger parameter errors in tests). ``False``: the error from the
    measured start, as reported by :mod:`.metrics`."""
    out = []
    for p, yhat in zip(pieces, simulate_pieces(model, pieces)):
        r = yhat - p.y[p.warmup:]
        out.append(demean_windows(r, p.window) if adjust_start else r)
    return np.concatenate(out) if len(out) > 1 else out[0]


def errors(model: PlantModel, pieces: Sequence[Piece]) -> tuple[np.ndarray, float]:
    """From one simulation: the objective's squared error per window (starts re-estimated) and
    the RMSE from the measured starts."""
    raw = residual(model, pieces, adjust_start=False)
    adj, k = [], 0
    for p in pieces:
        adj.append(demean_windows(raw[k:k + p.n_eval], p.window))
        k += p.n_eval
    return window_sse(np.concatenate(adj), pieces), math.sqrt(float(raw @ raw) / len(raw))


def window_sse(r: np.ndarray, pieces: Sequence[Piece]) -> np.ndarray:
    """Sum of squares of a concatenated residual per window, all pieces in order."""
    out, k = [], 0
    for p in pieces:
        seg = r[k:k + p.n_eval]
        k += p.n_eval
        out.append(window_means(seg * seg, p.window) * np.diff(
            np.minimum(np.arange(p.n_windows + 1) * p.window, p.n_eval)))
    return np.concatenate(out)


def window_labels(pieces: Sequence[Piece]) -> np.ndarray:
    """A global window number for every evaluated sample (clusters for the covariance)."""
    out, base = [], 0
    for p in pieces:
        out.append(p.window_index() + base)
        base += p.n_windows
    return np.concatenate(out)


def known_response(pieces: Sequence[Piece]) -> np.ndarray:
    """The windowed free-run response to the pieces' known force rates alone (zero where a
    piece has none): in each window, ``dt·Σ c`` over the steps since its start, as the
    simulation adds it (:func:`_piece_drive`). Concatenated over the evaluated samples."""
    out = []
    for p in pieces:
        if p.known is None:
            out.append(np.zeros(p.n_eval))
            continue
        c = np.asarray(p.known, float)[p.warmup:] * p.dt
        n, W = len(c), p.window
        nw = -(-n // W)
        padded = np.zeros(nw * W)
        padded[:n] = c
        steps = padded.reshape(nw, W)
        resp = np.zeros_like(steps)
        np.cumsum(steps[:, :-1], axis=1, out=resp[:, 1:])
        out.append(resp.reshape(-1)[:n])
    return np.concatenate(out)
