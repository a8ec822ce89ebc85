"""Time scaling: each segment is shortened while its turning point lands and lengthened when it
misses, on its own, never below the valve-limited minimum; the fastest schedule that met the
accuracy is saved and replayed. End to end: `stand load --fastest` on the emulated default
stand ends within 1.5x the minimum at the accuracy, and `--schedule` replays it."""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from core.errors import ParameterError
from gateway import Gateway, GatewayConfig
from gateway.load import run_load
from loading.design import design
from loading.programme import from_levels, random_sequence, sine
from loading.time_scaling import (HOLD, LAND, MISS, ScalingOptions, Schedule, TimeScaler,
                                  ringing_turning_points)
from plant import PlantModel
from stand.cli import main as stand
from tests.support.stand import BASE, plant

T = 0.002
MODEL = {**BASE, "reversal.boost": 2.0}


def report(programme, errors_pct):
    """A tracking report with these errors (% of the range) at the peaks and valleys."""
    idx = programme.turning_idx[1:-1]
    return SimpleNamespace(turning_points=[SimpleNamespace(index=int(i), error_pct=e)
                                           for i, e in zip(idx, errors_pct)])


def test_segments_that_land_shorten_to_the_floor_and_those_that_miss_are_bisected_on_their_own():
    p = from_levels([500.0, 5000.0, 1000.0, 4000.0, 2000.0, 2500.0], T, rate_kgf_s=2500)
    floor = p.segment_durations_s / 5
    scaler = TimeScaler(p, floor, p.segment_durations_s, ScalingOptions(accuracy_pct=0.5))
    start = scaler.durations.copy()
    # segment 1 (to the first peak) lands; segment 2 misses at any duration under 0.6 of its start
    for _ in range(12):
        current = p.with_durations(scaler.durations)
        e = [0.1, 0.9 if scaler.durations[1] < 0.6 * start[1] else 0.1, 0.1, 0.1]
        v = scaler.verdicts(current, report(current, e))
        scaler.update(v)
    assert scaler.durations[0] == pytest.approx(scaler.floor[0]), "a landing segment goes to its floor"
    assert 0.6 * start[1] <= scaler.durations[1] <= 0.6 * start[1] * 1.06 + T, \
        "a missing one settles within the resolution above where it starts to miss"
    assert scaler.all_settled and scaler.durations[2] == pytest.approx(scaler.floor[2])
    # the last segment arrives at no peak or valley: it lands
    assert scaler.verdicts(p, report(p, [0.1, 0.1, 0.1, 0.1]))[-1] == LAND


def test_the_verdict_bands_ringing_and_pacing():
    p = from_levels([500.0, 5000.0, 1000.0, 4000.0], T, rate_kgf_s=2500)
    scaler = TimeScaler(p, p.segment_durations_s / 3, p.segment_durations_s, ScalingOptions(accuracy_pct=0.5))
    assert scaler.verdicts(p, report(p, [0.2, -0.3])) == [LAND, HOLD, LAND]
    assert scaler.verdicts(p, report(p, [0.45, 0.1])) == [MISS, LAND, LAND]
    assert scaler.verdicts(p, report(p, [0.1, 0.1]), ringing={int(p.turning_idx[2])}) == [LAND, MISS, LAND]
    paced = {int(p.turning_idx[1]): 0.5 * p.segment_durations_s[0]}
    assert scaler.verdicts(p, report(p, [0.1, 0.1]), paced_s=paced) == [MISS, LAND, LAND]
    # a segment that misses where it had landed is settled a little longer, not chased
    d = scaler.durations[0]
    scaler.landed[0] = d
    scaler.update([MISS, LAND, LAND])
    scaler.update([MISS, LAND, LAND])
    assert scaler.durations[0] == pytest.approx(d * 1.1 ** 2, rel=0.02) and scaler.settled[0]
    assert (scaler.durations <= scaler.ceiling).all()


def test_a_ring_near_a_turning_point_is_found_there_only():
    p = sine(3000, 2000, 0.2, 3, T)
    y = p.r_kgf.copy()
    k = p.turning_idx[3]
    n = np.arange(len(y) - k)
    y[k:] += 100 * np.sin(2 * np.pi * 5 * n * T) * np.exp(-n * T / 0.2)
    assert ringing_turning_points(p, p.t_s, y) == {int(k)}
    assert ringing_turning_points(p, p.t_s, p.r_kgf) == set()


def test_a_schedule_round_trips_and_refuses_another_programme(tmp_path):
    p = from_levels([500.0, 5000.0, 1000.0], T, rate_kgf_s=2500)
    s = Schedule(p.levels_kgf, np.array([0.5, 0.4]), T, 0.5, 0.7, p.source, True, ["pass 3"])
    back = Schedule.load(s.save(tmp_path / "schedule.toml"))
    assert np.allclose(back.durations_s, [0.5, 0.4]) and back.verified and back.notes == ["pass 3"]
    assert np.allclose(back.apply(p).segment_durations_s, [0.5, 0.4])
    other = from_levels([500.0, 5000.0, 1200.0], T, rate_kgf_s=2500)
    with pytest.raises(ParameterError, match="another programme.*turning point 3 differs"):
        back.apply(other)
    (tmp_path / "bad.toml").write_text("levels_kgf = [1, 2]\n")
    with pytest.raises(ParameterError, match="not a schedule file"):
        Schedule.load(tmp_path / "bad.toml")
    with pytest.raises(ParameterError, match="accuracy 0.0 %: give a share"):
        ScalingOptions(accuracy_pct=0.0).check()


@pytest.mark.e2e
@pytest.mark.slow
def test_fastest_ends_near_the_valve_limit_at_the_accuracy_and_the_schedule_replays(bus_spec, start_emulator,
                                                                                    tmp_path, capsys):
    start_emulator(plant(MODEL, model="base+reversal"), lockstep=True, seed=4)
    controller = design(PlantModel.from_spec("base+reversal", MODEL), T)
    ctl = tmp_path / "c.toml"
    ctl.write_text(controller.to_toml())
    levels = random_sequence(12, 400, 6200, seed=5)
    seq = tmp_path / "tp.csv"
    seq.write_text("level\n" + "\n".join(repr(float(v)) for v in levels) + "\n")
    capsys.readouterr()
    rc = stand(["load", str(seq), "--rate", "2500", "--controller", str(ctl), "--out", str(tmp_path / "fast"),
                "--lockstep", "--bus", bus_spec, "--no-progress", "--json", "--fastest"])
    assert rc == 0, capsys.readouterr().err
    s = json.loads(capsys.readouterr().out)
    assert s["converged"] and s["schedule"]["verified"], s["schedule"]
    times = [p["programme_time_s"] for p in s["passes"]]
    assert times == sorted(times, reverse=True) and times[0] / times[-1] > 3, times
    assert s["schedule"]["time_s"] <= 1.5 * s["schedule"]["minimum_time_s"]
    assert s["time_over_minimum"] <= 1.5 and s["minimum_time_s"] > 0 and s["pacing_s"] == 0
    assert s["peak_valley_error_pct"]["p95"] <= 0.5 and s["peak_valley_error_pct"]["max"] <= 1.0
    assert all(p["extra_cycles"] == 0 for p in s["passes"])
    assert all("scaling" in p for p in s["passes"])
    schedule = Schedule.load(tmp_path / "fast" / "schedule.toml")
    with Gateway(GatewayConfig(bus=bus_spec, lockstep=True)) as gw:      # a production run
        res = run_load(gw, from_levels(levels, T, rate_kgf_s=2500), controller, tmp_path / "prod",
                       schedule=schedule, progress=False)
    again = res.summary()
    assert again["programme_time_s"] == pytest.approx(schedule.time_s, abs=T)
    assert again["peak_valley_error_pct"]["p95"] <= 0.5 and again["extra_cycles"] == 0


def test_scaling_and_a_schedule_are_checked_before_the_stand_is_touched(tmp_path, capsys):
    ctl = tmp_path / "c.toml"
    ctl.write_text(design(PlantModel.from_spec("base+reversal", MODEL), T).to_toml())
    seq = tmp_path / "tp.csv"
    seq.write_text("level\n500\n5000\n1000\n")
    s = Schedule(np.array([500.0, 5000.0, 1000.0]), np.array([0.8, 0.7]), T, 0.5, 1.0, "tp", True)
    s.save(tmp_path / "schedule.toml")
    other = tmp_path / "other.csv"
    other.write_text("level\n500\n5000\n1200\n")
    cases = [(["--fastest", "--schedule", str(tmp_path / "schedule.toml")], "one or the other"),
             (["--accuracy", "0"], "accuracy 0.0 %"),
             (["--schedule", str(tmp_path / "schedule.toml")], None)]
    for extra, message in cases:
        capsys.readouterr()
        rc = stand(["load", str(seq), "--controller", str(ctl), "--plan", *extra])
        out, err = capsys.readouterr()
        if message is None:       # a sequence needs no --rate with a schedule: its time is the schedule's
            assert rc == 0 and "the schedule:" in out and "1.5 s" in out, (out, err)
        else:
            assert rc == 2 and message in err and "Traceback" not in err, err
    rc = stand(["load", str(other), "--controller", str(ctl), "--plan", "--schedule", str(tmp_path / "schedule.toml")])
    err = capsys.readouterr().err
    assert rc == 2 and "made for another programme" in err
