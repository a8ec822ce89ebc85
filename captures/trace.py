"""The dynamometer's answers to the SYNCs of one captured run (:func:`force_trace`), for
``stand replay --as-plant`` (:class:`plant_emulator.replayed.ReplayedStand` plays them back)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from plant_emulator.replayed import ForceTrace

from .decode import decode_capture
from .frames import CaptureError


def force_trace(path: str | Path, run: int | None = None, **options) -> ForceTrace:
    """Extract the per-SYNC force sequence of one run of a capture."""
    result = decode_capture(path, trace=True, collect=False, run=run, **options)
    runs = [r for r in result.runs if r.syncs and r.index in result.traces]
    if not runs:
        raise CaptureError(f"{path}: no SYNC answered by the dynamometer in this capture"
                           + (f" (run {run})" if run is not None else ""))
    if run is None and len(runs) > 1:
        raise CaptureError(f"{path} holds {len(runs)} runs; choose one with --run N "
                           f"({', '.join(str(r.index) for r in runs)})")
    info = runs[0]
    tr = result.traces[info.index]
    return ForceTrace(tr["y_counts"].astype(np.int32), tr["force_status"].astype(np.uint8),
                      result.force_scale, float(info.period_s), str(path), info.index)
