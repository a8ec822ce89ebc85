"""Null pacing: on a stand whose valve is slower than the controller's model says (a flow limit
the model lacks), turning points are missed without pacing; with it the programme waits
(static) or also slows (dynamic) and none is missed, the time it took reported per pass. The
programme's clock runs sample for sample while the force follows, and gives up on a level the
stand cannot reach."""
from __future__ import annotations

import json

import numpy as np
import pytest

from gateway import Gateway, GatewayConfig
from gateway.load import run_load
from gateway.load_experiment import LoadProgramme
from loading.design import design
from loading.pacing import PacingOptions, ProgrammeClock
from loading.programme import from_levels, random_sequence
from plant import PlantModel
from plant_emulator.lockstep_plant import LockstepPlant
from stand.cli import main as stand
from tests.support.stand import BASE, plant
from tests.support.station_step import stepper

T = 0.002
MODEL = {**BASE, "reversal.boost": 2.0}


@pytest.mark.e2e
@pytest.mark.slow
def test_a_slow_valve_misses_turning_points_without_pacing_and_none_with_it(bus_spec, start_emulator,
                                                                             tmp_path, capsys):
    # the stand's valve passes at most 25 % of flow; the programme at 5000 kgf/s needs up to 42 %
    start_emulator(plant({**MODEL, "saturation.limit": 25.0}, model="base+reversal+saturation"),
                   lockstep=True, seed=3)
    controller = design(PlantModel.from_spec("base+reversal", MODEL), T)
    levels = random_sequence(9, 400, 6200, seed=3)
    out = {}
    with Gateway(GatewayConfig(bus=bus_spec, lockstep=True)) as gw:
        for mode in ("off", "static"):      # the pass without pacing may lag: let it finish, measured
            res = run_load(gw, from_levels(levels, T, rate_kgf_s=5000), controller, tmp_path / mode,
                           progress=False, error_limit_kgf=5000.0, pacing=PacingOptions(mode))
            assert res.end_reason is None, res.end_message
            out[mode] = res.summary()
    # dynamic, as a user runs it
    ctl = tmp_path / "c.toml"
    ctl.write_text(controller.to_toml())
    seq = tmp_path / "tp.csv"
    seq.write_text("level\n" + "\n".join(repr(float(v)) for v in levels) + "\n")
    capsys.readouterr()
    rc = stand(["load", str(seq), "--rate", "5000", "--controller", str(ctl), "--out", str(tmp_path / "dynamic"),
                "--lockstep", "--bus", bus_spec, "--no-progress", "--json", "--pacing", "dynamic"])
    assert rc == 0, capsys.readouterr().err
    out["dynamic"] = json.loads(capsys.readouterr().out)
    tolerance = 0.5                                     # % of the range: the pacing tolerance's default
    off = out["off"]
    assert off["peak_valley_error_pct"]["max"] > 4 * tolerance and off["pacing_s"] == 0.0
    for mode in ("static", "dynamic"):
        s = out[mode]
        assert s["peak_valley_error_pct"]["max"] <= tolerance, (mode, s["peak_valley_error_pct"])
        assert s["extra_cycles"] == 0 and s["pacing"]["waits"] >= 3 and s["pacing_s"] > 1.0, s["pacing"]
        assert s["programme_time_s"] == pytest.approx(off["programme_time_s"])
        assert s["minimum_time_s"] == pytest.approx(off["minimum_time_s"]) and s["minimum_time_s"] > 0
    assert out["dynamic"]["pacing"]["slowed_s"] > 0 and out["static"]["pacing"]["slowed_s"] == 0
    meta = json.loads((tmp_path / "dynamic" / "pass-1" / "run.json").read_text())
    assert meta["experiment"]["params"]["pacing"] == "dynamic"
    assert "pacing" in (tmp_path / "dynamic" / "report.txt").read_text()


def closed_loop(truth: PlantModel, e: LoadProgramme, steps: int | None = None) -> list[float]:
    """Run ``e`` against ``truth`` offline (no noise); the forces read."""
    plant_ = LockstepPlant(truth, 0.0, 0.0005)
    begin, finished, step, _aborted = stepper(e, T, 10000.0)
    y, t, ys = 0.0, 0.0, []
    begin(y)
    while not finished(t, y) and (steps is None or len(ys) < steps):
        u, _ = step(t, y)
        if e.abort:
            break
        y = plant_.step(T, u)
        ys.append(y)
        t += T
    return ys


def test_the_clock_runs_sample_for_sample_while_the_force_follows():
    model = PlantModel.from_spec("base+reversal", MODEL)
    p = from_levels(random_sequence(8, 400, 6200, seed=2), T, rate_kgf_s=2500)
    paced = LoadProgramme(p, design(model, T), pacing=PacingOptions("dynamic"))
    closed_loop(model, paced)
    assert paced.clock.record.pacing_s == 0.0 and paced.clock.record.waits == 0
    assert np.array_equal(paced.positions, np.arange(len(paced.positions)))
    assert len(paced.positions) == paced.reference.shape[1]


def test_a_level_the_stand_cannot_reach_stops_the_pass_after_the_timeout():
    model = PlantModel.from_spec("base+reversal", MODEL)
    # a stand whose force cannot pass 3000 kgf (a leak of 20 %/s of the force against 5 % of flow)
    truth = PlantModel.from_spec("base+reversal+saturation+leakage",
                                 {**MODEL, "saturation.limit": 5.0, "leakage.rate": 0.2})
    p = from_levels([200.0, 5000.0, 1000.0], T, rate_kgf_s=2500)
    e = LoadProgramme(p, design(model, T), pacing=PacingOptions("static", timeout_s=1.0))
    ys = closed_loop(truth, e)
    assert e.abort is not None and e.abort[0] == "pacing_timeout", e.abort
    assert "did not reach the turning point 5000 kgf" in e.abort[1] and max(ys) < 3100
    assert e.clock.record.waits == 1 and e.clock.waited_too_long()


def test_the_gate_sits_a_delay_before_its_turning_point_and_never_before_the_last_one():
    r = np.r_[np.linspace(0, 1000, 101), np.linspace(990, 900, 10), np.linspace(910, 2000, 100)]
    turnings = np.array([100, 110])
    clock = ProgrammeClock(r[None, :], turnings, [25], [120.0], T, PacingOptions("static"), [20.0])
    assert [g.position for g in clock.gates] == [75, 101]
    assert [g.way for g in clock.gates] == [1.0, -1.0]
    for bad, match in ((PacingOptions("sometimes"), "choose one of off, static, dynamic"),
                       (PacingOptions("dynamic", min_speed=0.0), "min speed"),
                       (PacingOptions("static", tolerance_kgf=-1.0), "tolerance")):
        with pytest.raises(Exception, match=match):
            bad.check()


def test_the_command_line_offers_the_pacing_modes_the_clock_knows():
    from loading.pacing import PACING_MODES
    from stand.commands.load import PACING_MODES as offered
    assert offered == PACING_MODES
