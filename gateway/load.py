"""Loading programmes on the stand, pass by pass (``stand load``): the load experiment
(:mod:`gateway.load_experiment`) run ``repeat`` times, learning between passes.

The supervisor's tracking-error limit, when none is set, is :data:`ERROR_LIMIT_SHARE` of the
programme's range for these passes: a pass that cannot track stops safely and says why.
``run_load`` runs ``repeat`` passes in a row, each in its own run directory under ``out``
(``pass-1``, ``pass-2``, ...); after each pass the tracking report is made from the recorded
force and the peak/valley compensation learns from it before the next. ``out`` also holds the
controller used, the learned corrections (``compensation.toml``), the report (``report.json``,
``report.txt``) and a figure of the last pass (``tracking.png``).

**Time scaling** (``scaling``, :mod:`loading.time_scaling`): the segment durations change
from pass to pass, each on its own, until every turning point holds the accuracy as fast as it
can; ``out/schedule.toml`` keeps the fastest schedule whose pass met the accuracy. A
``schedule`` replays one. Every pass reports the programme's time (without the approach, the
pre-roll and the unload), the valve-limited minimum (:mod:`loading.minimum_time`) and the time
spent pacing (:mod:`loading.pacing`).

Everything that can be checked is checked before anything moves (:meth:`LoadProgramme.check`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from core.errors import ParameterError
from loading.compensation import Compensation
from loading.design import ControllerDesign
from loading.gain_monitor import GainMonitor, MonitorOptions, margin_table
from loading.minimum_time import minimum_durations_s, programme_valve_limit
from loading.pacing import PacingOptions
from loading.programme import Programme
from loading.report import TrackingReport, load_summary, plot_tracking, tracking_report
from loading.time_scaling import (ScalingOptions, Schedule, TimeScaler, meets, ringing_turning_points,
                                  stretch_to_valve)

from .load_experiment import (FEEDFORWARD_SHARE, PRE_ROLL_S, PRE_ROLL_SHARE,  # noqa: F401 (re-exported)
                              LoadProgramme, OneWayApproach, _pre_roll, _unload_tail)
from .runs import load_run

#: the supervisor's tracking-error limit when none is set: this share of the programme's range
ERROR_LIMIT_SHARE = 0.10
#: time scaling: at most this many stretches of the segments the valve cannot follow, per pass
STRETCH_TRIES = 6


@dataclass
class PassTiming:
    """How long a pass's programme took beside its minimum, and what pacing did."""

    programme_time_s: float           #: the scheduled programme, without approach/pre-roll/unload
    minimum_time_s: float             #: the valve-limited minimum of the same programme
    pacing_s: float = 0.0             #: time on the stand beyond the programme's, pacing
    pacing: dict | None = None        #: the pacing record (waits, slowed time), None: pacing off
    scaling: dict | None = None       #: time scaling: segments landed / held / missed
    gain_blocks: list | None = None   #: the gain monitor's blocks of this pass (dicts)

    def figures(self) -> dict:
        d = {"programme_time_s": self.programme_time_s, "minimum_time_s": self.minimum_time_s,
             "time_over_minimum": self.programme_time_s / self.minimum_time_s if self.minimum_time_s else None,
             "pacing_s": self.pacing_s}
        if self.pacing is not None:
            d["pacing"] = self.pacing
        if self.scaling is not None:
            d["scaling"] = self.scaling
        if self.gain_blocks is not None:
            d["gain_blocks"] = self.gain_blocks
        return d


@dataclass
class LoadResult:
    out: Path
    passes: list[TrackingReport] = field(default_factory=list)
    run_dirs: list[Path] = field(default_factory=list)
    end_reason: str | None = None
    end_message: str | None = None
    compensation: Compensation | None = None
    timings: list[PassTiming] = field(default_factory=list)
    #: time scaling: the fastest schedule whose pass met the accuracy (None: none did)
    schedule: Schedule | None = None
    #: time scaling: did the last pass run every segment settled and meet the accuracy
    converged: bool | None = None
    #: the gain monitor of the test (None: off)
    monitor: GainMonitor | None = None

    def summary(self) -> dict:
        d = load_summary(self.passes, self.end_reason or "complete",
                         [t.figures() for t in self.timings[:len(self.passes)]])
        d["runs"] = [str(p) for p in self.run_dirs]
        if self.end_message:
            d["end_message"] = self.end_message
        if self.converged is not None:
            d["schedule"] = ({"time_s": self.schedule.time_s, "minimum_time_s": self.schedule.minimum_time_s,
                              "accuracy_pct": self.schedule.accuracy_pct, "verified": self.schedule.verified}
                             if self.schedule is not None else None)
            d["converged"] = self.converged
        if self.monitor is not None:
            d["gain"] = self.monitor.summary()
        return d


def achieved(run_dir: Path, experiment: LoadProgramme) -> tuple[np.ndarray, np.ndarray]:
    """The recorded force on the programme's clock (t = 0 at its start): with pacing, each
    sample of the main phase at the clock's position then (a wait's samples share a time)."""
    run = load_run(run_dir)
    t = np.asarray(run.t, float)
    t0 = experiment.programme_start_s or 0.0
    if not experiment.positions or experiment.main_start_s is None:
        return t - t0, np.asarray(run.y)
    T = experiment.programme.period_s
    i = np.round((t - experiment.main_start_s) / T).astype(int)
    pos = np.asarray(experiment.positions)
    inside = (i >= 0) & (i < len(pos))
    prog = np.where(inside, (pos[np.clip(i, 0, len(pos) - 1)] - experiment.lead) * T, t - t0)
    return prog, np.asarray(run.y)


@dataclass
class _Pass:
    """What every pass of one ``run_load`` shares."""

    gw: object
    controller: ControllerDesign
    compensation: Compensation | None
    unload_kgf: float
    pacing: PacingOptions | None
    monitor: GainMonitor | None = None

    def experiment(self, programme: Programme, check: bool = True) -> LoadProgramme:
        e = LoadProgramme(programme, self.controller, self.compensation, self.unload_kgf, pacing=self.pacing,
                          monitor=self.monitor, unload_limits=self.gw.config.limits)
        if check:
            limits = self.gw.config.limits
            e.check(self.gw.config.period_s, limits.force_limit_kgf, limits.command_limit_pct)
        return e

    @property
    def command_limit_pct(self) -> float:
        return min(self.controller.command_limit_pct, self.gw.config.limits.command_limit_pct)


def run_load(gw, programme: Programme, controller: ControllerDesign, out: str | Path,
             repeat: int = 1, compensation: Compensation | None = None, learn: bool = True,
             unload_kgf: float = 0.0, progress: bool | None = None,
             error_limit_kgf: float | None = None, pacing: PacingOptions | None = None,
             scaling: ScalingOptions | None = None, schedule: Schedule | None = None,
             monitor: MonitorOptions | None = None) -> LoadResult:
    """Run ``repeat`` passes of ``programme`` on the gateway ``gw`` (module docstring).
    ``error_limit_kgf``: the tracking-error limit for these passes (default: the supervisor's,
    else :data:`ERROR_LIMIT_SHARE` of the programme's range). ``pacing``: null pacing
    (:mod:`loading.pacing`). ``schedule``: the segment durations to run (a ``schedule.toml``).
    ``scaling``: time scaling, at most ``repeat`` passes (:mod:`loading.time_scaling`).
    ``monitor``: the stand's g estimated block by block, followed by the feedforward and
    watched for a fall or a rise (:mod:`loading.gain_monitor`)."""
    if not (1 <= repeat <= 1000):
        raise ParameterError(f"repeat = {repeat}: it must be from 1 to 1000")
    if scaling is not None:
        scaling.check()
        if schedule is None and programme.turning_idx.size < 2:
            raise ParameterError("time scaling needs a programme with turning points")
    out = Path(out)
    if schedule is not None:
        programme = schedule.apply(programme)
    comp = compensation if compensation is not None else (Compensation() if learn and repeat > 1 else None)
    watcher = None
    if monitor is not None:
        monitor.check()
        model = controller.model
        watcher = GainMonitor(model.g, model.tau, model.delta, gw.config.period_s, monitor,
                              margin_table(controller.kp_pct_per_kgf, controller.ti_s, model.g, model.tau,
                                           gw.config.period_s, controller.boost))
    shared = _Pass(gw, controller, comp, unload_kgf, pacing, watcher)
    first = shared.experiment(programme)
    limit = programme_valve_limit(programme, controller.model, shared.command_limit_pct)
    minimum = minimum_durations_s(programme, limit)
    supervisor = gw.loop.supervisor
    own_limits = supervisor.limits
    if error_limit_kgf is None and own_limits.error_limit_kgf is None:
        error_limit_kgf = max(ERROR_LIMIT_SHARE * programme.range_kgf, 100.0)
    if error_limit_kgf is not None:             # this programme's, for these passes only
        supervisor.limits = replace(own_limits, error_limit_kgf=error_limit_kgf)
    try:
        if scaling is not None:
            return _scaled_passes(shared, programme, minimum, out, repeat, learn, progress, scaling)
        return _passes(shared, programme, minimum, out, repeat, first, learn, progress)
    finally:
        supervisor.limits = own_limits


def _run_pass(shared: _Pass, experiment: LoadProgramme, programme: Programme, minimum_s: np.ndarray,
              path: Path, result: LoadResult, learn: bool, progress):
    """One pass: run, report, learn. Returns (report, (t, y), paced per turning point) or None
    if the pass ended early (result.end_reason says why)."""
    res = shared.gw.run(experiment, path, progress=progress)
    result.run_dirs.append(res.path)
    monitor = shared.monitor
    blocks = None
    if monitor is not None and monitor.end_pass():
        blocks = [b.to_dict() for b in monitor.blocks if b.pass_index == monitor.pass_index]
        (res.path / "gain.json").write_text(json.dumps({**monitor.summary(), "blocks": blocks}, indent=2) + "\n")
        result.monitor = monitor
    clock = experiment.clock
    timing = PassTiming(programme.duration_s, float(np.sum(minimum_s)),
                        clock.record.pacing_s if clock is not None else 0.0,
                        clock.record.to_dict() if clock is not None else None, gain_blocks=blocks)
    result.timings.append(timing)
    if pass_stopped(res, experiment, result):
        return None
    t, y = achieved(res.path, experiment)
    report = tracking_report(programme, t, y)
    result.passes.append(report)
    comp = shared.compensation
    if comp is not None and learn:
        comp.learn(report.turning_points, programme.range_kgf)
        comp.save(result.out / "compensation.toml")
    paced = {}
    if clock is not None:
        paced = {int(k) - experiment.lead: v for k, v in clock.paced_by_turning.items()}
    return report, (t, y), paced


def pass_stopped(res, experiment, result) -> bool:
    """True when the pass ``res`` ended before its programme was run through (a stand's or a
    rig's); ``result.end_reason`` and ``end_message`` then say why."""
    if res.status == "complete" and experiment.main_start_s is not None:
        return False
    result.end_reason = res.reason or res.status
    result.end_message = res.outcome.message if res.outcome else None
    return True


def _passes(shared: _Pass, programme, minimum, out, repeat, first, learn, progress) -> LoadResult:
    out.mkdir(parents=True, exist_ok=True)
    controller = shared.controller
    (out / "controller.toml").write_text(controller.to_toml(out / "controller.toml"))
    result = LoadResult(out, compensation=shared.compensation)
    last = None
    for i in range(1, repeat + 1):
        experiment = first if i == 1 else shared.experiment(programme)
        done = _run_pass(shared, experiment, programme, minimum, out / f"pass-{i}", result, learn, progress)
        if done is None:
            break
        last = done[1]
    _write_reports(result, programme, last)
    return result


def _scaled_passes(shared: _Pass, programme, minimum, out, repeat, learn, progress,
                   options: ScalingOptions) -> LoadResult:
    """Time scaling, pass by pass (loading.time_scaling)."""
    out.mkdir(parents=True, exist_ok=True)
    controller = shared.controller
    (out / "controller.toml").write_text(controller.to_toml(out / "controller.toml"))
    result = LoadResult(out, compensation=shared.compensation, converged=False)
    scaler = TimeScaler(programme, minimum, programme.segment_durations_s, options)
    share_limit = FEEDFORWARD_SHARE * shared.command_limit_pct
    base = programme
    last = None                                  # (the programme, its forces) of the last pass
    for i in range(1, repeat + 1):
        current, experiment = stretched_pass(base, scaler, i, lambda p: shared.experiment(p, check=False),
                                             _segment_peaks, share_limit)
        settled = scaler.all_settled
        limits = shared.gw.config.limits
        experiment.check(shared.gw.config.period_s, limits.force_limit_kgf, limits.command_limit_pct)
        done = _run_pass(shared, experiment, current, minimum, out / f"pass-{i}", result, learn, progress)
        if done is None:
            break
        report, forces, paced = done
        last = (current, forces)
        ok = meets(report, options.accuracy_pct)
        verdicts = scaler.verdicts(current, report, ringing_turning_points(current, *forces), paced)
        result.timings[-1].scaling = {**scaler.last, "met_accuracy": ok, "all_settled_before": settled}
        if ok:
            keep_if_fastest(result, base, current, i, options, minimum)
        if ok and settled:
            result.converged = True
            break
        scaler.update(verdicts)
    if result.schedule is None:
        save_unverified(result, base, scaler, options, minimum)
    _write_reports(result, *(last or (programme, None)))
    return result


def keep_if_fastest(result, base, current, i: int, options: ScalingOptions, minimum: np.ndarray,
                    channels: list[str] | None = None) -> None:
    """Pass ``i`` ran ``current`` and met the accuracy: its durations are ``result.schedule``
    (saved as ``OUT/schedule.toml``) when no faster pass met it. A stand's or (``channels``) a rig's."""
    if result.schedule is not None and current.duration_s >= result.schedule.time_s:
        return
    result.schedule = Schedule(base.levels_kgf, current.segment_durations_s, base.period_s,
                               options.accuracy_pct, float(np.sum(minimum)), base.source,
                               verified=True, notes=[f"pass {i} of {result.out}"], channels=channels)
    result.schedule.save(result.out / "schedule.toml")


def save_unverified(result, base, scaler: TimeScaler, options: ScalingOptions, minimum: np.ndarray,
                    channels: list[str] | None = None) -> None:
    """No pass met the accuracy: the next pass's durations saved, marked unverified."""
    Schedule(base.levels_kgf, scaler.durations, base.period_s, options.accuracy_pct,
             float(np.sum(minimum)), base.source, verified=False,
             notes=["no pass met the accuracy: these durations are the next pass's"],
             channels=channels).save(result.out / "schedule.toml")


def stretched_pass(base, scaler: TimeScaler, i: int, experiment_for, peaks_of, share_limit: float):
    """Pass ``i``'s programme (``base`` with the scaler's durations) and its experiment
    (``experiment_for(programme)``), every segment whose feedforward needs more than
    ``share_limit`` (``peaks_of(experiment)``: each segment's largest command) lengthened
    first, at most :data:`STRETCH_TRIES` times. A stand's or a rig's."""
    for _ in range(STRETCH_TRIES):
        current = base.with_durations(scaler.durations, f"{base.source}, scaled pass {i}")
        experiment = experiment_for(current)
        stretched = stretch_to_valve(scaler.durations, peaks_of(experiment), share_limit)
        if stretched is None:
            break
        scaler.durations = np.maximum(stretched, scaler.floor)
    return current, experiment


def _segment_peaks(e: LoadProgramme) -> np.ndarray:
    """Each segment's largest feedforward command (%), both ways into the programme."""
    programme = e.commanded
    m = int(round(e.controller.model.tau / programme.period_s))
    idx = e.lead + programme.turning_idx - m
    peaks = np.zeros(len(idx) - 1)
    for plan in e.plans.values():
        u = np.abs(plan.ff.u_pct)
        for j in range(len(peaks)):
            a, b = max(idx[j], 0), max(idx[j + 1], 1)
            peaks[j] = max(peaks[j], float(u[a:b].max()))
    return peaks


def _write_reports(result: LoadResult, programme: Programme, last) -> None:
    out = result.out
    if last is not None:
        lines = []
        for i, (p, timing) in enumerate(zip(result.passes, result.timings), start=1):
            lines.append(f"pass {i}:\n{timing_text(timing)}\n{p.text()}")
        if result.monitor is not None:
            lines.append(gain_text(result.monitor))
        (out / "report.txt").write_text("\n\n".join(lines) + "\n")
        t, y = last
        plot_tracking(programme, t, y, result.passes[-1], out / "tracking.png",
                      title=f"{programme.source}: pass {len(result.passes)}")
    (out / "report.json").write_text(json.dumps(result.summary(), indent=2) + "\n")


def timing_text(timing: PassTiming) -> str:
    """One line: the programme's time, the minimum, their ratio, pacing."""
    text = (f"programme {timing.programme_time_s:.1f} s, valve-limited minimum {timing.minimum_time_s:.1f} s "
            f"({timing.programme_time_s / timing.minimum_time_s:.2f}x)")
    if timing.pacing is not None:
        text += (f", pacing {timing.pacing_s:.2f} s ({timing.pacing['waits']} waits, "
                 f"{timing.pacing['slowed_s']:.2f} s slowed)")
    if timing.scaling is not None:
        s = timing.scaling
        text += f"; segments landed {s.get('land', 0)}, held {s.get('hold', 0)}, missed {s.get('miss', 0)}"
    return text


def gain_text(monitor: GainMonitor) -> str:
    """The gain monitor's blocks in a few lines: the estimates' span, the last, the alarm."""
    est = [b for b in monitor.blocks if b.g is not None]
    if not est:
        return f"gain: no block had enough steady motion for an estimate ({len(monitor.blocks)} blocks)"
    last = est[-1]
    lines = [f"gain: {len(est)} of {len(monitor.blocks)} blocks estimated, g from {min(b.g for b in est):.1f} "
             f"to {max(b.g for b in est):.1f} kgf/(%·s) (model {monitor.g_ref:.1f}); last "
             f"{last.g:.1f} [{last.low:.1f}, {last.high:.1f}] ({last.change_pct:+.1f} %), feedforward at "
             f"g = {monitor.g_follow:.1f}"]
    if monitor.alarm is not None:
        lines.append(f"gain alarm ({monitor.alarm[0]}, action {monitor.options.action}): {monitor.alarm[1]}")
    return "\n".join(lines)
