r"""G from one short run: every channel's valve a Hadamard meander on one switching grid.

The experiment (:mod:`rig.excitation`; ``stand campaign --rig RIG --one-run``): channel j's
command is ``±u0_j`` with the signs of row j of a Hadamard matrix played as doublets, every
channel switching at the same instants ``b_k``, one slot ``L`` apart. Its run names the
experiment (:attr:`gateway.experiments.one_run.OneRun.name`) in ``run.json``;
:func:`.estimate.estimate_rig` hands such runs here. The model and the regression are the other designs' (eq. (2'),
:mod:`.steady`, :mod:`.regression`); what the common grid changes is where the steady
stretches are and how the reversal boosts are told apart:

1. **τ_j** from the turns of channel j's own force after its reversals (:mod:`.delays`), then
   again with the other channels' part ``Σ_{k≠j} Ĝ_jk ∫u_k(t − τ_k)`` taken off its force.
2. **One stretch per row and slot, all of one length**: row i's stretch in slot k runs from
   ``b_k + S_i`` to ``b_{k+1} + min_j τ_j − margin``, with ``S_i`` the latest arrival of the
   guard after a reversal of any channel that moves force i, ``max_{j∈C_i}(τ_j + guard_j) +
   margin`` (C_i: the channels whose column of the first estimate's row i is not zero within
   its interval, and i itself), and never before every command change has arrived. Stretches
   of one length keep the design orthogonal, as planned (a slot where no channel of C_i
   reverses would give a stretch many times longer, whose weight, ``Σ(t − t̄)²``, would
   outweigh the others hundreds of times and unbalance the columns: variance inflations of 7
   were measured so). The first look leaves :data:`FIRST_SHARE` of every slot out.
3. **Row by row least squares** of the stretches' slopes on the delayed commands with the
   cluster-robust intervals (:func:`.regression.fit_row`).
4. **The reversal boosts, jointly** (:func:`boost_curves`): every channel reverses on the same
   grid, so channel j's own force shows its neighbours' boosts (through G) on top of its own,
   and each curve of :func:`.delays.boost_window` would be cut at once. Instead, after each
   grid instant ``b`` the excess of every force over the steady rate the first estimate
   predicts, ``E_i(θ) = y_i(b + θ) − y_i(b) − ∫_b^{b+θ} (Σ_j Ĝ_ij u_j(t − τ_j) + Δ̂_i) dt``, is
   the sum of the boosts of the channels that reversed there,
   ``E_i(θ) = Σ_{j reversed} Ĝ_ij u_j β_j(θ)``, with ``β_j(θ)`` channel j's extra flow time
   (s) θ after its command reversed. At each θ one least squares over every force and grid
   instant gives every ``β_j(θ)`` (the reversal patterns are the Hadamard rows: orthogonal);
   channel j's transitional window is where ``β_j`` reaches 90 % of its final value, counted
   from its rod's reversal (``τ_j`` after the command's), its boost's extra that final value.
   The run's first instant is left out: whether the rods reversed there depends on the way they
   moved before (the stretches treat it as a reversal, to be safe; counted here it put the
   boosts 10 % low).
   The guard after channel j's reversals is :data:`.estimate.GUARD_FACTOR` windows, as in the
   other designs.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from core.errors import DataError
from gateway.experiments.one_run import OneRun

from ..records.limits import clipped_mask, held_mask
from .delays import ChannelTiming, channel_timing
from .estimate import (FIRST_GUARD_S, GUARD_FACTOR, MARGIN_S, MIN_STRETCH_S, VIF_NOTE,
                       VIF_REFUSE, moving_channels, open_loop, others_off)
from .record import RigRecord
from .regression import RowFit, Slopes, collinearity, fit_row, stretch_slopes
from .result import RigEstimate, physical_note
from .steady import command_events, delayed, stretches

#: the first look leaves this share of every slot out after its grid instant (the boosts' tails
#: then bias G by about 0.1 %: enough to read the boosts against)
FIRST_SHARE = 0.6


def is_one_run(rec: RigRecord) -> bool:
    """Whether a rig record is a one-run campaign's run (its run.json names the experiment)."""
    return (rec.meta.get("experiment") or {}).get("name") == OneRun.name


def slot_grid(rec: RigRecord) -> np.ndarray:
    """The samples where any channel's command changes, the first one included: the grid
    instants ``b_k`` (a run that starts at a non-zero command starts at sample 0)."""
    u = rec.u
    change = np.flatnonzero(np.any(np.diff(u, axis=1) != 0, axis=0)) + 1
    if u.shape[1] and np.any(u[:, 0] != 0):
        change = np.concatenate([[0], change])
    return change


def estimate_one_run(records: Sequence[RigRecord], guard_s: float | None = None,
                     margin_s: float = MARGIN_S, level: float = 0.95) -> RigEstimate:
    """G with its intervals, each channel's τ, Δ and reversal boost and the physical check from
    one-run campaign runs (module docstring). ``guard_s``: the time left out after every
    reversal (default: :data:`.estimate.GUARD_FACTOR` times each channel's window)."""
    records = list(records)
    names = records[0].names
    N = len(names)
    for rec in records:
        still = sorted(set(range(N)) - set(moving_channels(rec)))
        if still:
            raise DataError(f"{rec.source}: a one-run excitation moves every channel, but "
                            f"{', '.join(names[j] for j in still)} did not reverse twice (did "
                            "the run stop early? run the campaign again)")
    grids = [slot_grid(rec) for rec in records]
    slot = min(int(np.median(np.diff(g))) for g in grids)
    timing = _delays(records, names, None, level)
    taus = np.array([timing[j].tau_s for j in range(N)])
    first = np.full(N, max(FIRST_GUARD_S, FIRST_SHARE * slot * records[0].dt))
    G, fits, _ = _fit(records, grids, taus, _starts(taus, first, None, margin_s),
                      margin_s, level)
    delta = np.array([f.coef[N] for f in fits])
    timing = _delays(records, names, G, level, taus)
    taus = np.array([timing[j].tau_s for j in range(N)])
    boost = boost_curves(records, grids, G, delta, taus)
    windows = [boost_window(b, tau, records[0].dt) for b, tau in zip(boost, taus)]
    guards = np.array([guard_s if guard_s is not None
                       else GUARD_FACTOR * w[0] if w is not None else FIRST_GUARD_S
                       for w in windows])
    coupled = np.stack([(f.ci[:N, 0] > 0) | (f.ci[:N, 1] < 0) for f in fits]) | np.eye(N, dtype=bool)
    starts = _starts(taus, guards, coupled, margin_s)
    room = slot * records[0].dt - (starts - taus.min() + margin_s)
    if np.any(room < MIN_STRETCH_S):
        raise DataError(_too_short(names, int(np.argmin(room)), coupled, taus, guards, windows,
                                   slot * records[0].dt, margin_s))
    G, fits, vif = _fit(records, grids, taus, starts, margin_s, level)
    notes = []
    for j in range(N):
        if vif[j] > VIF_NOTE:
            notes.append(f"column {names[j]}: the commands are partly a combination of each "
                         f"other on the steady stretches (variance inflation {vif[j]:.2g}): its "
                         f"interval is {math.sqrt(vif[j]):.2g}× what orthogonal commands give")
    return RigEstimate(
        names=list(names), G=G, G_ci=np.stack([f.ci[:N] for f in fits]),
        delta_kgf_s=np.array([f.coef[N] for f in fits]),
        delta_ci=np.array([f.ci[N] for f in fits]), tau_s=taus,
        tau_ci_s=np.array([timing[j].tau_ci_s for j in range(N)]),
        transitional_s=np.array([w[0] if w is not None else 0.0 for w in windows]),
        transitional_detected=[w is not None for w in windows],
        boost_extra_s=np.array([w[1] if w is not None else 0.0 for w in windows]),
        amplitude_pct=np.array([timing[j].amplitude_pct for j in range(N)]),
        reversals=[timing[j].reversals for j in range(N)], design="one-run",
        moving={rec.source: list(names) for rec in records}, inflation=vif[:N],
        stretches=[f.stretches for f in fits],
        residual_kgf=np.array([f.residual_kgf for f in fits]),
        physical=physical_note(G, np.stack([f.ci[:N] for f in fits]), names, level),
        notes=notes, sources=[rec.source for rec in records], level=level)


def _delays(records: list[RigRecord], names: list[str], G: np.ndarray | None, level: float,
            taus: np.ndarray | None = None) -> dict[int, ChannelTiming]:
    """Each channel's τ from its own turns (:func:`.delays.channel_timing`), with a first
    estimate ``G`` (and the delays ``taus``) the other channels' part off its force first."""
    out = {}
    for j in range(len(names)):
        parts = []
        for rec in records:
            y = rec.y[j] if G is None else others_off(rec, j, G, taus, range(rec.n))
            parts.append((np.where(open_loop(rec), rec.u[j], 0.0), y, None, math.nan, rec.dt,
                          None))
        out[j] = channel_timing(parts, names[j], level)
    return out


def _starts(taus: np.ndarray, guards: np.ndarray, coupled: np.ndarray | None,
            margin_s: float) -> np.ndarray:
    """Each row's stretch start after a grid instant, s: every command change arrived and the
    margin passed, and the guard after the reversal of every channel that moves the row
    (``coupled[i]``; None: every channel)."""
    N = len(taus)
    last = taus.max() + margin_s
    out = np.empty(N)
    for i in range(N):
        c = np.ones(N, bool) if coupled is None else coupled[i]
        out[i] = max(last, float(np.max(taus[c] + guards[c])) + margin_s)
    return out


def _fit(records: list[RigRecord], grids: list[np.ndarray], taus: np.ndarray,
         starts: np.ndarray, margin_s: float, level: float
         ) -> tuple[np.ndarray, list[RowFit], np.ndarray]:
    """Every row of G from one stretch per slot (module docstring), each column's largest
    variance inflation over the rows; a design that cannot separate a column is refused."""
    names = records[0].names
    N = len(names)
    fitted = np.ones(N + 1, bool)
    fits, inflation = [], np.full(N + 1, np.nan)
    uds = [np.vstack([delayed(rec.u[j], rec.dt, taus[j]) for j in range(N)]) for rec in records]
    for i in range(N):
        X, parts = [], []
        for rec, grid, ud in zip(records, grids, uds):
            dt, K = rec.dt, len(rec)
            y = rec.y[i]
            ok = open_loop(rec) & ~clipped_mask(y) & ~held_mask(rec.u[i], y, dt)
            ends = np.append(grid[1:] + int(round(taus.min() / dt)) - int(np.ceil(margin_s / dt)), K)
            window = np.zeros(K, bool)
            for b, e in zip(grid, ends):
                window[min(K, b + int(np.ceil(starts[i] / dt))):min(K, e)] = True
            spans = stretches(ok & window, max(3, int(round(MIN_STRETCH_S / dt))))
            parts.append(stretch_slopes(rec.t, y, spans))
            X += [np.append(ud[:, (a + b) // 2], 1.0) for a, b in spans]
        sl = Slopes(*(np.concatenate([getattr(p, f) for p in parts])
                      for f in ("slope", "weight", "sse", "samples")))
        if len(X) < N + 2:
            raise DataError(f"channel {names[i]}: only {len(X)} steady stretch(es) of at least "
                            f"{MIN_STRETCH_S:g} s where its force is not clipped or held, for "
                            f"{N + 1} unknowns of its row: the run is too short or stopped early "
                            "(run the one-run campaign again)")
        X = np.array(X)
        vif, corr = collinearity(X, sl.weight, fitted)
        if np.nanmax(vif[:N]) > VIF_REFUSE:
            j = int(np.nanargmax(vif[:N]))
            raise DataError(f"channel {names[i]}: the run's steady stretches cannot tell column "
                            f"{names[j]} of G apart (variance inflation {vif[j]:.3g}, at most "
                            f"{VIF_REFUSE:g} is accepted): its force was clipped or held over "
                            "much of the run, or the run stopped early; run the one-run "
                            "campaign again (a smaller --amplitude-pct keeps the forces clear of "
                            "their limits)")
        inflation = np.fmax(inflation, vif)
        fits.append(fit_row(X, sl, fitted, level))
    return np.stack([f.coef[:N] for f in fits]), fits, inflation


def boost_curves(records: list[RigRecord], grids: list[np.ndarray], G: np.ndarray,
                 delta: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """Every channel's extra flow time ``β_j(θ)`` (s) θ after its command reversed, ``(N,
    slot samples)``, by one least squares per θ over every force and grid instant (module
    docstring, step 4)."""
    N = G.shape[0]
    slot = min(int(np.median(np.diff(g))) for g in grids)
    rows_A, rows_E = [], []
    for rec, grid in zip(records, grids):
        dt, K = rec.dt, len(rec)
        u, y = rec.u, rec.y
        ud = np.vstack([delayed(u[j], dt, taus[j]) for j in range(N)])
        rate = G @ ud + delta[:, None]
        steady = np.concatenate([np.zeros((N, 1)), np.cumsum(rate, axis=1)], axis=1) * dt
        reversed_at = np.zeros((N, K), bool)
        for j in range(N):
            e, rev = command_events(u[j])
            reversed_at[j, e[rev]] = True
        bad = ~open_loop(rec)[None, :] | np.vstack([clipped_mask(y[i]) for i in range(N)])
        for b in grid[1:]:      # the first: the rods' way before the run is unknown
            if b + slot > K or not reversed_at[:, b].any():
                continue
            rev = reversed_at[:, b]
            for i in range(N):
                if bad[i, b:b + slot].any():
                    continue
                rows_A.append(np.where(rev, G[i] * u[:, b], 0.0))
                rows_E.append(y[i, b:b + slot] - y[i, b] - (steady[i, b:b + slot] - steady[i, b]))
    if len(rows_A) < N:
        return np.full((N, slot), np.nan)
    beta, *_ = np.linalg.lstsq(np.array(rows_A), np.array(rows_E), rcond=None)
    return beta


def boost_window(beta: np.ndarray, tau_s: float, dt: float) -> tuple[float, float] | None:
    """Channel's transitional window (s, from its rod's reversal) and the boost's extra (s of
    its steady rate) from its curve ``β(θ)`` (:func:`boost_curves`): where ``|β|`` first reaches
    90 % of its final value (the median of its second half); None when that value is not
    clearly above the curve's noise there (as :func:`.delays.boost_window`)."""
    if not np.all(np.isfinite(beta)):
        return None
    n = len(beta)
    late = beta[n // 2:]
    theta = np.arange(n // 2, n) * dt
    final = float(np.median(late))
    noise = float(np.std(late - np.polyval(np.polyfit(theta, late, 1), theta)))
    if abs(final) < max(5 * noise, 2 * dt):
        return None
    lag = int(round(tau_s / dt))
    reached = np.flatnonzero(np.abs(beta[lag:]) >= 0.9 * abs(final))
    return (float(reached[0] * dt), final) if len(reached) else None


def _too_short(names: list[str], i: int, coupled: np.ndarray, taus: np.ndarray,
               guards: np.ndarray, windows: list, slot_s: float, margin_s: float) -> str:
    """Why row ``i`` has no steady stretch in the run's slots, and what to do."""
    c = np.flatnonzero(coupled[i])
    j = int(c[np.argmax(taus[c] + guards[c])])
    w = windows[j]
    why = (f"its reversal boost lasts {w[0] * 1e3:.0f} ms (transitional window), so "
           f"{guards[j]:.3g} s are left out after each of its reversals" if w is not None
           else f"{guards[j]:.3g} s are left out after each of its reversals")
    need = taus.max() - taus.min() + guards[j] + 2 * margin_s + MIN_STRETCH_S
    return (f"channel {names[i]}: the one-run slots of {slot_s:.3g} s leave no steady stretch of "
            f"{MIN_STRETCH_S:g} s for its row of G after channel {names[j]}'s reversals: {why}. "
            f"Plan the one-run campaign for that boost (stand campaign --rig ... --one-run "
            f"--transitional-ms {math.ceil((w[0] if w is not None else guards[j] / GUARD_FACTOR) * 1e3):d}"
            f" gives slots of at least {need:.3g} s), or shorten the guard with --guard-ms (the "
            "boost left in the stretches then biases G up)")


# ------------------------------------------------------------------------------------------
# the plan
# ------------------------------------------------------------------------------------------
#: the transitional window the plan assumes when not told, s (the paper's: the emulator's
#: default boost, decaying in 0.15 s, adds 90 % of its force within 0.345 s)
TRANSITIONAL_S = 0.35


def left_out_s(transitional_s: float) -> float:
    """What this estimate leaves out of every slot (s): the guard after the reversals
    (:data:`.estimate.GUARD_FACTOR` windows), the delays' spread the plan allows
    (:data:`rig.excitation.DELAY_SPREAD_S`) and the margins either side."""
    from rig.excitation import DELAY_SPREAD_S
    return GUARD_FACTOR * transitional_s + DELAY_SPREAD_S + 2 * MARGIN_S


def plan_for_rig(rig, amplitude_pct: float, accuracy_pct: float | None,
                 transitional_s: float = TRANSITIONAL_S, noise_kgf: float = 2.0,
                 duration_s: float | None = None, level: float = 0.95):
    """The one-run design for a rig file (:func:`rig.excitation.plan_one_run`): its channels,
    the smallest diagonal entry of its G (None without G: the accuracy is not planned, and a
    ``duration_s`` is then needed), the slot that leaves a steady stretch after this
    estimate's guard. :class:`ParameterError` with what to do when it does not fit."""
    from core.errors import ParameterError
    from rig.excitation import plan_one_run
    for what, value, lo, hi in (("--accuracy-pct", accuracy_pct, 1e-3, 100.0),
                                ("--transitional-ms", transitional_s * 1e3, 0.0, 5000.0),
                                ("--noise-kgf", noise_kgf, 0.0, 1e4),
                                ("--amplitude-pct", amplitude_pct, 1e-3, 100.0)):
        if value is not None and not (lo < value <= hi if what != "--transitional-ms"
                                      else lo <= value <= hi):
            raise ParameterError(f"{what} {value:g} is out of range: give more than {lo:g}, up "
                                 f"to {hi:g}")
    if duration_s is not None and not (0 < duration_s <= 36000):
        raise ParameterError(f"--duration-s {duration_s:g} is out of range: give more than 0, up to 36000")
    g = None
    if rig.G is not None:
        g = float(np.min(np.diag(np.asarray(rig.G, float))))
    elif duration_s is None:
        raise ParameterError(f"{rig.where}: the rig file gives no G ([structure]), so the plan "
                             "cannot say how long the run must be for an accuracy (it needs each "
                             "channel's g): give --duration-s S (the run is then as long, its "
                             "accuracy unplanned), or G in the rig file")
    try:
        return plan_one_run(len(rig.names), amplitude_pct, rig.period_s, left_out_s(transitional_s),
                            noise_kgf, g, accuracy_pct, duration_s, level)
    except ValueError as exc:
        raise ParameterError(str(exc)) from None


def describe_design(design, transitional_s: float) -> str:
    """The plan in words, before anything moves."""
    d = design
    amps = (f"±{d.amplitude_pct[0]:g} %" if len(set(d.amplitude_pct)) == 1
            else f"±{min(d.amplitude_pct):g} to {max(d.amplitude_pct):g} %")
    head = (f"one run of Hadamard meanders: {d.channels} channel(s) on {d.slots} slots of "
            f"{d.slot_s:.4g} s (order {d.order} as doublets"
            f"{f', {d.repeats} times' if d.repeats > 1 else ''}) = {d.duration_s:.4g} s of stand "
            f"time at {amps}")
    if math.isfinite(d.planned_pct):
        what = (f"planned: every entry of G within ±{d.planned_pct:.2g} % of the smallest "
                f"diagonal ({d.smallest_g:.4g} kgf/(%·s)), all {d.channels ** 2} at once at "
                f"{100 * d.level:.0f} %")
        if d.requested_pct is not None:
            what += f" (asked: ±{d.requested_pct:g} %)"
    else:
        what = "accuracy not planned (the rig file gives no G)"
    return (f"{head}\n  {what}; for {d.noise_kgf:g} kgf of noise and transitional windows up to "
            f"{transitional_s * 1e3:.0f} ms ({d.left_out_s:.3g} s left out after each slot's "
            f"reversals, {d.steady_s:.3g} s steady)")
