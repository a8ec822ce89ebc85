"""Time scaling of a rig's load cases (``stand load --rig --fastest``): the one-channel
bisection (:mod:`loading.time_scaling`) on each segment between two load cases, the floor each
segment's valve-limited minimum through the rig's model (:mod:`loading.rig_minimum_time`).

Every channel moves on every segment (one common duration, so the load case's ratios hold at
its turning point), so a segment's verdict is the worst of its channels' at the load case it
arrives at: it lands only when every channel lands, misses when one misses (its error beyond
the miss share of the accuracy, or an extra cycle rang near it). A pass meets the accuracy when
every channel does (:func:`loading.time_scaling.meets`)."""
from __future__ import annotations

import numpy as np

from .rig_programme import RigProgramme
from .rig_report import RigTrackingReport
from .time_scaling import HOLD, LAND, MISS, TimeScaler, meets, ringing_turning_points

_WORSE = {LAND: 0, HOLD: 1, MISS: 2}


def rig_verdicts(scaler: TimeScaler, programme: RigProgramme, report: RigTrackingReport,
                 t_s: np.ndarray, y_kgf: np.ndarray, paced_s: dict[int, float] | None = None) -> list[str]:
    """Per segment between load cases: land, hold or miss, the worst of the channels' (module
    docstring), from the pass that ran ``programme`` and recorded the forces ``y_kgf`` (N, K)
    at ``t_s`` (the programme's clock); ``paced_s``: the time the programme waited heading to
    each load case (its sample): a segment it waited for misses, as for one channel."""
    per_channel = [scaler.verdicts(p, r, ringing_turning_points(p, t_s, y), paced_s)
                   for p, r, y in zip(programme.channels, report.channels, np.asarray(y_kgf, float))]
    out = [max(v, key=_WORSE.__getitem__) for v in zip(*per_channel)]
    scaler.last = {v: out.count(v) for v in (LAND, HOLD, MISS)}
    return out


def rig_meets(report: RigTrackingReport, accuracy_pct: float) -> bool:
    """Every channel's peak/valley error p95 within the accuracy, max within twice it, no extra
    cycle."""
    return all(meets(r, accuracy_pct) for r in report.channels)
