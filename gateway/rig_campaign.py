r"""The identification experiments of a rig, run through the rig gateway (``stand campaign --rig``).

Two plans (docs/rig.md, "Identifying G"):

* **per column**: one run per channel, that channel a meander (``±u0``, period ``P``), every
  other valve at a zero command; run ``k`` is column ``k`` of G;
* **simultaneous**: one run, every channel a meander of its own period (periods that tell the
  channels apart: :func:`analysis.rig.periods.separating_periods`, chosen by the caller), as
  many whole periods as fit in the duration (:class:`~gateway.experiments.each_channel.EachChannel`).

The runs are written as ``OUT/NN-LABEL`` (rig runs: every channel, a capture per bus) beside
``OUT/rig-campaign.json`` (the plan, each run's outcome, stand and wall time), so ``stand
estimate OUT --save rig.toml`` reads the directory as it is.

**Before anything moves**, when the rig file gives the structure G, each channel's planned
swing is checked: a meander that starts a quarter period in swings each force by at most

.. math::  s_i = \sum_j |G_{ij}|\,u_{0,j}\,P_j/4

about where it started (per column only the moving channel's term). Over
:data:`SWING_SHARE` of the channel's force limit (room for where the force starts and its
trend) the plan is refused with the amplitude that would fit. Each meander still stops itself
at 90 % of its channel's limit (the experiment's guard).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from .errors import ParameterError
from .experiments import Meander
from .experiments.each_channel import EachChannel
from .recorder import write_json
from .session import Gateway

FORMAT = "hydrostand-rig-campaign/1"
CAMPAIGN_FILE = "rig-campaign.json"
#: the share of a channel's force limit a planned meander may swing its force (module docstring)
SWING_SHARE = 0.6


@dataclass
class RigCampaignPlan:
    """Which experiment and its meanders: ``periods_s`` one per channel (simultaneous) or one
    for all (per column)."""

    simultaneous: bool
    amplitude_pct: float = 5.0
    periods_s: list[float] = field(default_factory=lambda: [8.0])
    #: per column: periods per run; simultaneous: the run's length (each channel as many whole
    #: periods as fit, at least 2)
    cycles: int = 4
    duration_s: float = 120.0

    def meanders(self, names: Sequence[str]) -> list[tuple[str, list[str] | None, object]]:
        """(label, driven channels or None for a rig experiment, experiment) per run."""
        if self.simultaneous:
            if len(self.periods_s) != len(names):
                raise ParameterError(f"{len(self.periods_s)} periods for {len(names)} channels")
            exps = [Meander(self.amplitude_pct, p, max(2, int(self.duration_s // p)))
                    for p in self.periods_s]
            return [("simultaneous", None, EachChannel(names, exps))]
        return [(f"column-{n}", [n], Meander(self.amplitude_pct, self.periods_s[0], self.cycles))
                for n in names]

    def swings_kgf(self, G: np.ndarray) -> np.ndarray:
        """Each channel's largest planned swing (kgf) over the runs (module docstring)."""
        n = G.shape[0]
        reach = np.abs(G) * self.amplitude_pct
        if self.simultaneous:
            return reach @ (np.asarray(self.periods_s, float) / 4)
        return np.max(reach * (self.periods_s[0] / 4), axis=1) if n else np.zeros(0)

    def check(self, rig) -> None:
        """Refuse, before anything moves, a plan whose swing the rig's G says is too large."""
        if not (0 < self.amplitude_pct <= 100):
            raise ParameterError(f"--amplitude-pct {self.amplitude_pct:g}: it must be from 0 to 100 %")
        if rig.G is None:
            return
        swings = self.swings_kgf(np.asarray(rig.G, float))
        limits = np.array([c.limit_kgf for c in rig.channels])
        share = swings / (SWING_SHARE * limits)
        i = int(np.argmax(share))
        if share[i] > 1:
            raise ParameterError(
                f"{rig.where}: channel {rig.names[i]} would swing ±{swings[i]:.0f} kgf (Σ|G_ij|·u0·P_j/4 "
                f"with the rig file's G), over {SWING_SHARE:.0%} of its force limit "
                f"±{limits[i]:.0f} kgf; nothing was started. Lower --amplitude-pct to "
                f"{self.amplitude_pct / share[i]:.2g} or the meander period")

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class RigCampaignResult:
    out: Path
    runs: list[dict] = field(default_factory=list)
    status: str = "complete"
    stand_s: float = 0.0
    wall_s: float = 0.0


def run_rig_campaign(gw: Gateway, plan: RigCampaignPlan, out: str | Path,
                     progress: bool | None = None, truth: dict | None = None) -> RigCampaignResult:
    """Run ``plan`` on the rig behind ``gw`` (module docstring). ``truth``: an emulated rig's
    truth (``RigEmulatorProcess.truth()``), written beside each run."""
    rig = gw.rig
    if rig is None:
        raise ParameterError("a rig campaign needs a rig (--rig RIG.toml)")
    plan.check(rig)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    result = RigCampaignResult(out)
    t0 = time.monotonic()
    for k, (label, channels, experiment) in enumerate(plan.meanders(rig.names), start=1):
        path = out / f"{k:02d}-{label}"
        res = gw.run(experiment, path, progress=progress, channels=channels)
        if truth is not None:
            write_json(path / "truth.json", truth)
        stats = res.outcome.stats
        stand_s = stats.cycles * gw.config.period_s
        result.stand_s += stand_s
        result.runs.append({"label": label, "path": path.name, "driven": channels or list(rig.names),
                            "status": res.status, "reason": res.reason,
                            "message": res.outcome.message, "stand_s": stand_s,
                            "wall_s": stats.wall_s})
        if res.status != "complete":
            result.status = "stopped"
            break
    result.wall_s = time.monotonic() - t0
    write_json(out / CAMPAIGN_FILE, {"format": FORMAT, "rig": rig.name, "plan": plan.to_dict(),
                                     "status": result.status, "runs": result.runs,
                                     "stand_s": result.stand_s, "wall_s": result.wall_s})
    return result
