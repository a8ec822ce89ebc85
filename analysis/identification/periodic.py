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

    def share(self, floor: float) -> float:
        """The share of the error above the noise ``floor`` (kgf RMS) it explains."""
        excess = self.total - floor ** 2 * self.n
        return min(1.0, self.explained / excess) if excess > 0 else 0.0


NONE = Periodic(None, None, 0.0, 0.0, 0)


def dominant_periodic(segments: Sequence[Segment], max_samples: int = 400_000) -> Periodic:
    """The sinusoid that explains most of the residual (see the module docstring); the fit
    uses at most ``max_samples`` samples."""
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
    k = int(np.flatnonzero(band)[np.argmax(psd_sum[band])])
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
    return Periodic(f, amp, expl, float(x @ x), len(x))


def residual_periodic(model: PlantModel, pieces: Sequence[Piece]) -> Periodic:
    """The dominant sinusoid in what ``model`` leaves of the pieces (windowed free run)."""
    segments = []
    for p, yhat in zip(pieces, simulate_pieces(model, pieces)):
        x = demean_windows(yhat - p.y[p.warmup:], p.window)
        t = p.t0 + (p.warmup + np.arange(p.n_eval)) * p.dt
        segments.append(Segment(t, x, p.window_index(), p.dt, p.window))
    return dominant_periodic(segments)
