"""Is a richer model's cut of the error worth its extra parameters? The criteria a catalogue
candidate (:func:`.candidates.judge`) and a per-record gain
(:mod:`.between_records`) are judged by, on the fit's objective (windowed error, window
starts re-estimated) against the noise floor.

A richer model *helps* if it lowers the objective RMSE by at least :data:`MIN_IMPROVEMENT`,
beyond what fitting noise can do (likelihood ratio) and consistently over the windows (paired
z); it *earns its parameters* if it also removes at least :data:`MIN_EXCESS_SHARE` of the error
above the noise floor.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

#: a candidate must lower the (objective) RMSE by at least this fraction
MIN_IMPROVEMENT = 0.05
#: ... and remove at least this share of the error above the noise floor
MIN_EXCESS_SHARE = 0.65
#: ... beyond what fitting noise can do: likelihood-ratio statistic N·ΔMSE/floor² above the
#: χ²(k) quantile of this tail probability (k = the extra parameters)
LR_ALPHA = 1e-6
#: ... and consistently over windows: paired z of the per-window squared-error reduction
MIN_Z = 2.0
#: an error this far above the noise floor is unexplained (below it, within what the noise
#: floor's estimate and a little model error allow)
UNEXPLAINED_RATIO = 1.12


@dataclass
class ErrorCut:
    """How much a richer model lowers the objective error, and whether it is worth it."""

    objective_rmse: float         #: windowed RMSE, window starts re-estimated, kgf
    improvement: float            #: 1 − objective_rmse/reference's (fraction)
    excess_share: float           #: share of the reference's error above the noise floor removed
    z: float                      #: paired z over windows of the squared-error reduction
    lr: float                     #: likelihood-ratio statistic N·ΔMSE/floor² (χ²(k) under "noise only")
    helps: bool                   #: significant, consistent, at least MIN_IMPROVEMENT
    earns: bool                   #: helps and removes at least MIN_EXCESS_SHARE of the excess


def error_cut(w: np.ndarray, ref_w: np.ndarray, floor: float, n: int, k: int) -> ErrorCut:
    """Judge the window squared errors ``w`` of a model with ``k`` extra parameters against the
    reference's ``ref_w`` (the same windows, ``n`` evaluated samples) on the noise floor
    ``floor`` (objective RMSE, kgf)."""
    ref_obj = math.sqrt(ref_w.sum() / n)
    obj = math.sqrt(w.sum() / n)
    improvement = 1.0 - obj / ref_obj if ref_obj > 0 else 0.0
    excess = ref_obj ** 2 - floor ** 2
    gain = ref_obj ** 2 - obj ** 2
    share = gain / excess if excess > 0 else 0.0
    d = ref_w - w
    z = float(d.mean() / (d.std(ddof=1) / math.sqrt(len(d)))) if len(d) > 1 and d.std() > 0 else (
        math.inf if d.mean() > 0 else 0.0)
    lr = n * gain / floor ** 2 if floor > 0 else math.inf
    significant = lr >= stats.chi2.isf(LR_ALPHA, max(1, k))
    # the per-window z guards small gains against a few lucky windows; a large gain that the
    # likelihood-ratio test calls significant needs no window-by-window consistency
    consistent = z >= MIN_Z or improvement >= 0.2
    helps = bool(improvement >= MIN_IMPROVEMENT and significant and consistent)
    return ErrorCut(objective_rmse=obj, improvement=improvement, excess_share=share, z=z, lr=lr,
                    helps=helps, earns=bool(helps and share >= MIN_EXCESS_SHARE))
