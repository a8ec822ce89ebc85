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

**Time scaling** of load cases (``scaling``, :mod:`loading.rig_time_scaling`): the segments
between load cases change from pass to pass, each on its own, floored at the valve-limited
minimum through the rig's model (:mod:`loading.rig_minimum_time`), until every channel holds the
accuracy at every load case as fast as it can; ``out/schedule.toml`` keeps the fastest schedule
whose pass met it (with the channels' names) and a ``schedule`` replays one. Every pass reports
the programme's time beside that minimum.

**The gain monitor** (``monitor``, :mod:`loading.rig_gain_monitor`): one for all the passes;
each pass writes its blocks (``pass-N/gain.json``), the summary has ``gain``.

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
from loading.gain_monitor import MonitorOptions
from loading.pacing import PacingOptions
from loading.rig_compensation import RigCompensation
from loading.rig_design import RigControllerDesign
from loading.rig_gain_monitor import RigGainMonitor
from loading.rig_minimum_time import programme_flow_limit, rig_minimum_durations_s
from loading.rig_programme import RigProgramme
from loading.rig_report import RigTrackingReport, plot_rig_tracking, rig_load_summary, rig_tracking_report
from loading.rig_time_scaling import rig_meets, rig_verdicts
from loading.time_scaling import ScalingOptions, Schedule, TimeScaler

from .load import (ERROR_LIMIT_SHARE, FEEDFORWARD_SHARE, keep_if_fastest, pass_stopped, save_unverified,
                   stretched_pass)
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
    #: its valve-limited minimum by the controller's model (load cases only)
    minimum_time_s: float | None = None
    #: per pass: its programme's time and, time scaling, the segments' verdicts
    timings: list[dict] = field(default_factory=list)
    #: time scaling: the fastest schedule whose pass met the accuracy (None: none did)
    schedule: Schedule | None = None
    #: time scaling: did the last pass run every segment settled and meet the accuracy
    converged: bool | None = None
    #: the gain monitor of the passes (None: not watched)
    monitor: RigGainMonitor | None = None

    def summary(self) -> dict:
        extras = [{**t, "minimum_time_s": self.minimum_time_s} for t in self.timings]
        d = rig_load_summary(self.passes, self.end_reason or "complete", extras)
        d["runs"] = [str(p) for p in self.run_dirs]
        if self.end_message:
            d["end_message"] = self.end_message
        if self.converged is not None:
            s = self.schedule
            d["schedule"] = ({"time_s": s.time_s, "minimum_time_s": s.minimum_time_s,
                              "accuracy_pct": s.accuracy_pct, "verified": s.verified}
                             if s is not None else None)
            d["converged"] = self.converged
        if self.monitor is not None:
            d["gain"] = self.monitor.summary()
        return d


def rig_force_limits(gw) -> list[float]:
    """Every channel's force limit, in the rig's order."""
    return [c.limit_kgf for c in gw.config.rig.channels]


def check_rig_load(gw_config, programme: RigProgramme, controller: RigControllerDesign,
                   compensation: RigCompensation | None = None, unload_kgf: float = 0.0,
                   monitor: RigGainMonitor | None = None, pacing: PacingOptions | None = None) -> RigLoadProgramme:
    """The first pass's experiment, checked against the rig (before anything is opened)."""
    rig = gw_config.rig
    if rig is None:
        raise ParameterError("a rig's programme needs the rig (--rig RIG.toml)")
    e = RigLoadProgramme(programme, controller, compensation, unload_kgf, monitor=monitor, pacing=pacing)
    e.check(gw_config.period_s, [c.limit_kgf for c in rig.channels], gw_config.limits.command_limit_pct)
    return e


def achieved(run_dir: Path, experiment: RigLoadProgramme) -> tuple[np.ndarray, np.ndarray]:
    """Every channel's recorded force (N, K) on the programme's clock (0 at its start)."""
    run = load_run(run_dir)
    runs = [run.channel(name) for name in experiment.names]
    return experiment.programme_times(runs[0].t), np.array([np.asarray(r.y, float) for r in runs])


def run_rig_load(gw, programme: RigProgramme, controller: RigControllerDesign, out: str | Path,
                 repeat: int = 1, compensation: RigCompensation | None = None, learn: bool = True,
                 unload_kgf: float = 0.0, progress: bool | None = None,
                 error_limit_kgf: float | None = None, scaling: ScalingOptions | None = None,
                 schedule: Schedule | None = None, monitor: MonitorOptions | None = None,
                 pacing: PacingOptions | None = None) -> RigLoadResult:
    """Run ``repeat`` passes of ``programme`` on the rig behind ``gw`` (module docstring).
    ``error_limit_kgf``: every channel's tracking-error limit for these passes (default: each
    supervisor's own, else :data:`ERROR_LIMIT_SHARE` of the channel's programme range).
    ``schedule``: the load cases' segment durations to run (a rig's ``schedule.toml``).
    ``scaling``: time scaling of the load cases, at most ``repeat`` passes
    (:mod:`loading.rig_time_scaling`). ``monitor``: every channel's gain estimated block by
    block through G, followed by the feedforward and watched for a fall or a rise
    (:mod:`loading.rig_gain_monitor`). ``pacing``: static null pacing at the load cases
    (:mod:`loading.rig_pacing`)."""
    if not (1 <= repeat <= 1000):
        raise ParameterError(f"repeat = {repeat}: it must be from 1 to 1000")
    if schedule is not None:
        programme = schedule.apply_rig(programme)
    if scaling is not None:
        scaling.check()
        if not programme.load_cases:
            raise ParameterError(f"{programme.source}: time scaling needs load cases (a CSV with a "
                                 "column per channel): per-channel sequences have no common segments")
    out = Path(out)
    comp = compensation if compensation is not None else (
        RigCompensation(programme.names) if learn and repeat > 1 else None)
    watcher = RigGainMonitor(controller.model, gw.config.period_s, monitor) if monitor is not None else None
    first = check_rig_load(gw.config, programme, controller, comp, unload_kgf, watcher, pacing)
    minimum = rig_minimum_s(gw.config, programme, controller, required=scaling is not None)
    supervisors = [ch.supervisor for ch in gw.loop.channels]
    own = [s.limits for s in supervisors]
    for s, lim, rng in zip(supervisors, own, programme.ranges_kgf):
        limit = error_limit_kgf if error_limit_kgf is not None else lim.error_limit_kgf
        if limit is None:
            limit = max(ERROR_LIMIT_SHARE * rng, 100.0)
        s.limits = replace(lim, error_limit_kgf=limit)
    out.mkdir(parents=True, exist_ok=True)
    (out / "controller.toml").write_text(controller.to_toml(out / "controller.toml"))
    result = RigLoadResult(out, compensation=comp, programme_time_s=programme.duration_s,
                           minimum_time_s=float(minimum.sum()) if minimum is not None else None,
                           monitor=watcher)
    shared = _Passes(gw, controller, unload_kgf, learn, progress, result, pacing)
    try:
        if scaling is not None:
            last = _scaled_passes(shared, programme, minimum, repeat, scaling)
        else:
            last = None
            for i in range(1, repeat + 1):
                experiment = first if i == 1 else check_rig_load(gw.config, programme, controller, comp,
                                                                 unload_kgf, watcher, pacing)
                done = shared.run(experiment, programme, i)
                if done is None:
                    break
                last = (programme, done)
    finally:
        for s, lim in zip(supervisors, own):
            s.limits = lim
    _write_reports(result, *(last or (programme, None)))
    return result


def rig_minimum_s(gw_config, programme: RigProgramme, controller: RigControllerDesign,
                  required: bool = False) -> np.ndarray | None:
    """Each load-case segment's valve-limited minimum by the controller's rig model
    (:mod:`loading.rig_minimum_time`); None for per-channel sequences, or when the model says a
    valve cannot hold and ``required`` is false (only time scaling needs it)."""
    if not programme.load_cases:
        return None
    limit = min(controller.command_limit_pct, gw_config.limits.command_limit_pct)
    try:
        return rig_minimum_durations_s(programme, controller.model,
                                       programme_flow_limit(programme, controller.model, limit))[0]
    except ParameterError:
        if required:
            raise
        return None


@dataclass
class _Passes:
    """What every pass of one ``run_rig_load`` shares (the compensation and the gain monitor
    are the result's)."""

    gw: object
    controller: RigControllerDesign
    unload_kgf: float
    learn: bool
    progress: bool | None
    result: RigLoadResult
    pacing: PacingOptions | None = None

    def run(self, experiment: RigLoadProgramme, programme: RigProgramme, i: int):
        """Pass ``i``: run, report, learn. Returns the forces ``(t, Y)`` on the programme's
        clock, or None if the pass ended early (``result.end_reason`` says why)."""
        result = self.result
        res = self.gw.run(experiment, result.out / f"pass-{i}", progress=self.progress)
        result.run_dirs.append(res.path)
        monitor = result.monitor
        if monitor is not None and monitor.end_pass():
            (res.path / "gain.json").write_text(json.dumps(
                {**monitor.summary(), "blocks": monitor.blocks(monitor.pass_index)}, indent=2) + "\n")
        if pass_stopped(res, experiment, result):
            return None
        t, Y = achieved(res.path, experiment)
        report = rig_tracking_report(programme, t, Y)
        result.passes.append(report)
        timing = {"programme_time_s": programme.duration_s}
        if experiment.clock is not None:
            timing["pacing_s"] = experiment.clock.record.pacing_s
            timing["pacing"] = experiment.clock.record.to_dict()
        result.timings.append(timing)
        (res.path / "tracking.json").write_text(json.dumps(report.to_dict(), indent=1) + "\n")
        comp = result.compensation
        if comp is not None and self.learn:
            comp.learn(report.channels, programme.ranges_kgf)
            comp.save(result.out / "compensation.toml")
        return t, Y


def _scaled_passes(shared: _Passes, programme: RigProgramme, minimum: np.ndarray, repeat: int,
                   options: ScalingOptions):
    """Time scaling of the load cases, pass by pass (loading.rig_time_scaling). Returns the
    last pass's (programme, forces), or None."""
    result = shared.result
    result.converged = False
    gw, controller = shared.gw, shared.controller
    scaler = TimeScaler(programme, minimum, programme.segment_durations_s, options)
    share_limit = FEEDFORWARD_SHARE * min(controller.command_limit_pct, gw.config.limits.command_limit_pct)
    base = programme
    last = None
    for i in range(1, repeat + 1):
        current, experiment = stretched_pass(
            base, scaler, i, lambda p: RigLoadProgramme(p, controller, result.compensation, shared.unload_kgf,
                                                        monitor=result.monitor, pacing=shared.pacing),
            segment_peaks, share_limit)
        settled = scaler.all_settled
        limits = gw.config.limits
        experiment.check(gw.config.period_s, [c.limit_kgf for c in gw.config.rig.channels],
                         limits.command_limit_pct)
        done = shared.run(experiment, current, i)
        if done is None:
            break
        last = (current, done)
        report = result.passes[-1]
        ok = rig_meets(report, options.accuracy_pct)
        clock = experiment.clock
        paced = ({k - experiment.lead: v for k, v in clock.paced_by_turning.items()}
                 if clock is not None else None)
        verdicts = rig_verdicts(scaler, current, report, *done, paced)
        result.timings[-1]["scaling"] = {**scaler.last, "met_accuracy": ok, "all_settled_before": settled}
        if ok:
            keep_if_fastest(result, base, current, i, options, minimum, list(base.names))
        if ok and settled:
            result.converged = True
            break
        scaler.update(verdicts)
    if result.schedule is None:
        save_unverified(result, base, scaler, options, minimum, list(base.names))
    return last


def segment_peaks(e: RigLoadProgramme) -> np.ndarray:
    """Each load-case segment's largest feedforward command (%) over every channel and both
    ways its rod may last have moved, each channel's sent its own delay ahead."""
    programme = e.commanded
    idx0 = e.lead + programme.turning_idx
    peaks = np.zeros(len(idx0) - 1)
    for ff in e.ff.values():
        for f, m in zip(ff.channels, e.controller.model.channels):
            idx = idx0 - int(round(m.tau / programme.period_s))
            u = np.abs(f.u_pct)
            for j in range(len(peaks)):
                a, b = max(idx[j], 0), max(idx[j + 1], 1)
                peaks[j] = max(peaks[j], float(u[a:b].max()))
    return peaks


def _write_reports(result: RigLoadResult, programme: RigProgramme, last) -> None:
    out = result.out
    lines = [f"pass {i}:\n{timing_text(t, result.minimum_time_s)}\n{p.text()}"
             for i, (p, t) in enumerate(zip(result.passes, result.timings), start=1)]
    if result.end_reason not in (None, "complete"):
        lines.append(f"pass {len(result.run_dirs)} stopped ({result.end_reason}): {result.end_message}")
    if result.monitor is not None:
        lines.append(result.monitor.text())
    (out / "report.txt").write_text("\n\n".join(lines) + "\n")
    if last is not None:
        plot_rig_tracking(programme, *last, result.passes[-1], out / "tracking.png",
                          title=f"{programme.source}: pass {len(result.passes)}")
    (out / "report.json").write_text(json.dumps(result.summary(), indent=2) + "\n")


def timing_text(timing: dict, minimum_time_s: float | None) -> str:
    """One line: the programme's time, its valve-limited minimum, time scaling's verdicts."""
    text = f"programme {timing['programme_time_s']:.1f} s"
    if minimum_time_s:
        text += (f", valve-limited minimum {minimum_time_s:.1f} s "
                 f"({timing['programme_time_s'] / minimum_time_s:.2f}x)")
    if timing.get("pacing") is not None:
        text += f", pacing {timing['pacing_s']:.2f} s ({timing['pacing']['waits']} waits)"
    s = timing.get("scaling")
    if s is not None:
        text += f"; segments landed {s.get('land', 0)}, held {s.get('hold', 0)}, missed {s.get('miss', 0)}"
    return text
