"""The loading API as the recorded one-channel passes use it (tests/support/golden_passes.py):
the one place that names the load experiment's constructors and calls, so the recorded
scenarios stay the same whatever the modules are called."""
from __future__ import annotations

import numpy as np

T = 0.002


def stepper(experiment, period_s: float, force_limit_kgf: float):
    """(begin, finished, step, aborted) for one channel, as the control loop calls them."""
    experiment.configure_rig(period_s, [force_limit_kgf])

    def step(t: float, y: float) -> tuple[float, float]:
        u, r = experiment.step_rig(t, [y])
        return float(u[0]), float(r[0])
    return (lambda y: experiment.begin_rig([y]), lambda t, y: experiment.finished_rig(t, [y]), step,
            lambda: experiment.abort is not None)


def design_from(model):
    from loading.design import design
    return design(model, T)


def proportional_from(model, kp: float):
    from loading.design import proportional
    return proportional(kp, model, T)


def programme_levels(n: int, seed: int, rate: float):
    from loading.programme import from_levels, random_sequence
    return lambda: from_levels(random_sequence(n, 400, 6200, seed=seed), T, rate_kgf_s=rate)


def programme_sine():
    from loading.programme import sine
    return sine(3000, 2000, 0.2, 3, T)


def compensation():
    from loading.compensation import Compensation
    from loading.programme import STAND
    return Compensation([STAND])


def pacing(mode: str):
    from loading.pacing import PacingOptions
    return PacingOptions(mode)


def gain_monitor(controller, block_s: float, follow: bool):
    from loading.gain_monitor import GainMonitor, MonitorOptions
    return GainMonitor.for_controller(controller, T, MonitorOptions(block_s=block_s, follow=follow))


def load_programme_for(programme, controller, compensation=None, pacing=None, monitor=None):
    from gateway.load_experiment import LoadProgramme
    from loading.programme import Programme
    return LoadProgramme(Programme.of(programme), controller, compensation, pacing=pacing, monitor=monitor)


def learn(experiment, u: np.ndarray, r: np.ndarray, y: np.ndarray, period_s: float) -> None:
    """What the pass loop does after a pass: the gain monitor closes it, the compensation learns
    from the tracking report on the programme's clock."""
    from loading.report import tracking_report
    if experiment.monitor is not None:
        experiment.monitor.end_pass()
    if experiment.compensation is None:
        return
    t = experiment.programme_times(np.arange(len(y)) * period_s)
    report = tracking_report(experiment.programme, t, np.asarray(y, float)[None, :])
    experiment.compensation.learn(report.channels, experiment.programme.ranges_kgf)
