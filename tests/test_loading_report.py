"""The tracking report: turning-point errors as % of the range, and self-oscillation counted as
rainflow cycles the programme does not have (a ring counts, a lag, an overshoot or noise not)."""
from __future__ import annotations

import json

import numpy as np

from loading.programme import from_levels, sine
from loading.report import channel_report, load_summary, plot_tracking, tracking_report

T = 0.002


def triangle_like():
    """A 0.2 Hz programme between 1000 and 5000 kgf (a sine, 6 cycles)."""
    return sine(3000, 2000, 0.2, 6, T)


def test_a_perfect_tracking_has_no_error_and_no_extra_cycle():
    p = triangle_like()
    rep = channel_report(p, p.t_s, p.r_kgf)
    assert rep.peak_valley_error_pct["max"] < 1e-9 and rep.rms_error_pct < 1e-9
    assert rep.extra_cycles == 0 and len(rep.turning_points) == 12


def test_a_ring_after_each_reversal_is_counted_as_extra_cycles():
    p = triangle_like()
    y = p.r_kgf.copy()
    for k in p.turning_idx[1:-1]:               # a decaying 5 Hz ring of 100 kgf after each one
        n = np.arange(len(y) - k)
        tt = n * T
        y[k:] += 100 * np.sin(2 * np.pi * 5 * tt) * np.exp(-tt / 0.3)
    rep = channel_report(p, p.t_s, y)
    # near each turning point the ring reverses the force against the programme's slope at
    # least once by more than the 20 kgf gate (0.5 % of 4000 kgf): one extra cycle or more each
    assert rep.extra_cycles >= 12 and rep.largest_extra_cycle_kgf > 20


def test_a_lag_an_overshoot_and_noise_count_no_extra_cycle_but_show_as_errors():
    p = triangle_like()
    lagged = np.interp(p.t_s - 0.05, p.t_s, p.r_kgf)
    y = 3000 + (lagged - 3000) * 1.01 + np.random.default_rng(1).normal(0, 2, len(p.t_s))
    rep = channel_report(p, p.t_s, y)
    assert rep.extra_cycles == 0
    # a 1 % overshoot of the amplitude is 0.5 % of the range at every peak and valley
    assert 0.4 < rep.peak_valley_error_pct["p95"] < 0.7 and 0.4 < rep.overshoot_max_pct < 0.7
    assert rep.rms_error_pct > 0.5, "a 50 ms lag at 0.2 Hz shows in the RMS error"


def test_a_late_peak_still_counts_as_reached():
    p = from_levels([1000, 5000, 1000], T, rate_kgf_s=2500)
    late = np.interp(p.t_s - 0.2, p.t_s, p.r_kgf)
    rep = channel_report(p, p.t_s, late)
    assert abs(rep.turning_points[0].error_kgf) < 1.0


def test_the_json_summary_has_the_last_pass_on_top_and_every_pass(tmp_path):
    p = triangle_like()
    reps = [tracking_report(p, p.t_s, p.r_kgf * f) for f in (1.02, 1.0)]
    s = json.loads(json.dumps(load_summary(reps, "complete")))
    assert s["schema"] == "hydrostand-load/1" and len(s["passes"]) == 2
    assert s["peak_valley_error_pct"] == s["passes"][1]["peak_valley_error_pct"]
    assert set(s) >= {"peak_valley_error_pct", "rms_error_pct", "extra_cycles", "range_kgf",
                      "turning_points", "end_reason", "passes"}
    png = plot_tracking(p, p.t_s, p.r_kgf * 1.02, reps[0], tmp_path / "t.png")
    assert png.stat().st_size > 10_000
