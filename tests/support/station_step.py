"""The loading API as the recorded one-channel passes use it (tests/support/golden_passes.py):
the one place that names the load experiment's constructors and calls, so the recorded
scenarios stay the same whatever the modules are called."""
from __future__ import annotations

import numpy as np

T = 0.002


def stepper(experiment, period_s: float, force_limit_kgf: float):
    """(begin, finished, step, aborted) for one channel, as the control loop calls them."""
    experiment.configure(period_s, force_limit_kgf)
    return (experiment.begin, experiment.finished, experiment.step,
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
    return Compensation()


def pacing(mode: str):
    from loading.pacing import PacingOptions
    return PacingOptions(mode)


def gain_monitor(controller, block_s: float, follow: bool):
    from loading.gain_monitor import GainMonitor, MonitorOptions, margin_table
    model = controller.model
    options = MonitorOptions(block_s=block_s, follow=follow)
    return GainMonitor(model.g, model.tau, model.delta, T, options,
                       margin_table(controller.kp_pct_per_kgf, controller.ti_s, model.g, model.tau, T,
                                    controller.boost))


def load_programme_for(programme, controller, compensation=None, pacing=None, monitor=None):
    from gateway.load_experiment import LoadProgramme
    return LoadProgramme(programme, controller, compensation, pacing=pacing, monitor=monitor)


def learn(experiment, u: np.ndarray, r: np.ndarray, y: np.ndarray, period_s: float) -> None:
    """What the pass loop does after a pass: the gain monitor closes it, the compensation learns
    from the tracking report on the programme's clock."""
    from loading.report import tracking_report
    if experiment.monitor is not None:
        experiment.monitor.end_pass()
    if experiment.compensation is None:
        return
    t = np.arange(len(y)) * period_s
    start = experiment.programme_start_s
    if experiment.positions:
        i = np.round((t - experiment.main_start_s) / period_s).astype(int)
        pos = np.asarray(experiment.positions)
        inside = (i >= 0) & (i < len(pos))
        t = np.where(inside, (pos[np.clip(i, 0, len(pos) - 1)] - experiment.lead) * period_s, t - start)
    else:
        t = t - start
    report = tracking_report(experiment.programme, t, y)
    experiment.compensation.learn(report.turning_points, experiment.programme.range_kgf)
