"""Is each command step reaching the valve at a slightly different time (timing jitter)?

A model with a fixed delay τ puts every command step's response at the same lag. If the
controller's cycle, the bus or the drive pass steps on with a jitter, the measured force after
each step is ahead or behind the model by ``g·Δu·ε`` (ε the step's timing error), at random and
either way, and stays so until the window ends: the residual *jumps* at the steps. No
deterministic effect removes that, so the diagnosis reports it in words, with the jitter's size.

It is told apart from look-alikes by three checks:

* the jumps are compared with the residual's jumps over the same spans *between* steps: an
  oscillation, drift or coloured noise jumps there as much, jitter does not;
* the mean jump of the steps each way must be small beside their spread: a reversal boost, a
  direction-dependent delay or a play are systematic, jitter is not;
* enough steps (:data:`MIN_STEPS`) for a spread to mean something.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..identification.metrics import RecordSimulation

#: residual averaged over this long before and after a step, s
SPAN_S = 0.04
#: the samples right after the step are skipped (the step's own fraction of a sample, a lag), s
SKIP_S = 0.006
#: fewest clean steps (and between-step spans) to say anything
MIN_STEPS = 20
MIN_QUIET = 10
#: the steps' mean square jump must exceed the quiet spans' by this factor
JUMP_RATIO = 4.0
#: a step counts if the delayed command moves by at least this share of the record's largest |u|
STEP_SHARE = 0.25


def _jump(r: np.ndarray, k: int, b: int, a: int) -> float:
    """Mean residual over ``[k + a, k + a + b)`` minus that over ``[k − b, k)``."""
    return float(r[k + a:k + a + b].mean() - r[k - b:k].mean())


def step_jumps(sims: Sequence[RecordSimulation]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residual jumps (model − measurement, kgf) across the clean command steps, the steps'
    sizes Δu (%), and jumps across spans midway between steps (no step near): the reference."""
    jumps, sizes, quiet = [], [], []
    for s in sims:
        dt = s.record.dt
        b = max(3, int(round(SPAN_S / dt)))
        a = max(1, int(round(SKIP_S / dt)))
        q = s.q
        top = float(np.abs(q).max()) if len(q) else 0.0
        if top <= 0:
            continue
        dq = np.diff(q, prepend=q[0])
        steps = np.flatnonzero(np.abs(dq) >= max(STEP_SHARE * top, 1e-9))
        r = s.r
        win = s.win
        n = len(r)
        bounds = np.concatenate([[-10 ** 9], steps, [10 ** 9]])
        for i, k in enumerate(steps):
            prev, nxt = bounds[i], bounds[i + 2]
            lo, hi = k - b, k + a + b
            if lo < 0 or hi > n or prev > lo or nxt < hi or win[lo] != win[hi - 1]:
                continue
            jumps.append(_jump(r, k, b, a))
            sizes.append(float(dq[k]))
        # the same measure halfway between consecutive steps (or in long step-free stretches)
        for k0, k1 in zip(bounds[:-1], bounds[1:]):
            k0, k1 = max(int(k0), 0), min(int(k1), n)
            m = (k0 + k1) // 2
            lo, hi = m - b, m + a + b
            if lo <= k0 + a + b or hi >= k1 - b or win[lo] != win[hi - 1]:
                continue
            quiet.append(_jump(r, m, b, a))
    return np.asarray(jumps), np.asarray(sizes), np.asarray(quiet)


def timing_jitter(sims: Sequence[RecordSimulation], g: float) -> dict | None:
    """The command steps' timing jitter the residual shows, or None: ``rms_s`` (the spread of
    the steps' timing beyond what the residual between steps explains), the mean square jumps
    at steps and between them, and the counts."""
    jumps, sizes, quiet = step_jumps(sims)
    if len(jumps) < MIN_STEPS or len(quiet) < MIN_QUIET or g <= 0:
        return None
    ms_quiet = float(np.mean(quiet ** 2))
    # per direction, the systematic part (a boost, a direction delay) comes off first
    eps = jumps / (g * sizes)                       # each step's timing error, s (+: late)
    spread = []
    for side in (sizes > 0, sizes < 0):
        if side.sum() >= 3:
            e = eps[side]
            if abs(e.mean()) > 0.5 * e.std():       # systematic, not jitter
                return None
            spread.append(jumps[side] - jumps[side].mean())
    centred = np.concatenate(spread) if spread else jumps
    ms_steps = float(np.mean(centred ** 2))
    if ms_steps < JUMP_RATIO * max(ms_quiet, 1e-12):
        return None
    excess = ms_steps - ms_quiet
    rms_s = math.sqrt(excess / np.mean((g * sizes) ** 2))
    return {"rms_s": rms_s, "steps": len(jumps), "quiet": len(quiet),
            "rms_jump_steps": math.sqrt(ms_steps), "rms_jump_quiet": math.sqrt(ms_quiet)}


def jitter_observation(sims: Sequence[RecordSimulation], g: float) -> list[str]:
    """The plain-words sentence for :func:`timing_jitter` (empty if it finds none)."""
    j = timing_jitter(sims, g)
    if j is None:
        return []
    return [f"the force after the command steps is off the model by a random amount, either way "
            f"({j['rms_jump_steps']:.3g} kgf rms over {j['steps']} steps, against "
            f"{j['rms_jump_quiet']:.3g} kgf over the same spans between steps): as if each step "
            f"reached the valve about ±{j['rms_s'] * 1e3:.2g} ms (rms) off a fixed delay; timing "
            f"jitter (the controller's cycle, the bus, the drive) rather than a plant effect, and "
            f"no model with a fixed τ removes it"]
