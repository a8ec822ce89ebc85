r"""How well a model reproduces measurements: the windowed free-run error and where it lives.

**Windowed free-run error.** Each record is cut into windows (default 2 s); in every window the
model is simulated *open loop* from the measured force at the window's first sample, driven by
the recorded command, with the command history (delay line, valve and reversal states) running
continuously through the record. The first :data:`~.windows.LEAD_S` of a record only primes
that history (the commands before the record are unknown). With ``ŷ`` the simulation:

.. math::

    \mathrm{RMSE} = \sqrt{\tfrac1N\textstyle\sum_k (y_k - \hat y_k)^2}\ \ [\mathrm{kgf}],\qquad
    \mathrm{fit} = 100\Big(1 - \frac{\lVert y - \hat y\rVert}{\lVert y - \bar y\rVert}\Big)\ [\%],

overall, per window and per regime.

**Noise σ.** From second differences (white noise: ``var Δ²e = 6σ²``), taken of the model's
residual inside its windows, where the force's corners the model reproduces have cancelled
(:func:`residual_noise_sigma`; of the force itself, :func:`noise_sigma`, when no model is at hand);
remaining outliers (beyond five robust standard deviations) are dropped.

**Noise floor.** A perfect model still shows the measurement noise twice: in the sample and in
the window's starting value, ``r_k = e_0 − e_k``, so the floor is ``√2·σ`` (the first sample of a
window has no error: ``σ·sqrt(2(1 − 1/W))``). σ comes from the second differences of the force
(:func:`noise_sigma`, robust to the corners of the command). With few windows the actual floor
scatters around this value (the window starts are few noise draws); the fit and the diagnosis
therefore judge models on the error with re-estimated window starts, whose floor is
``σ·sqrt(1 − 1/W)`` and does not scatter.

**Regimes.** The rod's direction is the sign of the delayed command ``u(t − τ)``:

* ``after reversal`` (within :data:`AFTER_REVERSAL_S` of a change of direction) vs ``steady``;
* ``extend`` (u > 0, force rising) vs ``retract`` (u < 0) vs ``hold`` (u = 0);
* ``|u|`` level (the distinct levels of a meander/relay, else quartiles);
* force level (quartiles of the measured force).

Per regime: RMSE, share of the squared error, and the *rate bias* — the mean slope error of the
model, ``mean(Δr)/dt`` (kgf/s), also relative to the model's mean slope there.

**Residual tests.** Whiteness: autocorrelation of the residual with each window's mean removed
(that removes ``e_0``; what remains is white if the model is right). Input–residual
cross-correlation at lags ``−L … L``. Both with the ``±1.96/√N`` band of a white sequence of
length N (95 % per lag; N = the samples used, at most :data:`MAX_TEST_SAMPLES` spread over the
data). In closed loop (relay, P-feedback) the command is computed from the noisy
force, so the cross-correlation at lags where the residual leads is expected to be non-zero.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from functools import cached_property
from typing import Sequence

import numpy as np

from plant import PlantModel

from ..records.record import Record
from .windows import WINDOW_S, pieces_from_records, simulate_piece

#: length of the "just after a reversal" regime, s
AFTER_REVERSAL_S = 0.2


# ------------------------------------------------------------------------------------------
# noise
# ------------------------------------------------------------------------------------------
def noise_sigma(y: np.ndarray) -> float:
    """Standard deviation of white measurement noise from second differences (kgf).

    ``Δ²y_k = y_{k+1} − 2y_k + y_{k−1}`` has variance ``6σ²`` plus the force's curvature, which is
    negligible except at the corners of the command; those are removed as outliers (beyond five
    robust standard deviations) before ``σ̂ = rms(Δ²y)/√6``. Quantization (resolution q) adds its
    ``q²/12`` like any white noise."""
    y = np.asarray(y, float)
    if len(y) < 5:
        return math.nan
    d2 = y[2:] - 2 * y[1:-1] + y[:-2]
    spread = 1.4826 * float(np.median(np.abs(d2 - np.median(d2))))
    if spread == 0.0:
        spread = float(np.std(d2))
    if spread == 0.0:
        return 0.0
    keep = np.abs(d2) <= 5 * spread
    return float(math.sqrt(np.mean(d2[keep] ** 2) / 6))


def residual_noise_sigma(sims: Sequence["RecordSimulation"]) -> float:
    """σ̂ from the second differences of the model's residual inside its windows: the same
    estimator as :func:`noise_sigma`, but the corners of the force that the model reproduces
    (every command switch delayed by τ, frequent in relay data) are gone first."""
    d2s = []
    for s in sims:
        r = s.r
        if len(r) < 5:
            continue
        d2 = r[2:] - 2 * r[1:-1] + r[:-2]
        h = s.horizon
        inside = (h[2:] >= 2)  # all three samples in the same window
        d2s.append(d2[inside])
    if not d2s:
        return math.nan
    d2 = np.concatenate(d2s)
    spread = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) or float(np.std(d2))
    if spread == 0.0:
        return 0.0
    keep = np.abs(d2) <= 5 * spread
    return float(math.sqrt(np.mean(d2[keep] ** 2) / 6))


def pooled_noise_sigma(records: Sequence[Record]) -> float:
    num = sum(noise_sigma(r.y) ** 2 * len(r) for r in records)
    return math.sqrt(num / sum(len(r) for r in records))


# ------------------------------------------------------------------------------------------
# the evaluation of one model on a data set
# ------------------------------------------------------------------------------------------
@dataclass
class RecordSimulation:
    """Windowed simulation of one record (or one unclipped stretch of it): the evaluated samples
    only, after the lead-in."""

    record: Record
    start: int                  #: index of the first evaluated sample in the record
    window: int                 #: window length, samples
    y: np.ndarray               #: measured force, kgf
    yhat: np.ndarray            #: simulated force, kgf
    u: np.ndarray               #: command, %
    q: np.ndarray               #: delayed command u(t − τ) (whole samples), %
    t: np.ndarray               #: time, s
    index: int = 0              #: index of the record in the data set

    @cached_property
    def r(self) -> np.ndarray:
        """Residual ``ŷ − y`` (model minus measurement), kgf."""
        return self.yhat - self.y

    @cached_property
    def win(self) -> np.ndarray:
        return np.arange(len(self.y)) // self.window

    @cached_property
    def horizon(self) -> np.ndarray:
        return np.arange(len(self.y)) % self.window


def simulate_records(model: PlantModel, records: Sequence[Record],
                     window_s: float = WINDOW_S) -> list[RecordSimulation]:
    out = []
    for piece in pieces_from_records(records, window_s):
        rec = records[piece.record]
        yhat = simulate_piece(model, piece)
        a = piece.start + piece.warmup
        b = piece.start + len(piece.u)
        m = int(round(model.tau / rec.dt))
        q = np.concatenate([np.full(m, rec.u[0]), rec.u])[:len(rec.u)] if m else rec.u
        out.append(RecordSimulation(rec, a, piece.window, rec.y[a:b], yhat, rec.u[a:b], q[a:b],
                                    rec.t[a:b], piece.record))
    return out


@dataclass
class WindowStat:
    record: int
    t_start: float
    t_end: float
    rmse: float
    fit_percent: float
    regime: str               #: the regime that dominates the window's error growth


@dataclass
class RegimeStat:
    group: str                #: "reversal", "direction", "command level", "force level"
    name: str
    n: int
    time_share: float         #: share of the samples
    rmse: float               #: kgf
    sse_share: float          #: share of the squared error
    rate_bias: float          #: mean slope error of the model, kgf/s (model minus measured)
    rate_bias_rel: float      #: slope error along the motion / model speed (+: model too fast)


@dataclass
class CorrelationTest:
    """Correlation at several lags with the 95 % band of a white sequence, and one overall
    portmanteau test (lags are not independent, so "share outside the band" alone misleads)."""

    lags: list[int]
    values: list[float]
    band: float               #: ±1.96/√N
    n: int
    outside_share: float      #: share of lags outside the band
    max_abs: float
    q_statistic: float = math.nan   #: N·Σρ² (after prewhitening the input, for cross-correlation)
    p_value: float = math.nan       #: χ² test of "no correlation at any of these lags"

    @property
    def white(self) -> bool:
        """No correlation detectable (portmanteau p ≥ 0.01)."""
        return not (self.p_value < 0.01)


@dataclass
class Evaluation:
    """Everything :mod:`.compare`, :mod:`analysis.diagnosis` and the plots need."""

    model: PlantModel
    window_s: float
    sims: list[RecordSimulation] = field(repr=False)
    rmse: float
    fit_percent: float
    n: int
    noise_sigma: float        #: σ̂ of the measurement noise, kgf
    noise_floor: float        #: RMSE a perfect model would show, kgf
    rmse_adjusted: float      #: RMSE with each window's start re-estimated (the fit's objective), kgf
    adjusted_floor: float     #: its noise floor ``σ·sqrt(1 − 1/W)``, kgf
    windows: list[WindowStat]
    regimes: list[RegimeStat]
    whiteness: CorrelationTest
    input_correlation: CorrelationTest

    @property
    def excess_ratio(self) -> float:
        """How far the model is from what the noise allows (1 = perfect), on the error with the
        window starts re-estimated (the measured-start ratio ``rmse/noise_floor`` scatters with
        the few noise draws at the window starts when there are few windows)."""
        return self.rmse_adjusted / self.adjusted_floor if self.adjusted_floor > 0 else math.inf

    def worst_windows(self, k: int = 3) -> list[WindowStat]:
        return sorted(self.windows, key=lambda w: -w.rmse)[:k]

    def window_sse(self) -> np.ndarray:
        """Squared error per window, all records in order."""
        return np.concatenate([np.bincount(s.win, weights=s.r ** 2) for s in self.sims])

    def summary(self) -> dict:
        return {"rmse": self.rmse, "fit_percent": self.fit_percent, "n_samples": self.n,
                "n_windows": len(self.windows), "window_s": self.window_s,
                "noise_sigma": self.noise_sigma, "noise_floor_rmse": self.noise_floor,
                "rmse_over_floor": self.rmse / self.noise_floor if self.noise_floor > 0 else math.inf,
                "excess_ratio": self.excess_ratio, "rmse_start_adjusted": self.rmse_adjusted,
                "start_adjusted_floor": self.adjusted_floor}

    def to_dict(self) -> dict:
        d = self.summary()
        d["windows"] = [asdict(w) for w in self.windows]
        d["worst_windows"] = [asdict(w) for w in self.worst_windows()]
        d["regimes"] = [asdict(r) for r in self.regimes]
        d["whiteness"] = {**asdict(self.whiteness), "white": self.whiteness.white}
        d["input_correlation"] = {**asdict(self.input_correlation),
                                  "white": self.input_correlation.white}
        return d


def evaluate(model: PlantModel, records: Sequence[Record], window_s: float = WINDOW_S,
             max_lag_s: float = 0.25, sigma: float | None = None) -> Evaluation:
    """Windowed free-run error of ``model`` on ``records``, per window and regime, with the
    residual tests. See the module docstring for the definitions. ``sigma``: the noise σ if
    already known (else estimated from this model's residual, or the force itself)."""
    sims = simulate_records(model, records, window_s)
    y = np.concatenate([s.y for s in sims])
    r = np.concatenate([s.r for s in sims])
    n = len(r)
    rmse = float(math.sqrt(np.mean(r ** 2)))
    fit = _fit_percent(y, r)
    if sigma is None:
        sigma = residual_noise_sigma(sims)
        if not math.isfinite(sigma):
            sigma = pooled_noise_sigma(records)
    floor = noise_floor(sims, sigma)
    windows = window_stats(sims)
    radj = np.concatenate(demeaned_residual(sims))
    rmse_adj = float(math.sqrt(np.mean(radj ** 2)))
    adj_floor = floor / math.sqrt(2.0)
    regimes = regime_stats(sims, model.tau)
    dt = min(s.record.dt for s in sims)
    L = int(max(10, min(250, round(max_lag_s / dt))))
    white = whiteness_test(sims, L)
    cross = input_correlation_test(sims, L)
    return Evaluation(model, window_s, sims, rmse, fit, n, sigma, floor, rmse_adj, adj_floor,
                      windows, regimes, white, cross)


def _fit_percent(y: np.ndarray, r: np.ndarray) -> float:
    den = float(np.linalg.norm(y - y.mean()))
    return 100.0 * (1.0 - float(np.linalg.norm(r)) / den) if den > 0 else math.nan


def noise_floor(sims: Sequence[RecordSimulation], sigma: float) -> float:
    """RMSE of a perfect model on these windows: every sample but a window's first carries its
    own noise and the window start's, ``sqrt(2σ²·(1 − 1/W))`` averaged over the windows."""
    if not math.isfinite(sigma):
        return math.nan
    n = sum(len(s.y) for s in sims)
    starts = sum(int(s.win[-1]) + 1 for s in sims if len(s.win))
    return sigma * math.sqrt(2.0 * (n - starts) / n) if n else math.nan


# ------------------------------------------------------------------------------------------
# regimes
# ------------------------------------------------------------------------------------------
def reversal_mask(q: np.ndarray, dt: float, after_s: float = AFTER_REVERSAL_S) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the rod's reversals (sign changes of the delayed command, ignoring zeros) and
    the mask of samples within ``after_s`` after one."""
    sgn = np.sign(q)
    idx = np.flatnonzero(sgn)
    if len(idx) < 2:
        return np.array([], int), np.zeros(len(q), bool)
    s = sgn[idx]
    rev = idx[1:][s[1:] != s[:-1]]
    mask = np.zeros(len(q), bool)
    n_after = max(1, int(round(after_s / dt)))
    marks = np.zeros(len(q) + 1, int)
    np.add.at(marks, rev, 1)
    np.add.at(marks, np.minimum(rev + n_after, len(q)), -1)
    mask = np.cumsum(marks[:-1]) > 0
    return rev, mask


def command_levels(u_abs: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Group |u| into its distinct levels (≤ 6, e.g. a meander's amplitudes) or quartiles.
    Returns the group index per sample (−1 for u = 0) and the labels."""
    nz = u_abs > 0
    group = np.full(len(u_abs), -1)
    if not nz.any():
        return group, []
    levels = np.unique(np.round(u_abs[nz], 2))
    if len(levels) <= 6:
        group[nz] = np.searchsorted(levels, np.round(u_abs[nz], 2))
        return group, [f"|u| = {v:g} %" for v in levels]
    edges = np.unique(np.quantile(u_abs[nz], [0, 0.25, 0.5, 0.75, 1.0]))
    group[nz] = np.clip(np.searchsorted(edges, u_abs[nz], side="right") - 1, 0, len(edges) - 2)
    return group, [f"|u| in [{_level(a)}, {_level(b)}] %" for a, b in zip(edges[:-1], edges[1:])]


def _level(v: float) -> str:
    """A command level for a label: 3 digits, and 0 for the smallest |u| of a continuous
    command (not 7.11e-05)."""
    return "0" if abs(v) < 0.005 else f"{v:.3g}"


def force_levels(y: np.ndarray) -> tuple[np.ndarray, list[str]]:
    edges = np.unique(np.quantile(y, [0, 0.25, 0.5, 0.75, 1.0]))
    if len(edges) < 2:
        return np.zeros(len(y), int), [f"y = {y[0]:.0f} kgf"]
    group = np.clip(np.searchsorted(edges, y, side="right") - 1, 0, len(edges) - 2)
    return group, [f"y in [{a:.0f}, {b:.0f}] kgf" for a, b in zip(edges[:-1], edges[1:])]


def regime_labels(sims: Sequence[RecordSimulation], tau: float) -> dict[str, tuple[np.ndarray, list[str]]]:
    """For each regime group: an integer label per evaluated sample (all records concatenated,
    −1 = not in the group) and the names."""
    after, direction = [], []
    for s in sims:
        _, m = reversal_mask(s.q, s.record.dt)
        after.append(np.where(np.sign(s.q) == 0, -1, np.where(m, 0, 1)))
        direction.append(np.where(s.q > 0, 0, np.where(s.q < 0, 1, 2)))
    y = np.concatenate([s.y for s in sims])
    q = np.concatenate([s.q for s in sims])
    lv, lv_names = command_levels(np.abs(q))
    fl, fl_names = force_levels(y)
    return {
        "reversal": (np.concatenate(after), [f"first {AFTER_REVERSAL_S:g} s after a reversal", "steady ramp"]),
        "direction": (np.concatenate(direction), ["extend (u > 0)", "retract (u < 0)", "hold (u = 0)"]),
        "command level": (lv, lv_names),
        "force level": (fl, fl_names),
    }


def window_increments(sims: Sequence[RecordSimulation]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residual and model increments per sample (0 at window starts) and the sample time."""
    dr, dyh, dts = [], [], []
    for s in sims:
        a = np.diff(s.r, prepend=0.0)
        b = np.diff(s.yhat, prepend=s.yhat[0])
        first = s.horizon == 0
        a[first] = 0.0
        b[first] = 0.0
        dr.append(a)
        dyh.append(b)
        dts.append(np.full(len(a), s.record.dt))
    return np.concatenate(dr), np.concatenate(dyh), np.concatenate(dts)


def regime_stats(sims: Sequence[RecordSimulation], tau: float) -> list[RegimeStat]:
    r = np.concatenate([s.r for s in sims])
    dr, dyh, dts = window_increments(sims)
    sgn = np.sign(np.concatenate([s.q for s in sims]))
    total = float(np.sum(r ** 2)) or 1.0
    out = []
    for group, (lab, names) in regime_labels(sims, tau).items():
        for i, name in enumerate(names):
            sel = lab == i
            k = int(sel.sum())
            if k == 0:
                continue
            bias = float(np.sum(dr[sel]) / np.sum(dts[sel]))
            # relative, along the motion: + means the model moves too fast where it moves
            along = float(np.sum(dr[sel] * sgn[sel]))
            speed = float(np.sum(np.abs(dyh[sel])))
            rel = along / speed if speed > 1e-9 else math.nan
            out.append(RegimeStat(group, name, k, k / len(r), float(math.sqrt(np.mean(r[sel] ** 2))),
                                  float(np.sum(r[sel] ** 2)) / total, bias, rel))
    return out


def window_stats(sims: Sequence[RecordSimulation]) -> list[WindowStat]:
    """RMSE and fit % per window; each window labelled by where its error grows: ``after
    reversal`` if the residual's increments concentrate in the post-reversal samples (more than
    twice their share of the window's time), else ``ramp``."""
    out = []
    for i, s in enumerate(sims):
        wi = s.win
        nw = int(wi[-1]) + 1 if len(wi) else 0
        cnt = np.bincount(wi, minlength=nw).astype(float)
        sse = np.bincount(wi, weights=s.r ** 2, minlength=nw)
        ym = np.bincount(wi, weights=s.y, minlength=nw) / cnt
        ss = np.bincount(wi, weights=(s.y - ym[wi]) ** 2, minlength=nw)
        t0 = s.t[np.minimum(np.arange(nw) * s.window, len(s.t) - 1)]
        t1 = s.t[np.minimum((np.arange(nw) + 1) * s.window, len(s.t)) - 1]
        _, m = reversal_mask(s.q, s.record.dt)
        d = np.abs(np.diff(s.r, prepend=0.0))
        d[s.horizon == 0] = 0.0
        a = np.bincount(wi, weights=d * m, minlength=nw)
        b = np.bincount(wi, weights=d * ~m, minlength=nw)
        share = np.bincount(wi, weights=m.astype(float), minlength=nw) / cnt
        for w in range(nw):
            fit = 100.0 * (1 - math.sqrt(sse[w] / ss[w])) if ss[w] > 0 else math.nan
            if a[w] + b[w] == 0:
                label = "-"
            elif share[w] > 0 and a[w] / (a[w] + b[w]) > 2 * share[w]:
                label = "after reversal"
            else:
                label = "ramp"
            out.append(WindowStat(s.index, float(t0[w]), float(t1[w]), float(math.sqrt(sse[w] / cnt[w])),
                                  float(fit), label))
    return out


# ------------------------------------------------------------------------------------------
# residual tests
# ------------------------------------------------------------------------------------------
def demeaned_residual(sims: Sequence[RecordSimulation]) -> list[np.ndarray]:
    """Each record's residual with every window's mean removed (removes the start error e_0)."""
    out = []
    for s in sims:
        wi = s.win
        mean = np.bincount(wi, weights=s.r) / np.bincount(wi)
        out.append(s.r - mean[wi])
    return out


def _xcorr(a_list: Sequence[np.ndarray], b_list: Sequence[np.ndarray], L: int) -> tuple[np.ndarray, int]:
    """Normalized cross-correlation ``ρ_ab(l) = Σ a[k+l]·b[k] / √(Σa²·Σb²)`` for l = −L..L,
    pooled over records (FFT)."""
    num = np.zeros(2 * L + 1)
    saa = sbb = 0.0
    n = 0
    for a, b in zip(a_list, b_list):
        a = a - a.mean()
        b = b - b.mean()
        m = len(a)
        if m < 2:
            continue
        nfft = 1 << int(math.ceil(math.log2(2 * m)))
        fa, fb = np.fft.rfft(a, nfft), np.fft.rfft(b, nfft)
        c = np.fft.irfft(fa * np.conj(fb), nfft)
        for i, l in enumerate(range(-L, L + 1)):
            if abs(l) < m:
                num[i] += c[l % nfft]
        saa += float(a @ a)
        sbb += float(b @ b)
        n += m
    den = math.sqrt(saa * sbb) or 1.0
    return num / den, n


#: the residual tests use at most this many samples (spread over the data set, whole windows)
MAX_TEST_SAMPLES = 400_000


def _test_sample(sims: Sequence[RecordSimulation]) -> list[RecordSimulation]:
    """Whole records while they fit in :data:`MAX_TEST_SAMPLES`, else evenly spaced stretches of
    50 windows from each (N in the bands is then the number of samples used)."""
    total = sum(len(s.y) for s in sims)
    if total <= MAX_TEST_SAMPLES:
        return list(sims)
    out = []
    for s in sims:
        share = int(MAX_TEST_SAMPLES * len(s.y) / total)
        span = 50 * s.window
        k = max(1, share // span)
        for a in np.linspace(0, max(0, len(s.y) - span), k).astype(int):
            a -= a % s.window
            b = min(len(s.y), a + span)
            out.append(RecordSimulation(s.record, s.start + a, s.window, s.y[a:b], s.yhat[a:b],
                                        s.u[a:b], s.q[a:b], s.t[a:b], s.index))
    return out


def whiteness_test(sims: Sequence[RecordSimulation], max_lag: int) -> CorrelationTest:
    """Autocorrelation of the window-demeaned residual at lags 1..L; Ljung–Box Q over them."""
    sims = _test_sample(sims)
    e = demeaned_residual(sims)
    rho, n = _xcorr(e, e, max_lag)
    lags = list(range(1, max_lag + 1))
    vals = rho[max_lag + 1:]
    k = np.arange(1, max_lag + 1)
    q = float(n * (n + 2) * np.sum(vals ** 2 / np.maximum(n - k, 1)))
    return _test(lags, vals, n, q, max_lag)


def is_closed_loop(sims: Sequence[RecordSimulation]) -> bool:
    """Feedback data: the command was computed from the measured force (relay, P-feedback: the
    record names the experiment or carries a reference r)."""
    return any(s.record.experiment in ("relay", "pfeedback") or s.record.has_reference() for s in sims)


def input_correlation_test(sims: Sequence[RecordSimulation], max_lag: int) -> CorrelationTest:
    """ρ between the residual at k + l and the command at k, l = −L..L (l > 0: residual after
    the command). The values are the plain correlations; the Q test uses both signals
    prewhitened by their own AR(10) filters, as the lags of a smooth input (or of a coloured
    residual) are strongly dependent.
    In closed loop the command reacts to the measured noise, so only l ≥ 1 (the residual after
    the command) enter the test."""
    closed = is_closed_loop(sims)
    sims = _test_sample(sims)
    e = demeaned_residual(sims)
    u = [s.u.astype(float) for s in sims]
    rho, n = _xcorr(e, u, max_lag)
    # each side whitened by its own AR(10) filter: then, under "no relation", the correlations
    # at different lags are independent and N·Σρ² is χ² (a coloured residual would otherwise
    # make neighbouring lags move together and the test fire too often)
    a_u, a_e = _ar_fit(u, 10), _ar_fit(e, 10)
    uw = [_ar_filter(x, a_u) for x in u]
    ew = [_ar_filter(x, a_e) for x in e]
    rw, nw = _xcorr(ew, uw, max_lag)
    if closed:
        rw = rw[max_lag + 1:]
    q = float(nw * np.sum(rw ** 2))
    return _test(list(range(-max_lag, max_lag + 1)), rho, n, q, len(rw))


def _ar_fit(xs: Sequence[np.ndarray], order: int) -> np.ndarray:
    """AR coefficients ``x_k ≈ Σ a_i x_{k−i}`` by least squares (at most 200 000 samples)."""
    rows, rhs = [], []
    budget = 200_000
    for x in xs:
        x = (x - x.mean())[:budget]
        budget -= len(x)
        if len(x) <= order + 1:
            continue
        rows.append(np.column_stack([x[order - i - 1:len(x) - i - 1] for i in range(order)]))
        rhs.append(x[order:])
        if budget <= 0:
            break
    if not rows:
        return np.zeros(order)
    A, b = np.vstack(rows), np.concatenate(rhs)
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    return np.nan_to_num(coef)


def _ar_filter(x: np.ndarray, a: np.ndarray) -> np.ndarray:
    from scipy.signal import lfilter
    return lfilter(np.concatenate([[1.0], -a]), [1.0], x - x.mean())


def _test(lags: list[int], vals: np.ndarray, n: int, q: float, dof: int) -> CorrelationTest:
    from scipy import stats
    band = 1.96 / math.sqrt(max(n, 1))
    vals = np.nan_to_num(np.asarray(vals, float))
    outside = float(np.mean(np.abs(vals) > band)) if len(vals) else 0.0
    p = float(stats.chi2.sf(q, dof)) if math.isfinite(q) else math.nan
    return CorrelationTest(lags, [float(v) for v in vals], band, n, outside,
                           float(np.max(np.abs(vals))) if len(vals) else 0.0, q, p)
