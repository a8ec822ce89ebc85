"""stand diagnose --stepwise: data that miss several effects at once, built up one effect at a
time (our plant model, and the independent simulator of tests/support/independent_stand.py)."""
from __future__ import annotations

import json

import pytest

from analysis import diagnosable_effects, diagnose, stepwise, write_csv
from plant import PlantModel, load_model_file
from stand.cli import main
from tests.support import independent_stand as sim
from tests.support.records import independent_records as independent
from tests.support.records import held_at_limit, meander4, pfeedback, relay
from tests.support.stand import BASE

THREE = {"reversal.boost": 1.5, "reversal.decay": 0.1, "leakage.rate": 0.2, "backlash.width": 2.0}


def campaign(truth: PlantModel, seed: int) -> list:
    """Meanders at four amplitudes, relay at three references, P-feedback at two frequencies."""
    return [meander4(truth, seed=seed), relay(truth, seed=seed), pfeedback(truth, seed=seed)]


@pytest.mark.slow
def test_three_effects_no_single_one_explains_are_found_one_after_another():
    truth = PlantModel.from_spec("base+reversal+leakage+backlash", {**BASE, **THREE})
    r = stepwise(campaign(truth, seed=5))
    # alone, no effect explains it: the plain diagnosis calls it unexplained, or names the
    # effect that removes most of the excess (here `unloading`: faster toward zero force, like
    # the leak) and says the error is still many times the floor
    d0 = r.steps[0].diagnosis
    assert d0.verdict == "unexplained" or any("still" in w for w in d0.warnings), d0.summary
    assert r.verdict == "adequate", r.summary
    assert {e.name for e in r.model.effects} == {"reversal", "leakage", "backlash"}
    for name, want in {**BASE, **THREE}.items():
        if name != "reversal.exponent":
            assert r.model.params()[name] == pytest.approx(want, rel=0.05, abs=0.005), name
    rmse = [s.rmse for s in r.steps]
    assert all(b < a for a, b in zip(rmse, rmse[1:])), rmse          # the error falls each step
    assert r.steps[-1].over_floor < 1.1
    assert r.steps[0].why.startswith(("part of the missing behaviour", "earns its parameters"))
    # each true effect is needed; one picked on the way (here unloading, for the leak it
    # partly mimics) is dropped by the backward check
    true = {"reversal", "leakage", "backlash"}
    assert all(n.kept and n.factor > 2 for n in r.needed if n.effect in true), r.needed
    assert {n.effect for n in r.needed if n.kept} == true, r.needed


@pytest.mark.slow
def test_an_effect_picked_early_is_dropped_once_the_real_ones_are_in():
    """Independent simulator, dead zone + asymmetry + leakage: the load-pressure law explains
    most of the first residual, then leakage, dead zone and asymmetry take over and the
    backward check drops it."""
    r = stepwise(independent("deadzone+asymmetry+leakage", 1001))
    assert r.verdict == "adequate", r.summary
    assert {e.name for e in r.model.effects} == {"deadzone", "asymmetry", "leakage"}, r.summary
    p = r.model.params()
    assert p["deadzone.width"] == pytest.approx(1.0, rel=0.05)
    assert p["leakage.rate"] == pytest.approx(0.1, rel=0.05)
    # the simulator's retract gain 0.8 is (1 - a)/(1 + a) in the catalogue's form
    assert (1 - p["asymmetry.ratio"]) / (1 + p["asymmetry.ratio"]) == pytest.approx(0.8, abs=0.01)
    gone = [n for n in r.needed if not n.kept]
    if gone:   # picked first and dropped again (the path depends on the noise draw)
        assert [n.effect for n in gone] == ["load_pressure"] and "dropped" in gone[0].text()


@pytest.mark.slow
def test_a_sensor_filter_behind_a_flow_limit_is_not_a_valve_lag():
    """Independent simulator, 12 % flow limit + 10 ms dynamometer filter: a valve lag sits before
    the limit and cannot mimic it; the sensor lag is found, with its time constant."""
    r = stepwise(independent("saturation+sensorlag", 1004))
    assert r.verdict == "adequate" and r.model.spec == "base+saturation+sensor_lag", r.summary
    p = r.model.params()
    assert p["sensor_lag.time_constant"] == pytest.approx(0.010, rel=0.15)
    assert p["saturation.limit"] == pytest.approx(12.0, rel=0.02)


@pytest.mark.slow
def test_a_dead_zone_is_found_after_a_flow_curve_that_took_part_of_it():
    """Independent simulator, dead zone 1 % then a power-law flow 0.8: the flow curve alone
    fits p = 0.88 and holds part of the dead zone's error, so the dead zone's best start is
    "off" (the model as it was); found once a start with it on is polished too.

    A sagging supply settles at a static gain √(1 − k·|u|/100), a degressive flow curve of its
    own, and on these meanders (|u| held for seconds) it fits the pair to the floor as well:
    the data cannot tell, and the diagnosis says so. The stepwise path is checked without it."""
    recs = independent("deadzone+flownl", 5002)
    d = diagnose(recs)
    assert d.best == "supply" and any(set(a.effects) == {"supply", "flow_curve"}
                                      for a in d.ambiguities), (d.summary, d.ambiguities)
    r = stepwise(recs, effects=[e for e in diagnosable_effects(PlantModel.from_spec("base")) if e != "supply"])
    assert r.verdict == "adequate" and r.model.spec == "base+deadzone+flow_curve", r.summary
    p = r.model.params()
    assert p["deadzone.width"] == pytest.approx(1.0, rel=0.03)
    assert p["flow_curve.exponent"] == pytest.approx(0.8, abs=0.01)


@pytest.mark.slow
def test_what_the_catalogue_cannot_explain_stays_unexplained_after_what_it_can():
    r = stepwise(independent("osc+asymmetry", 1005))
    assert r.verdict == "unexplained" and r.model.spec == "base+asymmetry", r.summary
    assert r.last.unexplained.dominant_frequency_hz == pytest.approx(3.0, abs=0.05)


def test_nothing_missing_is_one_step():
    r = stepwise(independent("none", 1006))
    assert r.verdict == "adequate" and r.model.spec == "base" and len(r.steps) == 1


@pytest.mark.slow
def test_cli_stepwise_json_plot_and_saved_model(tmp_path, capsys):
    truth = PlantModel.from_spec("base+reversal+deadzone",
                                 {**BASE, "reversal.boost": 2.0, "reversal.decay": 0.15,
                                  "deadzone.width": 1.5})
    paths = []
    for i, rec in enumerate(campaign(truth, seed=7)[:2]):
        paths.append(tmp_path / f"run{i}.csv")
        write_csv(rec, paths[-1])
    saved = tmp_path / "found.toml"
    code = main(["diagnose", *map(str, paths), "--stepwise", "--json", "--no-progress",
                 "--save", str(saved), "--plots", str(tmp_path / "pl"), "--report", str(tmp_path / "rep")])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["verdict"] == "adequate"
    assert [s["added"] for s in out["steps"]] == ["reversal", "deadzone", None]
    assert out["steps"][0]["diagnosis"]["verdict"] == "missing_effect"
    model = load_model_file(saved)
    assert model.spec == out["model"] and model.params()["deadzone.width"] == pytest.approx(1.5, rel=0.05)
    assert (tmp_path / "pl" / "stepwise.png").read_bytes()[:4] == b"\x89PNG"
    # the report keeps every step as a version: the error falling as effects are added
    history = json.loads((tmp_path / "rep" / "history.json").read_text())
    assert [v["model"] for v in history["versions"]] == [s["model"] for s in out["steps"]]
    rmse = [v["metrics"]["rmse"] for v in history["versions"]]
    assert rmse == sorted(rmse, reverse=True) and "<img" in (tmp_path / "rep" / "report.html").read_text()
    code = main(["diagnose", *map(str, paths), "--stepwise", "--no-progress", "--max-effects", "1"])
    text = capsys.readouterr().out
    assert code == 0 and text.startswith("verdict: MAX_EFFECTS")
    assert "stopped after 1 added effects (--max-effects); next: deadzone" in text


@pytest.mark.slow
def test_a_force_held_at_a_relief_valve_is_left_out_and_the_real_effects_found():
    """Independent simulator: a valve lag and an asymmetry, and a relief valve holding the force
    at 1500 kgf while the meanders at 10 to 20 % push on, some of the holds beginning less than
    0.1 s before the command turns. Before, the limit became a direction-dependent delay and a
    load-pressure law and the build-up ended unexplained; then, with the long holds left out,
    the short ones still bent the fit (load_pressure first, unexplained at 7.7x the floor); now
    every hold is left out (said in the notes) and lag and asymmetry are found alone, with the
    simulator's values (seeds 11 and 23 too: docs/benchmarks.md)."""
    recs = independent("lag+asymmetry+forcelimit", 7)
    held = [n for r in recs for n in r.notes if "hydraulic limit" in n]
    assert all("1500 kgf" in n or "1499 kgf" in n or "1501 kgf" in n for n in held), held
    # every meander's hold is found, the short ones before a turn too (4 at 10 %, 5 at 15 %)
    assert [sum("hydraulic limit" in n for n in r.notes) for r in recs[:4]] == [1, 4, 5, 5]
    r = stepwise(recs)
    assert r.verdict == "adequate", r.summary
    assert {e.name for e in r.model.effects} <= {"lag", "sensor_lag", "asymmetry"}, r.model.spec
    assert "asymmetry" in {e.name for e in r.model.effects}
    p = r.model.params()
    lag = p.get("lag.time_constant", p.get("sensor_lag.time_constant"))
    assert lag == pytest.approx(sim.EFFECT_PARAMS["lag"]["T"], rel=0.15)
    # retract at 0.8 of extend: (1 + a)/(1 − a) = 1/0.8, a = 0.2/1.8 about the mean gain
    assert p["asymmetry.ratio"] == pytest.approx(0.2 / 1.8, abs=0.01)
    assert p["tau"] == pytest.approx(sim.DEFAULTS["tau"], abs=0.002)


@pytest.mark.slow
def test_a_dead_zone_beside_a_relief_valve_is_found_with_its_width():
    """Another real effect beside the limit: a 1 % dead zone (independent simulator, seed 7).
    Before the short holds were found (one of three stayed in) this ended unexplained at 4.6x
    the floor, with Δ at 3.3 kgf/s for 6."""
    recs = independent("deadzone+forcelimit", 7)
    assert sum("hydraulic limit" in n for r in recs for n in r.notes) == 3
    r = stepwise(recs)
    assert r.verdict == "adequate" and r.model.spec == "base+deadzone", r.summary
    p = r.model.params()
    assert p["deadzone.width"] == pytest.approx(sim.EFFECT_PARAMS["deadzone"]["d"], abs=0.02)
    assert p["delta"] == pytest.approx(sim.DEFAULTS["delta"], abs=0.5)
    assert p["tau"] == pytest.approx(sim.DEFAULTS["tau"], abs=0.002)


@pytest.mark.slow
def test_a_lag_beside_an_asymmetry_held_at_a_relief_valve_is_named_not_a_resonance():
    """The emulator's default plant (base + reversal) with a 0.1 s valve lag and an asymmetry,
    meanders at 10-20 % whose force a relief valve holds at 1500 kgf, 96 s (screened on a
    subset of windows). The lag and an overdamped resonance leave the same error; ranked by
    BIC the resonance (10.7 Hz, ζ 3.43) was added in the lag's place (2.0063 vs 2.0067 kgf).
    Ties go to the simpler law: the lag, with the resonance named as its equivalent. The
    candidates are the lag's and the asymmetry's look-alikes (the whole catalogue takes the
    same path, in minutes)."""
    truth = PlantModel.from_spec("base+reversal+lag+asymmetry", {
        **BASE, "reversal.boost": 2.0, "reversal.decay": 0.15, "lag.time_constant": 0.1,
        "asymmetry.ratio": 0.1})
    recs = held_at_limit(truth, (10.0, 15.0, 20.0), 1500.0, cycles=8, seed=3)
    assert all(any("hydraulic limit" in n for n in r.notes) for r in recs)
    r = stepwise(recs, "base+reversal",
                 effects=["lag", "resonance", "sensor_lag", "asymmetry", "unloading"])
    assert r.verdict == "adequate", r.summary
    assert {e.name for e in r.model.effects} == {"reversal", "lag", "asymmetry"}, r.summary
    p = r.model.params()
    assert p["lag.time_constant"] == pytest.approx(0.1, rel=0.05)
    assert p["asymmetry.ratio"] == pytest.approx(0.1, abs=0.005)
    step = next(st for st in r.steps if st.added == "lag")
    assert step.diagnosis.best_candidate.equivalents == ["resonance"]
    assert "+resonance leaves as little error with more parameters" in step.why, step.why


def test_look_alikes_go_both_ways():
    from plant.catalogue import CATALOGUE, look_alikes
    for name, cls in CATALOGUE.items():
        if cls.diagnosable:
            assert all(name in look_alikes(other) for other in look_alikes(name)), name
    assert set(look_alikes("resonance")) == {"lag", "sensor_lag"}
    assert "resonance" in look_alikes("sensor_lag")      # named by the resonance only


def test_a_resonance_is_its_own_evidence_only_when_it_rings():
    from plant.catalogue import CATALOGUE
    own, why = CATALOGUE["resonance"].own_evidence({"resonance.frequency": 20.5,
                                                    "resonance.damping": 3.0})
    assert not own and "overdamped" in why and "46.6 ms" in why      # 2ζ/ω = 6/(2π·20.5)
    own, why = CATALOGUE["resonance"].own_evidence({"resonance.frequency": 6.0,
                                                    "resonance.damping": 0.2})
    assert own and "it rings" in why and "53 % overshoot" in why
    assert CATALOGUE["lag"].own_evidence({"lag.time_constant": 0.03}) == (True, "")


def test_an_overdamped_resonance_is_swapped_for_the_sensor_lag_it_stands_in_for():
    """The issue's first pair on our model: a dynamometer filter of 40 ms behind the reversal
    boost, with an overdamped resonance fitted in its place (the greedy build-up's choice).
    Revised, the resonance is tried in place of its look-alikes: the sensor lag explains more
    with a parameter fewer and replaces it; a valve lag (before the boost) leaves more."""
    from analysis import fit_model
    from analysis.diagnosis.revision import revise
    from analysis.diagnosis.verdict import Windows, objective_floor
    from analysis.identification.metrics import evaluate
    from analysis.records import synthetic as S
    truth = PlantModel.from_spec("base+reversal+sensor_lag", {
        **BASE, "reversal.boost": 2.0, "reversal.decay": 0.15, "sensor_lag.time_constant": 0.04})
    recs = [S.meander(truth, (5.0, 20.0), period_s=4.0, cycles=2, seed=3)]
    w = Windows.of(recs, 2.0, 150)
    values = {k: v for k, v in truth.params().items() if not k.startswith("sensor_lag")}
    wrong = fit_model(w.full, PlantModel.from_spec("base+reversal+resonance", {
        **values, "resonance.frequency": 20.0, "resonance.damping": 3.0}))
    assert wrong.model.params()["resonance.damping"] > 1          # the stand-in: overdamped
    floor = objective_floor(w.full, evaluate(wrong.model, recs, 2.0).noise_sigma)
    r = revise(wrong, ["resonance"], w.full, w.screen, floor, jobs=1)
    assert r.fit.model.spec == "base+reversal+sensor_lag", r.text
    assert [a.change for a in r.kept] == ["+sensor_lag in place of +resonance"]
    assert "with 1 parameter fewer" in r.kept[0].why
    assert r.fit.model.params()["sensor_lag.time_constant"] == pytest.approx(0.04, rel=0.05)
    lag = next(a for a in r.rejected if a.added == "lag")
    assert lag.objective_rmse > r.kept[0].objective_rmse, lag
