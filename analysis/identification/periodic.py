"""The dominant periodic part of a residual: its frequency and amplitude.

The diagnosis describes with it what no effect removes ("periodic at 3.01 Hz"); the fit starts
a parameter in Hz there when an effect's start grid asks (a plug-in's disturbance, say:
:func:`plant.start_grids.generic_starts`). The residual is taken with each window's mean
removed (the start error of a free-run window); its Welch spectrum's peak above the window
rate is refined by fitting ``a·sin 2πft + b·cos 2πft`` (window means removed alike) on a fine
grid of frequencies, each record with its own amplitude and phase (a disturbance is not
synchronous with the starts of separate runs).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from plant import PlantModel

from .windows import Piece, demean_windows, simulate_pieces


@dataclass(frozen=True)
class Segment:
    """One record's (or stretch's) residual with its window means removed."""

    t: np.ndarray             #: time of each sample, s
    x: np.ndarray             #: the residual, kgf
    win: np.ndarray           #: window number of each sample
    dt: float
    window: int               #: samples per window


@dataclass(frozen=True)
class Periodic:
    """A sinusoid in a residual: ``frequency_hz`` None when there is none to find."""

    frequency_hz: float | None
    amplitude_kgf: float | None
    explained: float          #: squared error the sinusoid explains on the samples fitted, kgf²
    total: float              #: squared error of those samples, kgf²
    n: int                    #: how many samples were fitted
    #: the spectrum's peak over its median within ±:data:`LOCAL_BINS` bins: how far the line
    #: stands out of the residual's background (a few for noise, tens or more for a line)
    prominence: float = 0.0

    def share(self, floor: float) -> float:
        """The share of the error above the noise ``floor`` (kgf RMS) it explains."""
        excess = self.total - floor ** 2 * self.n
        return min(1.0, self.explained / excess) if excess > 0 else 0.0


NONE = Periodic(None, None, 0.0, 0.0, 0)
#: the surroundings of a spectral bin, ± bins (±2.5 Hz at the 0.125 Hz of 8 s segments)
LOCAL_BINS = 20


def _local_median(psd: np.ndarray) -> np.ndarray:
    """Each bin's background: the median of the spectrum within ±:data:`LOCAL_BINS` bins."""
    from scipy.ndimage import median_filter
    return np.maximum(median_filter(psd, size=2 * LOCAL_BINS + 1, mode="nearest"), 1e-300)


def dominant_periodic(segments: Sequence[Segment], max_samples: int = 400_000,
                      whiten: bool = False) -> Periodic:
    """The sinusoid that explains most of the residual (see the module docstring); the fit
    uses at most ``max_samples`` samples. ``whiten``: pick the spectrum's peak that stands out
    most of its surroundings rather than the largest (for a coloured background)."""
    from scipy.signal import welch
    if not segments:
        return NONE
    dt = segments[0].dt
    psd_sum, freqs = None, None
    seg = 1 << int(math.ceil(math.log2(max(16, round(8.0 / dt)))))
    for s in segments:
        if s.dt != dt or len(s.x) < 16:
            continue
        fr, p = welch(s.x, fs=1 / dt, nperseg=min(seg, len(s.x)), detrend=False)
        if freqs is None:
            freqs, psd_sum = fr, np.zeros_like(p)
        if len(fr) == len(freqs):
            psd_sum += p
    if freqs is None:
        return NONE
    wmin = 1.0 / (segments[0].window * dt)  # below the window rate the demeaning removes power
    band = (freqs >= wmin) & (freqs < 0.45 / dt)
    if not band.any():
        return NONE
    local = _local_median(psd_sum)
    idx = np.flatnonzero(band)
    # the largest peak (the force), or the one that stands out most of its surroundings (a
    # rate, whose differenced noise rises with frequency)
    k = int(idx[np.argmax(psd_sum[band] / local[band] if whiten else psd_sum[band])])
    prominence = float(psd_sum[k] / local[k])
    df = freqs[1] - freqs[0]
    grid = np.linspace(max(wmin, freqs[k] - 1.5 * df), freqs[k] + 1.5 * df, 61)
    parts = []
    budget = max_samples
    for s in segments:
        m = min(len(s.x), budget)
        if m <= 0:
            break
        wl = s.win[:m]
        parts.append((s.t[:m], s.x[:m], wl, np.bincount(wl)))
        budget -= m

    best = (0.0, None, None)
    for f in grid:
        expl = weight = amp2 = 0.0
        for t, x, wl, cnt in parts:
            S = np.sin(2 * np.pi * f * t)
            C = np.cos(2 * np.pi * f * t)
            S -= (np.bincount(wl, weights=S) / cnt)[wl]
            C -= (np.bincount(wl, weights=C) / cnt)[wl]
            A = np.column_stack([S, C])
            coef, *_ = np.linalg.lstsq(A, x, rcond=None)
            expl += float(np.sum((A @ coef) ** 2))
            amp2 += float(coef @ coef) * len(x)
            weight += len(x)
        if expl > best[0]:
            best = (expl, float(f), math.sqrt(amp2 / weight))
    expl, f, amp = best
    x = np.concatenate([p[1] for p in parts])
    return Periodic(f, amp, expl, float(x @ x), len(x), prominence)


#: what the residual is read as, by where the effect to find acts: the force itself (a
#: disturbance, a force term, a sensor), its rate (a valve's offset of the flow command), or its
#: rate over the flow g·q (a FLOW effect's change of the gain, which the command's reversals
#: would otherwise modulate into sidebands: a 3 Hz ripple of the gain under a 0.25 Hz meander
#: shows in the force at 2.75 and 3.25 Hz, not at 3)
CARRIERS = ("force", "rate", "flow")
#: the flow must be at least this share of its median |q| for its samples to count ("flow")
FLOW_SHARE = 0.3


def residual_periodic(model: PlantModel, pieces: Sequence[Piece], carrier: str = "force") -> Periodic:
    """The dominant sinusoid in what ``model`` leaves of the pieces (windowed free run), read
    as ``carrier`` (:data:`CARRIERS`)."""
    if carrier not in CARRIERS:
        raise ValueError(f"carrier {carrier!r}: one of {CARRIERS}")
    segments = []
    m = int(round(model.tau / pieces[0].dt)) if pieces else 0
    for p, yhat in zip(pieces, simulate_pieces(model, pieces)):
        r = yhat - p.y[p.warmup:]
        win = p.window_index()
        if carrier != "force":
            rate = np.zeros_like(r)
            rate[1:] = np.diff(r) / p.dt
            rate[np.r_[True, win[1:] != win[:-1]]] = 0.0    # no rate across a window's start
            r = rate
            if carrier == "flow":
                q = np.r_[np.full(m, p.u[0]), p.u][:len(p.u)][p.warmup:]
                big = np.abs(q) >= FLOW_SHARE * max(float(np.median(np.abs(q))), 1e-9)
                r = np.where(big, r / (model.g * np.where(big, q, 1.0)), 0.0)
        x = demean_windows(r, p.window)
        t = p.t0 + (p.warmup + np.arange(p.n_eval)) * p.dt
        segments.append(Segment(t, x, win, p.dt, p.window))
    return dominant_periodic(segments, whiten=carrier != "force")
