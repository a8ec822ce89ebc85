"""stand fit / compare / report / effects: the command line and the HTML history."""
from __future__ import annotations

import json
import re

import pytest

from analysis import compare, load_history, write_csv, write_report
from analysis.records import synthetic as S
from plant import CATALOGUE, PlantModel, load_model_file
from stand.cli import main
from tests.support.stand import BASE

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def reversal_csv(tmp_path_factory):
    truth = PlantModel.from_spec("base+reversal", BASE)
    path = tmp_path_factory.mktemp("data") / "meander.csv"
    write_csv(S.meander(truth, (5.0, 10.0, 20.0), period_s=2.0, cycles=2, seed=1), path)
    return path


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_fit_json_schema_and_saved_model_file_round_trip(reversal_csv, tmp_path, capsys):
    saved = tmp_path / "fitted.toml"
    code, out, _ = run_cli(capsys, "fit", reversal_csv, "--model", "base+reversal", "--json", "--save", saved)
    assert code == 0
    doc = json.loads(out)
    assert doc["model"] == "base+reversal"
    assert doc["params"]["g"] == pytest.approx(120.0, rel=0.01)
    assert {"rmse", "fit_percent", "noise_floor_rmse", "n_windows"} <= set(doc["metrics"])
    assert doc["intervals"]["reversal.boost"]["ci_low"] < 2.0 < doc["intervals"]["reversal.boost"]["ci_high"]
    back = load_model_file(saved)
    assert back.spec == "base+reversal" and back.params() == pytest.approx(doc["params"])
    # a model file is a start: fitting it again changes nothing
    code, out, _ = run_cli(capsys, "fit", reversal_csv, "--model", saved, "--json")
    assert json.loads(out)["params"]["g"] == pytest.approx(doc["params"]["g"], rel=1e-4)


def test_fit_prints_a_table_with_intervals(reversal_csv, capsys):
    code, out, _ = run_cli(capsys, "fit", reversal_csv, "--model", "base", "--fix", "tau")
    assert code == 0
    assert re.search(r"^g\s+[\d.]+\s+\[[\d.]+, [\d.]+\]", out, re.M)
    assert re.search(r"^tau\s+0\.05\s+fixed", out, re.M)
    assert "windowed free-run error" in out and "RMSE" in out and "worst windows" in out


def test_compare_writes_plots_and_a_regime_table(reversal_csv, tmp_path, capsys):
    code, out, _ = run_cli(capsys, "compare", reversal_csv, "--model", "base", "--out", tmp_path / "cmp")
    assert code == 0
    for name in ("overlay.png", "regimes.png", "correlations.png"):
        assert (tmp_path / "cmp" / name).read_bytes()[:8] == PNG
    assert "[reversal]" in out and "first 0.2 s after a reversal" in out and "retract (u < 0)" in out
    assert "residual whiteness: NOT white" in out


def test_compare_as_given_uses_the_file_values(reversal_csv, tmp_path, capsys):
    model_file = tmp_path / "m.toml"
    model_file.write_text('model = "base"\n[base]\ng = 100.0\ntau = 0.05\ndelta = 0.0\n')
    code, out, _ = run_cli(capsys, "compare", reversal_csv, "--model", model_file, "--as-given",
                           "--no-plots", "--json")
    doc = json.loads(out)
    assert code == 0 and doc["params"]["g"] == 100.0 and doc["fitted"] is False
    assert {"regimes", "windows", "whiteness", "input_correlation"} <= set(doc)
    assert doc["whiteness"]["band"] == pytest.approx(1.96 / doc["whiteness"]["n"] ** 0.5)


@pytest.mark.slow
def test_report_keeps_the_history_and_the_error_falls(reversal_csv, tmp_path, capsys):
    out_dir = tmp_path / "rep"
    for spec in ("base", "base+lag", "base+reversal"):
        code, out, _ = run_cli(capsys, "report", reversal_csv, "--model", spec, "--out", out_dir)
        assert code == 0
    history = load_history(out_dir)
    versions = history["versions"]
    assert [v["model"] for v in versions] == ["base", "base+lag", "base+reversal"]
    rmse = [v["metrics"]["rmse"] for v in versions]
    assert rmse[2] < 0.1 * rmse[0]
    # the same model again refreshes the latest version instead of adding one
    run_cli(capsys, "report", reversal_csv, "--model", "base+reversal", "--out", out_dir)
    assert len(load_history(out_dir)["versions"]) == 3
    page = (out_dir / "report.html").read_text()
    assert "v3" in page and "base+reversal" in page and "Error of each model version" in page
    assert page.count("data:image/png;base64,") >= 4
    # self-contained: no reference to anything outside the page
    assert not re.search(r"(src|href)=[\"'](?!data:)", page)
    assert "http://" not in page and "https://" not in page


@pytest.mark.slow
def test_report_refuses_another_data_set_unless_told(reversal_csv, tmp_path, capsys):
    out_dir = tmp_path / "rep"
    run_cli(capsys, "report", reversal_csv, "--model", "base", "--out", out_dir)
    other = tmp_path / "other.csv"
    write_csv(S.meander(PlantModel.from_spec("base", BASE), (10.0,), cycles=2, seed=3), other)
    code, _, err = run_cli(capsys, "report", other, "--model", "base", "--out", out_dir)
    assert code == 2 and "another data set" in err and "Traceback" not in err
    code, _, _ = run_cli(capsys, "report", other, "--model", "base", "--out", out_dir, "--new-history")
    assert code == 0 and len(load_history(out_dir)["versions"]) == 1


@pytest.mark.slow
def test_report_with_diagnosis_of_the_latest_model(reversal_csv, tmp_path):
    from analysis import diagnose, read_csv
    recs = [read_csv(reversal_csv)]
    d = diagnose(recs, "base")
    res = write_report(recs, "base", tmp_path / "r", diagnosis=d)
    page = res.path.read_text()
    assert "still misses" in page and "missing_effect" in page and "+reversal" in page


def test_effects_lists_the_catalogue_with_units_and_bounds(capsys):
    code, out, _ = run_cli(capsys, "effects")
    assert code == 0
    for name, cls in CATALOGUE.items():
        assert f"{name}: " in out
        for p in cls.params:
            assert f"{name}.{p.name}" in out
    assert "oscillation" in out and "not offered by `stand diagnose`" in out
    code, out, _ = run_cli(capsys, "effects", "--json")
    rows = json.loads(out)
    assert rows[0]["effect"] == "base"
    lag = next(r for r in rows if r["effect"] == "lag")
    assert lag["params"][0] == {"name": "time_constant", "default": 0.03, "lower": 1e-4, "upper": 2.0,
                                "unit": "s", "doc": lag["params"][0]["doc"], "log": True}
    assert "math::" in lag["doc"]


def test_user_errors_are_one_line(reversal_csv, tmp_path, capsys):
    code, _, err = run_cli(capsys, "fit", reversal_csv, "--model", "base+friction")
    assert code == 2 and "unknown effect 'friction'" in err and "Traceback" not in err
    code, _, err = run_cli(capsys, "diagnose", tmp_path / "missing.csv")
    assert code == 2 and "does not exist" in err
    code, _, err = run_cli(capsys, "fit", reversal_csv, "--model", tmp_path / "nope.toml")
    assert code == 2 and "does not exist" in err
    code, _, err = run_cli(capsys, "compare", reversal_csv, "--model", "base", "--window-s", "0")
    assert code == 2 and "--window-s" in err


@pytest.mark.slow
def test_diagnose_command_prints_verdict_table_and_words(reversal_csv, tmp_path, capsys):
    code, out, _ = run_cli(capsys, "diagnose", reversal_csv, "--no-progress", "--plots", tmp_path / "dg")
    assert code == 0
    assert out.startswith("verdict: MISSING_EFFECT")
    assert re.search(r"^\+reversal\s+[\d.]+\s+-\d+\.\d%\s+\d+%\s+yes\s+<- best", out, re.M)
    assert "what the residual of base shows" in out
    assert (tmp_path / "dg" / "candidates.png").read_bytes()[:8] == PNG


def test_compare_library_call_matches_the_fit(reversal_csv):
    from analysis import read_csv
    c = compare([read_csv(reversal_csv)], "base+reversal")
    assert c.fit is not None and c.metrics()["rmse"] < 1.2 * c.metrics()["noise_floor_rmse"]
