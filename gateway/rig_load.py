"""Loading a rig's programme, pass by pass (``stand load --rig``): the rig's load experiment
(:mod:`gateway.rig_load_experiment`) run ``repeat`` times on every channel at once, each
channel's peak/valley compensation learning between passes.

Each pass is one rig run (``pass-1``, ``pass-2``, ...: every channel's columns, a capture per
bus); after it the tracking report is made from every channel's recorded force
(``load_run(path, channel=NAME)``) and each channel's compensation learns from its own peaks and
valleys. ``out`` also holds the controller used, the corrections (``compensation.toml``, a table
per channel), the report (``report.json``: schema ``hydrostand-load/1`` with ``channels`` and
``ratio_error_pct``; ``report.txt``) and the last pass's figure (``tracking.png``: a row per
channel).

Every channel's supervisor keeps its own tracking-error limit for these passes, unless one is
given: :data:`ERROR_LIMIT_SHARE` of that channel's programme range (at least 100 kgf), so a
pass that cannot track stops safely (and, with the rig's safety, every channel with it) and says
why. Everything that can be checked is checked before anything moves
(:meth:`RigLoadProgramme.check`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from core.errors import ParameterError
from loading.rig_compensation import RigCompensation
from loading.rig_design import RigControllerDesign
from loading.rig_programme import RigProgramme
from loading.rig_report import RigTrackingReport, plot_rig_tracking, rig_load_summary, rig_tracking_report

from .load import ERROR_LIMIT_SHARE
from .rig_load_experiment import RigLoadProgramme
from .runs import load_run


@dataclass
class RigLoadResult:
    out: Path
    passes: list[RigTrackingReport] = field(default_factory=list)
    run_dirs: list[Path] = field(default_factory=list)
    end_reason: str | None = None
    end_message: str | None = None
    compensation: RigCompensation | None = None
    #: the programme's own time (s), as the one-channel summary's ``programme_time_s``
    programme_time_s: float | None = None

    def summary(self) -> dict:
        extras = [{"programme_time_s": self.programme_time_s}] * len(self.passes)
        d = rig_load_summary(self.passes, self.end_reason or "complete", extras)
        d["runs"] = [str(p) for p in self.run_dirs]
        if self.end_message:
            d["end_message"] = self.end_message
        return d


def rig_force_limits(gw) -> list[float]:
    """Every channel's force limit, in the rig's order."""
    return [c.limit_kgf for c in gw.config.rig.channels]


def check_rig_load(gw_config, programme: RigProgramme, controller: RigControllerDesign,
                   compensation: RigCompensation | None = None, unload_kgf: float = 0.0) -> RigLoadProgramme:
    """The first pass's experiment, checked against the rig (before anything is opened)."""
    rig = gw_config.rig
    if rig is None:
        raise ParameterError("a rig's programme needs the rig (--rig RIG.toml)")
    e = RigLoadProgramme(programme, controller, compensation, unload_kgf)
    e.check(gw_config.period_s, [c.limit_kgf for c in rig.channels], gw_config.limits.command_limit_pct)
    return e


def achieved(run_dir: Path, experiment: RigLoadProgramme) -> tuple[np.ndarray, np.ndarray]:
    """Every channel's recorded force (N, K) on the programme's clock (0 at its start)."""
    run = load_run(run_dir)
    runs = [run.channel(name) for name in experiment.names]
    t = np.asarray(runs[0].t, float) - (experiment.programme_start_s or 0.0)
    return t, np.array([np.asarray(r.y, float) for r in runs])


def run_rig_load(gw, programme: RigProgramme, controller: RigControllerDesign, out: str | Path,
                 repeat: int = 1, compensation: RigCompensation | None = None, learn: bool = True,
                 unload_kgf: float = 0.0, progress: bool | None = None,
                 error_limit_kgf: float | None = None) -> RigLoadResult:
    """Run ``repeat`` passes of ``programme`` on the rig behind ``gw`` (module docstring).
    ``error_limit_kgf``: every channel's tracking-error limit for these passes (default: each
    supervisor's own, else :data:`ERROR_LIMIT_SHARE` of the channel's programme range)."""
    if not (1 <= repeat <= 1000):
        raise ParameterError(f"repeat = {repeat}: it must be from 1 to 1000")
    out = Path(out)
    comp = compensation if compensation is not None else (
        RigCompensation(programme.names) if learn and repeat > 1 else None)
    first = check_rig_load(gw.config, programme, controller, comp, unload_kgf)
    supervisors = [ch.supervisor for ch in gw.loop.channels]
    own = [s.limits for s in supervisors]
    for s, lim, rng in zip(supervisors, own, programme.ranges_kgf):
        limit = error_limit_kgf if error_limit_kgf is not None else lim.error_limit_kgf
        if limit is None:
            limit = max(ERROR_LIMIT_SHARE * rng, 100.0)
        s.limits = replace(lim, error_limit_kgf=limit)
    out.mkdir(parents=True, exist_ok=True)
    (out / "controller.toml").write_text(controller.to_toml(out / "controller.toml"))
    result = RigLoadResult(out, compensation=comp, programme_time_s=programme.duration_s)
    last = None
    try:
        for i in range(1, repeat + 1):
            experiment = first if i == 1 else check_rig_load(gw.config, programme, controller, comp, unload_kgf)
            res = gw.run(experiment, out / f"pass-{i}", progress=progress)
            result.run_dirs.append(res.path)
            if res.status != "complete" or experiment.main_start_s is None:
                result.end_reason = res.reason or res.status
                result.end_message = res.outcome.message if res.outcome else None
                break
            t, Y = achieved(res.path, experiment)
            report = rig_tracking_report(programme, t, Y)
            result.passes.append(report)
            (res.path / "tracking.json").write_text(json.dumps(report.to_dict(), indent=1) + "\n")
            if comp is not None and learn:
                comp.learn(report.channels, programme.ranges_kgf)
                comp.save(out / "compensation.toml")
            last = (t, Y)
    finally:
        for s, lim in zip(supervisors, own):
            s.limits = lim
    _write_reports(result, programme, last)
    return result


def _write_reports(result: RigLoadResult, programme: RigProgramme, last) -> None:
    out = result.out
    if last is not None:
        lines = [f"pass {i}:\n{p.text()}" for i, p in enumerate(result.passes, start=1)]
        (out / "report.txt").write_text("\n\n".join(lines) + "\n")
        plot_rig_tracking(programme, *last, result.passes[-1], out / "tracking.png",
                          title=f"{programme.source}: pass {len(result.passes)}")
    (out / "report.json").write_text(json.dumps(result.summary(), indent=2) + "\n")
