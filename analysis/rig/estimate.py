r"""G, every channel's τ and Δ from rig meanders: per column or all at once.

The rig's model (``plant.rig``) is ``dy_i/dt = Σ_j G_ij·w_j(t − τ_j) + Δ_i`` with ``w_j = u_j``
on the paper's main portions. Two experiments identify G:

* **per column**: a meander on channel j, every other valve at a zero command; each channel's
  force rate over channel j's delayed command is ``G_ij`` (the paper's eq. (2) per column:
  ``G_ij = (y_i(t_2) − y_i(t_1) − Δ_i(t_2 − t_1)) / (u_{j}(t_2 − t_1))`` on each main portion);
* **simultaneous**: every channel a meander of its own period, chosen so the channels can be
  told apart (:mod:`.periods`); each row of G is the least squares of the channel's force rate
  on all channels' delayed commands.

Both are one estimator, eq. (2'): on the steady stretches of the runs (:mod:`.steady`: every
delayed command constant, no channel inside its transitional window after a reversal, where
the boost would bias g) each force is a line of slope ``s_{i,p} = Σ_j G_ij u_{j,p} + Δ_i``; row i
is the weighted least squares of its stretches' slopes on the commands (all runs together, Δ_i
shared), with cluster-robust 95 % intervals, the stretches as clusters (:mod:`.regression`). A
per-column campaign is the case where each stretch moves one column. τ_j and the transitional
window come from channel j's own reversals (:mod:`.delays`); in a simultaneous run the others'
part ``Σ_{k≠j} Ĝ_jk ∫u_k`` is first taken off channel j's force with a first estimate of G, and
the steady stretches and G are found again with the delays and windows of that second look.

A column no run moves is unknown (NaN, said in a note); columns the runs cannot tell apart
(variance inflation above :data:`VIF_REFUSE`: commands nearly a combination of each other) are
refused with the pair and what to change. The physical check (is there a symmetric positive
definite stiffness behind G?) is noted with the estimate, never refused (:mod:`.result`).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from core.errors import DataError

from ..records.limits import clipped_mask, held_mask
from .delays import ChannelTiming, channel_timing
from .record import RigRecord
from .regression import RowFit, Slopes, collinearity, fit_row, stretch_slopes
from .result import RigEstimate, physical_note
from .steady import command_events, delayed, steady_mask, stretches

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
#: a column whose variance inflation exceeds this cannot be told apart from the others: refused
#: (its interval would be over 4.5 times as wide as with orthogonal commands)
VIF_REFUSE = 20.0
#: above this the estimate notes the inflation
VIF_NOTE = 2.0
#: another channel whose part of a force is above this share of the channel's own gain ends
#: that channel's excess-force curves at its reversals (its boost arrives through G)
COUPLED_SHARE = 0.01
#: a command that changes on more than this share of samples is not a meander (a closed loop)
MAX_CHANGE_SHARE = 0.05


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


def estimate_rig(records: Sequence[RigRecord], guard_s: float | None = None,
                 margin_s: float = MARGIN_S, level: float = 0.95) -> RigEstimate:
    """G with its intervals, each channel's τ and Δ and the physical check from rig meanders
    (module docstring). ``guard_s``: the time left out after every reversal (default:
    :data:`GUARD_FACTOR` times each channel's transitional window)."""
    records = list(records)
    if not records:
        raise DataError("no rig runs given")
    from .onerun import estimate_one_run, is_one_run
    one = [is_one_run(rec) for rec in records]
    if all(one):
        return estimate_one_run(records, guard_s, margin_s, level)
    if any(one):
        raise DataError(f"{records[one.index(True)].source} is a one-run campaign's run: "
                        "estimate it alone (stand estimate RUN), not with meanders of other "
                        "designs")
    names = records[0].names
    N = len(names)
    moving = [moving_channels(rec) for rec in records]
    notes: list[str] = []
    for rec, m in zip(records, moving):
        if not m:
            notes.append(f"{rec.source}: no channel's command reversed twice (no meander): left out")
    if not any(moving):
        raise DataError("no channel's command reverses twice in any run: the rig estimate needs "
                        "meanders of two reversals or more (one channel at a time, or all at once "
                        "with periods of their own; stand campaign --rig --cycles 2 or more)")
    moved = sorted({j for m in moving for j in m})
    unknown = [names[j] for j in range(N) if j not in moved]
    if unknown:
        notes.append(f"{', '.join(unknown)} moved in no run: their columns of G are unknown "
                     "(run a meander on each)")
    simultaneous = any(len(m) > 1 for m in moving)
    # first look: τ from the raw forces, a nominal guard after every reversal
    timing = _timing(records, moving, names, None, None, None, level)
    first_guard = FIRST_GUARD_S if guard_s is None else guard_s
    G, fits, vif = _fit(records, timing, first_guard, margin_s, level, None)
    # second look: the others' part off each moving channel's force for its turns, its boost
    # window against the predicted steady rate, each row guarded only after the reversals of
    # the channels that move its force
    delta = np.array([f.coef[N] for f in fits])
    timing = _timing(records, moving, names, G, delta, timing, level)
    coupled = np.stack([(f.ci[:N, 0] > 0) | (f.ci[:N, 1] < 0) for f in fits]) | np.eye(N, dtype=bool)
    G, fits, vif = _fit(records, timing, guard_s, margin_s, level, coupled)
    for j in moved:
        if vif[j] > VIF_NOTE:
            notes.append(f"column {names[j]}: the runs' commands are partly a combination of "
                         f"each other (variance inflation {vif[j]:.2g}): its interval is "
                         f"{math.sqrt(vif[j]):.2g}× what separate meanders would give")
    G_ci = np.stack([f.ci[:N] for f in fits])
    delta = np.array([f.coef[N] for f in fits])
    delta_ci = np.array([f.ci[N] for f in fits])
    tau = np.array([timing[j].tau_s if j in timing else math.nan for j in range(N)])
    tau_ci = np.array([timing[j].tau_ci_s if j in timing else (math.nan, math.nan)
                       for j in range(N)])
    trans = np.array([timing[j].transitional_s if j in timing else math.nan for j in range(N)])
    design = ("simultaneous" if all(len(m) == len(moved) for m in moving if m) and simultaneous
              else "per-column" if not simultaneous else "mixed")
    return RigEstimate(
        names=list(names), G=G, G_ci=G_ci, delta_kgf_s=delta, delta_ci=delta_ci, tau_s=tau,
        tau_ci_s=tau_ci, transitional_s=trans,
        transitional_detected=[bool(timing[j].transitional_detected) if j in timing else False
                               for j in range(N)],
        boost_extra_s=np.array([timing[j].boost_extra_s if j in timing else math.nan
                                for j in range(N)]),
        amplitude_pct=np.array([timing[j].amplitude_pct if j in timing else math.nan
                                for j in range(N)]),
        reversals=[timing[j].reversals if j in timing else 0 for j in range(N)],
        design=design, moving={rec.source: [names[j] for j in m] for rec, m in zip(records, moving)},
        inflation=vif[:N], stretches=[f.stretches for f in fits],
        residual_kgf=np.array([f.residual_kgf for f in fits]),
        physical=physical_note(G, G_ci, names, level), notes=notes,
        sources=[rec.source for rec in records], level=level)


def _timing(records: list[RigRecord], moving: list[list[int]], names: list[str],
            G: np.ndarray | None, delta: np.ndarray | None,
            before: dict[int, ChannelTiming] | None, level: float) -> dict[int, ChannelTiming]:
    """Each moving channel's τ and transitional window from the runs it moved in
    (:mod:`.delays`); with a first estimate (``G``, ``delta``, the delays ``before``) the other
    channels' part is taken off its force first and the window is read against the steady
    rate that estimate predicts; without one only τ is read."""
    out: dict[int, ChannelTiming] = {}
    for j in sorted({j for m in moving for j in m}):
        parts = []
        for rec, m in zip(records, moving):
            if j not in m:
                continue
            usable = open_loop(rec)
            y, rate, own, cuts = rec.y[j], None, math.nan, []
            if G is not None and before is not None and delta is not None:
                taus = [before[k].tau_s if k in before else 0.0 for k in range(rec.n)]
                y = others_off(rec, j, G, taus, m)
                for k in m:
                    if k != j and np.isfinite(G[j, k]) and abs(G[j, k]) > COUPLED_SHARE * abs(G[j, j]):
                        e, rev = command_events(rec.u[k])
                        cuts += list(e[rev] + int(round(before[k].tau_s / rec.dt)))
                own = float(G[j, j])
                rate = own * delayed(rec.u[j], rec.dt, before[j].tau_s) + delta[j]
            parts.append((np.where(usable, rec.u[j], 0.0), y, rate, own, rec.dt,
                          np.array(cuts, int)))
        out[j] = channel_timing(parts, names[j], level)
    return out


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


def _fit(records: list[RigRecord], timing: dict[int, ChannelTiming], guard_s: float | None,
         margin_s: float, level: float, coupled: np.ndarray | None
         ) -> tuple[np.ndarray, list[RowFit], np.ndarray]:
    """Every row of G by eq. (2') on the runs' steady stretches; each column's largest
    variance inflation over the rows (a row's design that cannot separate a column, above
    :data:`VIF_REFUSE`, is refused). ``coupled[i, j]``: row i is left
    out after channel j's reversals (None: after every channel's; a channel that does not move
    channel i's force cannot bias its slopes with its boost), the margins around every command
    change stay."""
    names = records[0].names
    N = len(names)
    taus = [timing[j].tau_s if j in timing else 0.0 for j in range(N)]
    guards = np.array([guard_s if guard_s is not None else _guard(timing[j]) if j in timing
                       else 0.0 for j in range(N)])
    fitted = np.array([j in timing for j in range(N)] + [True])
    shortest = [max(3, int(round(MIN_STRETCH_S / rec.dt))) for rec in records]
    ud = [np.vstack([delayed(rec.u[j], rec.dt, taus[j]) for j in range(N)]) for rec in records]
    # each row's own design decides whether it separates the columns: rows are guarded only
    # after the reversals of the channels that move them (second look), so they see more
    fits = []
    inflation = np.full(N + 1, np.nan)
    for i in range(N):
        row_guards = guards if coupled is None else np.where(coupled[i], guards, 0.0)
        X, parts = [], []
        for rec, d, m in zip(records, ud, shortest):
            y = rec.y[i]
            ok = steady_mask(rec.u, rec.dt, taus, row_guards, margin_s, open_loop(rec))
            ok &= ~clipped_mask(y) & ~held_mask(rec.u[i], y, rec.dt)
            spans = stretches(ok, m)
            parts.append(stretch_slopes(rec.t, y, spans))
            X += [np.append(d[:, (a + b) // 2], 1.0) for a, b in spans]
        sl = Slopes(*(np.concatenate([getattr(p, f) for p in parts])
                      for f in ("slope", "weight", "sse", "samples")))
        if len(X) < fitted.sum() + 1:
            raise DataError(f"channel {names[i]}: only {len(X)} steady stretch(es) of at least "
                            f"{MIN_STRETCH_S:g} s where its force is not clipped or held at a "
                            "limit: too few for its row of G (longer runs, longer periods, or a "
                            "shorter guard after the reversals)")
        X = np.array(X)
        bare = [j for j in range(N) if fitted[j] and not np.any(X[:, j] != 0)]
        if bare:
            raise DataError(_no_stretch(records, names, i, bare[0], guards, margin_s))
        vif, corr = collinearity(X, sl.weight, fitted)
        worst = int(np.nanargmax(np.where(fitted[:N], vif[:N], -1.0))) if fitted[:N].any() else 0
        if vif[worst] > VIF_REFUSE:
            raise DataError(_inseparable(names, worst, vif, corr, fitted))
        inflation = np.fmax(inflation, vif)
        fits.append(fit_row(X, sl, fitted, level))
    G = np.stack([f.coef[:N] for f in fits])
    return G, fits, inflation


def _guard(timing: ChannelTiming) -> float:
    """The time left out after a reversal of a channel: :data:`GUARD_FACTOR` times its
    transitional window, or :data:`FIRST_GUARD_S` when no boost was found."""
    return GUARD_FACTOR * timing.transitional_s if timing.transitional_detected else FIRST_GUARD_S


def _no_stretch(records: list[RigRecord], names: list[str], i: int, j: int,
                guards: np.ndarray, margin_s: float) -> str:
    """Why row ``i`` has no steady stretch where channel ``j``'s valve moves: its meander's
    half periods leave nothing after the guard, and what to do."""
    halves = []
    for rec in records:
        e, rev = command_events(rec.u[j])
        e = e[rev]
        if len(e) > 1:
            halves.append(float(np.median(np.diff(e))) * rec.dt)
    half = min(halves) if halves else math.nan
    need = guards[j] + 2 * margin_s + MIN_STRETCH_S
    # half periods of twice what is left out after each reversal: most of each is steady
    period = math.ceil(4 * need)
    return (f"channel {names[i]}: no steady stretch where channel {names[j]}'s valve moves, so "
            f"G[{names[i]},{names[j]}] cannot be estimated: {names[j]}'s meander reverses every "
            f"{half:.3g} s, and after each reversal {guards[j]:.3g} s are left out (its reversal "
            f"boost dies out there) and {MIN_STRETCH_S:g} s more are needed. Give longer meander "
            f"periods (stand campaign --rig ... --meander-period-s {period:d} or more), or a "
            "shorter guard with --guard-ms (the boost left in the stretches then biases G up)")


def _inseparable(names: list[str], j: int, vif: np.ndarray, corr: np.ndarray,
                 fitted: np.ndarray) -> str:
    """Why column ``j`` cannot be told apart, naming the column it moves most with."""
    N = len(names)
    others = [k for k in range(N + 1) if k != j and fitted[k]]
    k = max(others, key=lambda k: abs(corr[j, k])) if others else j
    with_ = "the trend Δ (its command is about constant on the steady parts)" if k == N \
        else f"channel {names[k]}"
    inflation = "infinite" if not math.isfinite(vif[j]) else f"{vif[j]:.3g}"
    return (f"the runs cannot tell column {names[j]} of G apart: on the steady parts its delayed "
            f"command moves with {with_} (correlation {corr[j, k]:+.3f}; variance inflation "
            f"{inflation}, at most {VIF_REFUSE:g} is accepted). Give every channel a meander "
            "period of its own that does not share harmonics with the others' (not equal, not "
            "a ratio of odd numbers such as 1:3; e.g. 8, 10, 12 and 15 s for four channels: "
            "analysis.rig.periods.separating_periods), or identify G column by column (one "
            "channel's meander per run, the other valves at a zero command)")
