"""Loading a station's programme, pass by pass (``stand load``): the load experiment
(:mod:`gateway.load_experiment`) run ``repeat`` times on every channel at once, each channel's
peak/valley compensation learning between passes.

Each pass is one run (``pass-1``, ``pass-2``, ...: a rig's has every channel's columns and a
capture per bus); after it the tracking report is made from every channel's recorded force and
each channel's compensation learns from its own peaks and valleys. ``out`` also holds the
controller used, the corrections (``compensation.toml``), the report (``report.json``: schema
``hydrostand-load/1``; ``report.txt``) and the last pass's figure (``tracking.png``).

**Time scaling** (``scaling``, :mod:`loading.time_scaling`): the segments between load cases
change from pass to pass, each on its own, floored at the valve-limited minimum through the
station's model (:mod:`loading.minimum_time`), until every channel holds the accuracy at every
load case as fast as it can; ``out/schedule.toml`` keeps the fastest schedule whose pass met it
and a ``schedule`` replays one. Every pass reports the programme's time (without the approach,
the pre-roll and the unload) beside that minimum, and the time spent pacing
(:mod:`loading.pacing`).

**The gain monitor** (``monitor``, :mod:`loading.gain_monitor`): one for all the passes; each
pass writes its blocks (``pass-N/gain.json``), the summary has ``gain``.

Every channel's supervisor keeps its own tracking-error limit for these passes, unless one is
given: :func:`~gateway.limits.programme_error_limit_kgf` of that channel's programme range, so a
pass that cannot track stops safely (on a rig every channel with it) and says why. Everything
that can be checked is checked before anything moves (:meth:`LoadProgramme.check`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from core.errors import ParameterError
from loading.compensation import UNREACHED_BELOW, Compensation
from loading.design import ControllerDesign
from loading.gain_monitor import GainMonitor, MonitorOptions
from loading.minimum_time import FEEDFORWARD_SHARE, minimum_durations_s, programme_flow_limit
from loading.pacing import PacingOptions
from loading.programme import ChannelProgramme, Programme, as_programme
from loading.report import TrackingReport, cases_table, load_summary, plot_tracking, tracking_report
from loading.time_scaling import ScalingOptions, Schedule, TimeScaler, meets, stretch_to_valve

from .limits import programme_error_limit_kgf
from .load_experiment import LoadProgramme
from .runs import load_run

#: time scaling: at most this many stretches of the segments the valve cannot follow, per pass
STRETCH_TRIES = 6
#: the corrections the fastest pass that met the accuracy ran with, beside ``schedule.toml``
SCHEDULE_COMPENSATION = "schedule-compensation.toml"


@dataclass
class PassTiming:
    """How long a pass's programme took beside its minimum, and what pacing did."""

    programme_time_s: float           #: the scheduled programme, without approach/pre-roll/unload
    minimum_time_s: float | None      #: its valve-limited minimum (None: per-channel sequences)
    pacing_s: float = 0.0             #: time on the stand beyond the programme's, pacing
    pacing: dict | None = None        #: the pacing record (waits, slowed time), None: pacing off
    scaling: dict | None = None       #: time scaling: segments landed / held / missed
    gain_blocks: list | dict | None = None   #: the gain monitor's blocks of this pass

    def figures(self) -> dict:
        m = self.minimum_time_s
        d = {"programme_time_s": self.programme_time_s, "minimum_time_s": m,
             "time_over_minimum": self.programme_time_s / m if m else None, "pacing_s": self.pacing_s}
        if self.pacing is not None:
            d["pacing"] = self.pacing
        if self.scaling is not None:
            d["scaling"] = self.scaling
        if self.gain_blocks is not None:
            d["gain_blocks"] = self.gain_blocks
        return d

    def text(self) -> str:
        """One line: the programme's time, the minimum, their ratio, pacing, time scaling."""
        text = f"programme {self.programme_time_s:.1f} s"
        if self.minimum_time_s:
            text += (f", valve-limited minimum {self.minimum_time_s:.1f} s "
                     f"({self.programme_time_s / self.minimum_time_s:.2f}x)")
        if self.pacing is not None:
            text += (f", pacing {self.pacing_s:.2f} s ({self.pacing['waits']} waits, "
                     f"{self.pacing['slowed_s']:.2f} s slowed)")
        if self.scaling is not None:
            s = self.scaling
            text += f"; segments landed {s.get('land', 0)}, held {s.get('hold', 0)}, missed {s.get('miss', 0)}"
        return text


@dataclass
class LoadResult:
    out: Path
    passes: list[TrackingReport] = field(default_factory=list)
    run_dirs: list[Path] = field(default_factory=list)
    end_reason: str | None = None
    end_message: str | None = None
    compensation: Compensation | None = None
    #: per pass begun: its programme's time, pacing and time scaling
    timings: list[PassTiming] = field(default_factory=list)
    #: time scaling: the fastest schedule whose pass met the accuracy (None: none did)
    schedule: Schedule | None = None
    #: time scaling: did the last pass run every segment settled and meet the accuracy
    converged: bool | None = None
    #: the gain monitor of the passes (None: not watched)
    monitor: GainMonitor | None = None
    #: per channel, what the first pass's feedforward inverts of its model and what it does
    #: not (left to the feedback and the learning)
    feedforward: dict | None = None
    #: per pass, what the compensation learnt from it by load case (Compensation.learned)
    learned: list = field(default_factory=list)

    def summary(self) -> dict:
        extras = [t.figures() for t in self.timings[:len(self.passes)]]
        for x, learned in zip(extras, self.learned):
            if learned is not None:
                x["learned"] = learned
        d = load_summary(self.passes, self.end_reason or "complete", extras)
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
        if self.feedforward is not None:
            d["feedforward"] = self.feedforward
        return d


def force_limits(gw_config) -> list[float]:
    """Every channel's force limit, in the station's order."""
    if gw_config.rig is None:
        return [gw_config.limits.force_limit_kgf]
    return [c.limit_kgf for c in gw_config.rig.channels]


def check_load(gw_config, programme: Programme, controller: ControllerDesign,
               compensation: Compensation | None = None, unload_kgf: float = 0.0,
               monitor: GainMonitor | None = None, pacing: PacingOptions | None = None) -> LoadProgramme:
    """The first pass's experiment, checked against the station (before anything is opened)."""
    e = LoadProgramme(programme, controller, compensation, unload_kgf, monitor=monitor, pacing=pacing)
    e.check(gw_config.period_s, force_limits(gw_config), gw_config.limits.command_limit_pct)
    return e


def achieved(run_dir: Path, experiment: LoadProgramme) -> tuple[np.ndarray, np.ndarray]:
    """Every channel's recorded force (N, K) on the programme's clock (0 at its start; with
    pacing, each sample of the main phase at the clock's position then)."""
    run = load_run(run_dir)
    runs = [run.channel(name) for name in experiment.names] if run.channels else [run]
    return experiment.programme_times(runs[0].t), np.array([np.asarray(r.y, float) for r in runs])


def minimum_s(gw_config, programme: Programme, controller: ControllerDesign,
              required: bool = False) -> np.ndarray | None:
    """Each load-case segment's valve-limited minimum by the controller's model
    (:mod:`loading.minimum_time`); None for per-channel sequences, or when the model says a
    valve cannot move or hold and ``required`` is false (only time scaling needs it)."""
    if not programme.load_cases:
        return None
    limit = min(controller.command_limit_pct, gw_config.limits.command_limit_pct)
    try:
        return minimum_durations_s(programme, controller.model,
                                   programme_flow_limit(programme, controller.model, limit))[0]
    except ParameterError:
        if required:
            raise
        return None


def run_load(gw, programme: Programme | ChannelProgramme, controller: ControllerDesign, out: str | Path,
             repeat: int = 1, compensation: Compensation | None = None, learn: bool = True,
             unload_kgf: float = 0.0, progress: bool | None = None,
             error_limit_kgf: float | None = None, scaling: ScalingOptions | None = None,
             schedule: Schedule | None = None, monitor: MonitorOptions | None = None,
             pacing: PacingOptions | None = None) -> LoadResult:
    """Run ``repeat`` passes of ``programme`` on the station behind ``gw`` (module docstring).
    ``error_limit_kgf``: every channel's tracking-error limit for these passes (default: each
    supervisor's own, else :func:`~gateway.limits.programme_error_limit_kgf` of the channel's
    programme range).
    ``schedule``: the load cases' segment durations to run (a ``schedule.toml``). ``scaling``:
    time scaling, at most ``repeat`` passes (:mod:`loading.time_scaling`). ``monitor``: every
    channel's gain estimated block by block, followed by the feedforward and watched for a fall
    or a rise (:mod:`loading.gain_monitor`). ``pacing``: null pacing (:mod:`loading.pacing`)."""
    if not (1 <= repeat <= 1000):
        raise ParameterError(f"repeat = {repeat}: it must be from 1 to 1000")
    programme = as_programme(programme)
    if schedule is not None:
        programme = schedule.apply(programme)
    if scaling is not None:
        scaling.check()
        if not programme.load_cases:
            raise ParameterError(f"{programme.source}: time scaling needs load cases (a CSV with a "
                                 "column per channel): per-channel sequences have no common segments")
    out = Path(out)
    comp = compensation if compensation is not None else (
        Compensation(programme.names) if learn and repeat > 1 else None)
    watcher = GainMonitor.for_controller(controller, gw.config.period_s, monitor) if monitor is not None else None
    first = check_load(gw.config, programme, controller, comp, unload_kgf, watcher, pacing)
    minimum = minimum_s(gw.config, programme, controller, required=scaling is not None)
    supervisors = [ch.supervisor for ch in gw.loop.channels]
    own = [s.limits for s in supervisors]
    for s, lim, rng in zip(supervisors, own, programme.ranges_kgf):
        limit = error_limit_kgf if error_limit_kgf is not None else lim.error_limit_kgf
        if limit is None:
            limit = programme_error_limit_kgf(rng)
        s.limits = replace(lim, error_limit_kgf=limit)
    out.mkdir(parents=True, exist_ok=True)
    (out / "controller.toml").write_text(controller.to_toml(out / "controller.toml"))
    result = LoadResult(out, compensation=comp, monitor=watcher, feedforward=first.feedforward_covers())
    passes = _Passes(gw, controller, unload_kgf, learn, progress, result, pacing)
    try:
        if scaling is not None:
            last = _scaled_passes(passes, programme, minimum, repeat, scaling)
        else:
            last = None
            for i in range(1, repeat + 1):
                # where a level was not reached, its segment runs longer (not under a schedule)
                current = comp.timed(programme) if comp is not None and schedule is None else programme
                experiment = first if i == 1 and current is programme else check_load(
                    gw.config, current, controller, comp, unload_kgf, watcher, pacing)
                done = passes.run(experiment, current, minimum, i)
                if done is None:
                    break
                last = (current, done)
    finally:
        for s, lim in zip(supervisors, own):
            s.limits = lim
    _write_reports(result, *(last or (programme, None)))
    return result


@dataclass
class _Passes:
    """What every pass of one ``run_load`` shares (the compensation and the gain monitor are
    the result's)."""

    gw: object
    controller: ControllerDesign
    unload_kgf: float
    learn: bool
    progress: bool | None
    result: LoadResult
    pacing: PacingOptions | None = None
    #: the corrections (a compensation file's text) the last pass began with
    ran_with: str | None = None

    def experiment(self, programme: Programme) -> LoadProgramme:
        """A pass's experiment, not yet checked (time scaling stretches it first)."""
        r = self.result
        return LoadProgramme(programme, self.controller, r.compensation, self.unload_kgf, monitor=r.monitor,
                             pacing=self.pacing)

    def run(self, experiment: LoadProgramme, programme: Programme, minimum: np.ndarray | None, i: int):
        """Pass ``i``: run, report, learn. Returns the forces ``(t, Y)`` on the programme's
        clock, or None if the pass ended early (``result.end_reason`` says why)."""
        result = self.result
        self.ran_with = result.compensation.to_toml() if result.compensation is not None else None
        res = self.gw.run(experiment, result.out / f"pass-{i}", progress=self.progress)
        result.run_dirs.append(res.path)
        monitor = result.monitor
        blocks = None
        if monitor is not None and monitor.end_pass():
            blocks = monitor.blocks(monitor.pass_index)
            (res.path / "gain.json").write_text(json.dumps({**monitor.summary(), "blocks": blocks}, indent=2) + "\n")
        clock = experiment.clock
        result.timings.append(PassTiming(programme.duration_s, float(np.sum(minimum)) if minimum is not None else None,
                                         clock.record.pacing_s if clock is not None else 0.0,
                                         clock.record.to_dict() if clock is not None else None,
                                         gain_blocks=blocks))
        if pass_stopped(res, experiment, result):
            return None
        t, Y = achieved(res.path, experiment)
        report = tracking_report(programme, t, Y)
        result.passes.append(report)
        (res.path / "tracking.json").write_text(json.dumps(report.to_dict(), indent=1) + "\n")
        comp = result.compensation
        learned = None
        if comp is not None and self.learn:
            comp.learn(report.channels, programme.ranges_kgf)
            comp.save(result.out / "compensation.toml")
            if report.cases is not None:
                learned = comp.learned(programme.case_labels)
        result.learned.append(learned)
        return t, Y


def pass_stopped(res, experiment, result) -> bool:
    """True when the pass ``res`` ended before its programme was run through; ``result.end_reason``
    and ``end_message`` then say why."""
    if res.status == "complete" and experiment.main_start_s is not None:
        return False
    result.end_reason = res.reason or res.status
    result.end_message = res.outcome.message if res.outcome else None
    return True


def _scaled_passes(passes: _Passes, programme: Programme, minimum: np.ndarray, repeat: int,
                   options: ScalingOptions):
    """Time scaling of the load cases, pass by pass (loading.time_scaling). Returns the last
    pass's (programme, forces), or None."""
    result = passes.result
    result.converged = False
    gw, controller = passes.gw, passes.controller
    scaler = TimeScaler(programme, minimum, programme.segment_durations_s, options)
    share_limit = FEEDFORWARD_SHARE * min(controller.command_limit_pct, gw.config.limits.command_limit_pct)
    base = programme
    last = None
    for i in range(1, repeat + 1):
        current, experiment = stretched_pass(base, scaler, i, passes.experiment, segment_peaks, share_limit)
        settled = scaler.all_settled
        experiment.check(gw.config.period_s, force_limits(gw.config), gw.config.limits.command_limit_pct)
        done = passes.run(experiment, current, minimum, i)
        if done is None:
            break
        last = (current, done)
        report = result.passes[-1]
        ok = meets(report, options.accuracy_pct)
        clock = experiment.clock
        paced = ({k - experiment.lead: v for k, v in clock.paced_by_turning.items()}
                 if clock is not None else None)
        verdicts = scaler.station_verdicts(current, report, *done, paced)
        result.timings[-1].scaling = {**scaler.last, "met_accuracy": ok, "all_settled_before": settled}
        if ok:
            keep_if_fastest(result, base, current, i, options, minimum, passes.ran_with)
        if ok and settled:
            result.converged = True
            break
        scaler.update(verdicts)
    if result.schedule is None:
        Schedule.of(base, scaler.durations, options.accuracy_pct, float(np.sum(minimum)), False,
                    ["no pass met the accuracy: these durations are the next pass's"]).save(result.out / "schedule.toml")
    return last


def keep_if_fastest(result: LoadResult, base: Programme, current: Programme, i: int, options: ScalingOptions,
                    minimum: np.ndarray, compensation: str | None = None) -> None:
    """Pass ``i`` ran ``current`` and met the accuracy: its durations are ``result.schedule``
    (saved as ``OUT/schedule.toml``) when no faster pass met it, with the corrections it ran
    with (``compensation``: a compensation file's text, saved beside it as
    :data:`SCHEDULE_COMPENSATION`), which a replay starts from: it holds what the pass did."""
    if result.schedule is not None and current.duration_s >= result.schedule.time_s:
        return
    result.schedule = Schedule.of(base, current.segment_durations_s, options.accuracy_pct, float(np.sum(minimum)),
                                  True, [f"pass {i} of {result.out}"])
    if compensation is not None:
        (result.out / SCHEDULE_COMPENSATION).write_text(compensation)
        result.schedule.compensation = SCHEDULE_COMPENSATION
    result.schedule.save(result.out / "schedule.toml")


def stretched_pass(base: Programme, scaler: TimeScaler, i: int, experiment_for, peaks_of, share_limit: float):
    """Pass ``i``'s programme (``base`` with the scaler's durations) and its experiment
    (``experiment_for(programme)``), every segment whose feedforward needs more than
    ``share_limit`` (``peaks_of(experiment)``: each segment's largest command) lengthened
    first, at most :data:`STRETCH_TRIES` times."""
    for _ in range(STRETCH_TRIES):
        current = base.with_durations(scaler.durations, f"{base.source}, scaled pass {i}")
        experiment = experiment_for(current)
        stretched = stretch_to_valve(scaler.durations, peaks_of(experiment), share_limit)
        if stretched is None:
            break
        scaler.durations = np.maximum(stretched, scaler.floor)
    return current, experiment


def segment_peaks(e: LoadProgramme) -> np.ndarray:
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


def feedforward_text(covers: dict) -> str:
    """Per channel, what the feedforward inverts of the controller's model and what it leaves
    to the feedback and the learning (``LoadProgramme.feedforward_covers``)."""
    lines = ["feedforward from the controller's model (what it inverts; what it does not, left to the "
             "feedback and the learning):"]
    for name, c in covers.items():
        lines.append(f"  {name}: inverts {', '.join(c['inverts']) or 'nothing'}"
                     + (f"; not {', '.join(c['does_not_invert'])}" if c["does_not_invert"] else ""))
    return "\n".join(lines)


def learned_text(learned: dict) -> str:
    """One pass's learning by load case in a few lines (``Compensation.learned``)."""
    counts = ", ".join(f"{k} {v}" for k, v in learned["statuses"].items() if v)
    lines = [f"learnt by load case (channel and case): {counts}"]
    for w in learned["not_learning"]:
        why = {"bound": "its correction is at the bound (5 % of the range)",
               "back": "worse than its best, no sensitivity to trust: back to the best correction",
               "unreached": f"the force did not follow the level (it moved under {UNREACHED_BELOW:.0%} of "
                            "a correction): the segment arriving there runs longer"}[w["status"]]
        lines.append(f"  {w['channel']} at case {w['case']} ({w['error_kgf']:+.0f} kgf): {why}")
    if learned.get("stretched_segments"):
        lines.append("  segments lengthened: " + ", ".join(f"{k} x{f:.2f}" for k, f in learned["stretched_segments"].items()))
    return "\n".join(lines)


def _write_reports(result: LoadResult, programme: Programme, last) -> None:
    out = result.out
    lines = [feedforward_text(result.feedforward)] if result.feedforward is not None else []
    for i, (p, t) in enumerate(zip(result.passes, result.timings), start=1):
        learned = result.learned[i - 1] if i - 1 < len(result.learned) else None
        lines.append(f"pass {i}:\n{t.text()}\n{p.text()}" + (f"\n{learned_text(learned)}" if learned else ""))
    table = cases_table(result.passes)
    if table:
        lines.append(table)
    if result.end_reason not in (None, "complete"):
        lines.append(f"pass {len(result.run_dirs)} stopped ({result.end_reason}): {result.end_message}")
    if result.monitor is not None:
        lines.append(result.monitor.text())
    (out / "report.txt").write_text("\n\n".join(lines) + "\n")
    if last is not None:
        plot_tracking(programme, *last, result.passes[-1], out / "tracking.png",
                      title=f"{programme.source}: pass {len(result.passes)}")
    (out / "report.json").write_text(json.dumps(result.summary(), indent=2) + "\n")
