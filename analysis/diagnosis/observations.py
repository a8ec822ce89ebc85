"""The residual in plain words: where and how a model misses the data.

For the starting model: the error against the noise, the transient after the rod's reversals
(:func:`reversal_transient`), the extend/retract slopes and the slope per command level
(:func:`slope_observations`), a gain that drifts during the runs (:func:`drift_observation`),
timing jitter of the command steps (:mod:`.timing`), where the error concentrates, and the
residual tests. When nothing explains the error: its periodic part or where it lives
(:func:`describe_unexplained`). And whether what a model leaves is noise after all (correlated
in time: a filtered sensor), not structure (:func:`residual_is_noise`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from plant import PlantModel

from ..identification.fit import FitResult
from ..identification.periodic import Segment, dominant_periodic, residual_periodic
from ..identification.metrics import (AFTER_REVERSAL_S, Evaluation, RecordSimulation,
                                      command_levels, demeaned_residual, input_correlation_test,
                                      is_closed_loop, reversal_mask, simulate_records,
                                      window_increments)
from ..identification.windows import pieces_from_records
from ..records.record import Record
from .timing import jitter_observation

#: p-value below which the residual counts as related to the command (a real model error gives
#: p-values many orders smaller; 0.001 keeps noise from ever being called structure)
NOISE_P = 1e-3
#: a residual whose mean square late in the windows (80-100 % of the horizon) differs from its
#: mean square early on (20-40 %) by more than this factor, either way, changes along the
#: free-run: a model error, not noise (noise, white or coloured, gives n(t) − n(t₀): flat once
#: past its correlation time; filtered noise up to 0.2 s gave 0.70-1.71 on 16 s records)
NOISE_GROWTH_MAX = 2.0
#: a change of the model's relative slope error of at least this much over the records is
#: worth saying
GAIN_CHANGE_MIN = 0.04


@dataclass
class Unexplained:
    dominant_frequency_hz: float | None
    amplitude_kgf: float | None
    periodic_share: float         #: share of the excess error a sinusoid at that frequency explains
    rmse_over_floor: float
    correlated_with_command: bool
    description: str
    #: what the user can do: write the missing law as a plug-in, at the stage it suggests
    next_step: str = ""
    #: where the residual's rate over the flow has a line (a gain changing periodically)
    gain_frequency_hz: float | None = None


def pct(x: float) -> str:
    """A fraction in words: '42 %'."""
    return f"{100 * x:.0f} %"


def describe_residual(ev: Evaluation) -> list[str]:
    """Plain-words description of where and how the model ``ev.model`` misses the data."""
    out: list[str] = []
    floor = ev.noise_floor
    out.append(f"windowed RMSE {ev.rmse:.3g} kgf, fit {ev.fit_percent:.2f} %; noise floor "
               f"{floor:.3g} kgf (σ = {ev.noise_sigma:.3g} kgf); with the window starts "
               f"re-estimated the error is {ev.excess_ratio:.2f}× what the noise allows")
    rev = reversal_transient(ev.sims, ev.model.tau)
    if rev is not None:
        out.append(rev)
    out += slope_observations(ev.sims)
    if ev.excess_ratio > 1.1:
        out += drift_observation(ev.sims)
        out += jitter_observation(ev.sims, ev.model.g)
    conc = [r for r in ev.regimes if r.group == "reversal" and r.name.startswith("first")]
    if conc and ev.excess_ratio > 1.1:
        r = conc[0]
        if r.sse_share > 1.5 * r.time_share and r.sse_share > 0.3:
            out.append(f"error concentrates in the {AFTER_REVERSAL_S:g} s after each reversal: "
                       f"{pct(r.sse_share)} of the squared error in {pct(r.time_share)} of the time")
    if ev.excess_ratio > 1.1:
        worst = ev.worst_windows(3)
        out.append("worst windows: " + ", ".join(
            f"{w.t_start:.1f}–{w.t_end:.1f} s ({w.rmse:.3g} kgf, {w.regime})" for w in worst))
    if not ev.whiteness.white and ev.excess_ratio > 1.1:
        out.append("the residual is not white (autocorrelation beyond the ±1.96/√N band): "
                   "structure is left in it")
    if not ev.input_correlation.white and ev.excess_ratio > 1.1:
        out.append("the residual is correlated with the command: the model misses part of the "
                   "command's effect")
    return out


def reversal_transient(sims: Sequence[RecordSimulation], tau: float,
                       horizon_s: float = 0.6) -> str | None:
    """Ensemble of the residual after each rod reversal: the extra force the model misses in the
    new direction, and how fast it builds up ("error concentrates in the 0.2 s after ...")."""
    curves, dts = [], []
    for s in sims:
        dt = s.record.dt
        rev, _ = reversal_mask(s.q, dt)
        L = int(round(horizon_s / dt))
        for i in rev:
            w = s.win[i]
            if i + L >= len(s.r) or s.win[i + L] != w or i == 0:
                continue
            sgn = np.sign(s.q[i])
            # measured minus model, in the new direction of motion, from the reversal on
            curves.append(-(s.r[i:i + L] - s.r[i]) * sgn)
            dts.append(dt)
    if len(curves) < 3 or len(set(dts)) != 1:
        return None
    c = np.vstack(curves)
    dt = dts[0]
    mean = c.mean(axis=0)
    se = c.std(axis=0, ddof=1) / math.sqrt(len(c))
    phases = []
    for sign in (1, -1):
        k = int(np.argmax(sign * mean))
        if k > 0 and sign * mean[k] > max(4 * se[k], 1e-9):
            phases.append((k, float(mean[k])))
    if not phases:
        return None
    phases.sort()
    words = []
    for k, peak in phases:
        if peak > 0:
            words.append(f"moves up to {peak:.3g} kgf further in the new direction than the model "
                         f"predicts (at {k * dt:.2f} s)")
        else:
            words.append(f"lags up to {-peak:.3g} kgf behind the model (at {k * dt:.2f} s)")
    first, last = phases[0], phases[-1]
    if len(phases) == 2:
        meaning = ("a slow start then a faster take-off than the model: a transient after the "
                   "change of direction that the model lacks" if first[1] < 0 else
                   "a fast start then a slower ramp than the model: a transient after the change "
                   "of direction that the model lacks")
    elif first[1] > 0:
        meaning = "a faster take-off after a change of direction than the model has"
    else:
        meaning = "a slower take-off than the model: a lag, or more delay"
    return ("after each reversal the force " + ", then ".join(words)
            + f": the error concentrates in the first {last[0] * dt:.2f} s after the reversals "
            f"({meaning})")


def slope_observations(sims: Sequence[RecordSimulation]) -> list[str]:
    """Measured slope per % command on steady stretches: extend vs retract, and per |u| level."""
    num_e = num_r = den_e = den_r = 0.0
    lv_num: dict[int, float] = {}
    lv_den: dict[int, float] = {}
    q_all = np.concatenate([s.q for s in sims])
    groups, names = command_levels(np.abs(q_all))
    k0 = 0
    for s in sims:
        dt = s.record.dt
        _, after = reversal_mask(s.q, dt)
        dy = np.diff(s.y, append=s.y[-1])
        steady = ~after & (s.q != 0)
        steady[-1] = False
        g = groups[k0:k0 + len(s.q)]
        k0 += len(s.q)
        ext, ret = steady & (s.q > 0), steady & (s.q < 0)
        num_e += float(dy[ext].sum())
        den_e += float(s.q[ext].sum() * dt)
        num_r += float(dy[ret].sum())
        den_r += float(s.q[ret].sum() * dt)
        for lv in np.unique(g[steady]):
            sel = steady & (g == lv)
            lv_num[lv] = lv_num.get(lv, 0.0) + float((dy[sel] * np.sign(s.q[sel])).sum())
            lv_den[lv] = lv_den.get(lv, 0.0) + float(np.abs(s.q[sel]).sum() * dt)
    out = []
    if den_e > 0 and den_r < 0:
        ge, gr = num_e / den_e, num_r / den_r
        if ge > 0 and gr > 0 and abs(gr / ge - 1) >= 0.03:
            word = "lower" if gr < ge else "higher"
            out.append(f"retract slope is {abs(gr / ge - 1) * 100:.0f} % {word} than extend "
                       f"({gr:.4g} vs {ge:.4g} kgf/s per % command): an extend/retract asymmetry"
                       f" (or, at a single amplitude, the trend Δ)")
    gains = {lv: lv_num[lv] / lv_den[lv] for lv in lv_num if lv_den[lv] > 0 and lv >= 0}
    if len(gains) >= 2 and len(names) <= 6:
        lo_lv, hi_lv = min(gains), max(gains)
        glo, ghi = gains[lo_lv], gains[hi_lv]
        if ghi > 0 and abs(glo / ghi - 1) >= 0.03:
            word = "lower" if glo < ghi else "higher"
            hint = ("a dead zone (or a transient after reversals)" if glo < ghi
                    else "a flow limit (saturation) or a reversal boost that weighs more at small |u|")
            out.append(f"slope per % command is {abs(glo / ghi - 1) * 100:.0f} % {word} at "
                       f"{names[lo_lv]} than at {names[hi_lv]} ({glo:.4g} vs {ghi:.4g}): {hint}")
    return out


def drift_observation(sims: Sequence[RecordSimulation]) -> list[str]:
    """Does the model's slope error along the motion (steady stretches, away from reversals)
    change from the start of the records to their end? That is a gain that drifts during a run
    (oil warming up, supply pressure sagging): what ``gain_drift`` models, said in words
    because the records' clocks may not start with the runs.

    (The same comparison across |force| levels was tried for a specimen stiffness and dropped:
    between records |force| goes with the command level and the experiment, so a dead zone, a
    leak or a reversal boost made it speak of a stiffness; the ``stiffness`` candidate's fit
    tells it apart instead.)"""
    dr, dyh, _ = window_increments(sims)
    steady, sgn, into = [], [], []
    for s in sims:
        _, after = reversal_mask(s.q, s.record.dt)
        steady.append(~after & (s.q != 0) & (s.horizon > 0))
        sgn.append(np.sign(s.q))
        into.append((s.t - s.record.t[0]) / max(s.record.duration_s, s.record.dt))
    steady = np.concatenate(steady)
    along = (dr * np.concatenate(sgn))[steady]
    speed = np.abs(dyh)[steady]
    into = np.concatenate(into)[steady]

    def rel(sel: np.ndarray) -> float:
        v = float(speed[sel].sum())
        return float(along[sel].sum()) / v if v > 1e-9 and sel.sum() > 50 else math.nan

    first, last = rel(into < 0.25), rel(into >= 0.75)
    if not abs(first - last) >= GAIN_CHANGE_MIN:     # NaN (too little motion) says nothing
        return []
    return [f"the model's slope is {_signed_pct(first)} in the first quarter of the records and "
            f"{_signed_pct(last)} in the last: the gain {'grows' if last < first else 'falls'} "
            f"during a run (oil warming up, supply pressure changing): the `gain_drift` effect "
            f"models that; or let the stand warm up before measuring"]


def _signed_pct(x: float) -> str:
    """A relative slope error in words: '6 % too fast' / '4 % too slow'."""
    return f"{abs(x) * 100:.0f} % too {'fast' if x > 0 else 'slow'}"


#: a line in the residual's rate over the flow standing out this many times from its
#: surroundings, at no frequency of the command, reads as a gain that changes periodically
GAIN_LINE_PROMINENCE = 100.0


def describe_unexplained(ev: Evaluation, floor: float, ratio: float,
                         fit: FitResult) -> Unexplained:
    """What the residual left by every candidate looks like: periodic or broadband, where; and
    when the force's residual is not periodic, whether the gain is (a periodic change of the
    gain under a reversing command shows in the force only as sidebands)."""
    f, amp, share = periodic_component(ev.sims, floor)
    corr = command_has_line(ev.sims, f) if f is not None else False
    closed = is_closed_loop(ev.sims)
    gain_f = None
    if f is not None and share >= 0.5:
        desc = (f"the residual is periodic at {f:.3g} Hz (amplitude ≈ {amp:.3g} kgf, "
                f"{pct(share)} of the error above the noise)"
                + ((", and the command has it too: in closed loop the controller reacts to a "
                    "disturbance, so this alone does not tell cause from effect" if closed else
                    ", at a frequency where the command has a spectral line (the command's period "
                    "or a harmonic): a response to the command the model lacks") if corr else
                   ", unrelated to the command — like an external disturbance (a neighbouring "
                   "actuator, a structural resonance, pump ripple)"))
    else:
        where = max((r for r in ev.regimes if r.group in ("reversal", "direction")
                     and r.time_share >= 0.01),      # not a regime of a few samples
                    key=lambda r: r.sse_share / max(r.time_share, 1e-9), default=None)
        desc = "the residual is broadband (no dominant frequency)"
        if f is not None:
            desc += f"; its strongest periodic part is at {f:.3g} Hz ({pct(share)} of the excess)"
        if where is not None:
            desc += (f"; it is largest in '{where.name}' ({pct(where.sse_share)} of the squared "
                     f"error in {pct(where.time_share)} of the time)")
        records = list({id(s.record): s.record for s in ev.sims}.values())
        gain = residual_periodic(fit.model, pieces_from_records(records, ev.window_s), "flow")
        if (gain.frequency_hz is not None and gain.prominence >= GAIN_LINE_PROMINENCE
                and not command_has_line(ev.sims, gain.frequency_hz)):
            gain_f = gain.frequency_hz
            desc += (f"; read as a change of the gain (the residual's rate over the flow g·q), "
                     f"it is periodic at {gain_f:.3g} Hz ({gain.prominence:.0f}× its "
                     f"surroundings, ≈ {100 * gain.amplitude_kgf:.2g} % of g): a gain that "
                     f"changes at {gain_f:.3g} Hz, such as a supply pressure that oscillates")
    if f is not None and share >= 0.5 and not corr:
        stage, law = "disturbance", f"a force at {f:.3g} Hz"
    elif f is not None and share >= 0.5:
        stage, law = "flow", f"a gain that changes at {f:.3g} Hz"
    elif gain_f is not None:
        stage, law = "flow", f"a gain that changes at {gain_f:.3g} Hz"
    else:
        stage, law = "flow", "the law"
    step = (f"next: write {law} as an effect of your own (`stand effects --new NAME --stage "
            f"{stage} > NAME.py`, docs/your-own-effect.md) and diagnose again with "
            f"--effects NAME.py")
    return Unexplained(dominant_frequency_hz=f, amplitude_kgf=amp, periodic_share=share,
                       rmse_over_floor=ratio, correlated_with_command=corr, description=desc,
                       next_step=step, gain_frequency_hz=gain_f)


def residual_is_noise(model: PlantModel, records: Sequence[Record], window_s: float,
                      floor: float) -> bool:
    """The residual of ``model`` is noise-like: not correlated with the command (prewhitened
    cross-correlation test, p ≥ :data:`NOISE_P`), not growing or shrinking along the free-run
    windows (:func:`horizon_growth` within :data:`NOISE_GROWTH_MAX`) and without a periodic component that
    carries half of its excess over ``floor``."""
    sims = simulate_records(model, records, window_s)
    dt = min(s.record.dt for s in sims)
    L = int(max(10, min(250, round(0.25 / dt))))
    if input_correlation_test(sims, L).p_value < NOISE_P:
        return False
    growth = horizon_growth(sims)
    if not 1 / NOISE_GROWTH_MAX <= growth <= NOISE_GROWTH_MAX:
        return False
    f, _, share = periodic_component(sims, floor)
    return f is None or share < 0.5


def horizon_growth(sims: Sequence[RecordSimulation]) -> float:
    """Mean square residual late in the windows (80-100 % of the horizon) over early on
    (20-40 %). A free-run from a measured start accumulates a model's error (a wrong gain grows
    linearly: ≈ 9×; a model fitted with re-estimated window starts can also leave its error
    early in the windows: 0.3× seen), while measurement noise only contributes n(t) − n(t₀),
    flat once past its correlation time (≈ 1×)."""
    early = late = 0.0
    n_early = n_late = 0
    for s in sims:
        h = s.horizon / s.window
        r2 = s.r ** 2
        e = (h >= 0.2) & (h < 0.4)
        l8 = h >= 0.8
        early += float(r2[e].sum())
        late += float(r2[l8].sum())
        n_early += int(e.sum())
        n_late += int(l8.sum())
    if not n_early or not n_late or early <= 0:
        return 1.0
    return (late / n_late) / (early / n_early)


def command_has_line(sims: Sequence[RecordSimulation], f: float) -> bool:
    """Whether the command has a spectral line at ``f`` (its fundamental or a harmonic): its
    power in the bin of ``f`` is ten times its median power around it."""
    from scipy.signal import welch
    dt = sims[0].record.dt
    seg = 1 << int(math.ceil(math.log2(max(16, round(8.0 / dt)))))
    u = np.concatenate([s.u for s in sims if s.record.dt == dt])
    fr, p = welch(u - u.mean(), fs=1 / dt, nperseg=min(seg, len(u)))
    k = int(np.argmin(np.abs(fr - f)))
    around = p[max(1, k - 20):k + 21]
    return bool(p[max(0, k - 1):k + 2].max() > 10 * np.median(around))


def periodic_component(sims: Sequence[RecordSimulation], floor: float,
                       max_samples: int = 400_000) -> tuple[float | None, float | None, float]:
    """Dominant frequency of the residual (:func:`..identification.periodic.dominant_periodic`).
    Returns (frequency Hz, amplitude kgf, share of the excess squared error it explains)."""
    segments = [Segment(s.t, x, s.win, s.record.dt, s.window)
                for s, x in zip(sims, demeaned_residual(sims))]
    found = dominant_periodic(segments, max_samples)
    if found.frequency_hz is None:
        return None, None, 0.0
    return found.frequency_hz, found.amplitude_kgf, found.share(floor)
