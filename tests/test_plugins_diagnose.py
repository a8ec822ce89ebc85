"""A plug-in found by the diagnosis as the catalogue's effects are: from its default grid (its
frequency where the residual is periodic, read where the effect acts), with the same rules;
the worked example of docs/your-own-effect.md, run as written; the emulator running it and
the diagnosis finding it back in a recorded run."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from analysis import diagnose, write_csv
from analysis.records.synthetic import meander
from plant import PlantModel, plugins
from plant.params import Param
from plant.start_grids import GENERIC_LIMIT, generic_starts
from tests.support.plugins import RIPPLE
from tests.support.records import independent_records

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "your-own-effect.md"


def docs_plugin() -> str:
    """The plug-in of docs/your-own-effect.md, as the page shows it."""
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(), re.S)
    assert len(blocks) == 1, "the page shows one plug-in"
    return blocks[0]


pytestmark = pytest.mark.usefixtures("isolated_catalogue")


def stand(*args: str, cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "stand", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd)


def test_a_default_grid_starts_a_frequency_where_the_residual_is_periodic():
    params = (Param("gain", 0.1, 0.0, 0.9, "1", "a"),
              Param("frequency", 1.0, 0.1, 50.0, "Hz", "f", log=True),
              Param("omega", 10.0, 1.0, 300.0, "rad/s", "ω", log=True),
              Param("amplitude", 20.0, 0.0, 500.0, "kgf", "A"))
    asked = []
    s = SimpleNamespace(residual_periodic=lambda carrier: asked.append(carrier) or SimpleNamespace(
        frequency_hz=3.02, amplitude_kgf=31.0))
    from plant import Stage
    starts = generic_starts("x", params, s, Stage.FLOW)
    assert starts[0] == {"x.gain": 0.1, "x.frequency": 3.02, "x.omega": pytest.approx(2 * 3.14159265 * 3.02),
                         "x.amplitude": 31.0}
    assert asked == ["flow", "force"]        # the frequency read as a gain's, the amplitude as a force's
    assert len(starts) <= GENERIC_LIMIT and len({json.dumps(c, sort_keys=True) for c in starts}) == len(starts)
    # without a summary: the defaults first, then values across the bounds (log-spaced)
    plain = generic_starts("x", params[1:2])
    assert [c["x.frequency"] for c in plain] == pytest.approx([1.0, 0.4729, 2.2361, 10.5737], rel=1e-3)


def test_a_disturbance_plugin_is_diagnosed_from_a_default_three_times_off(tmp_path):
    f = tmp_path / "ripple.py"
    f.write_text(RIPPLE)
    plugins.load_plugins([f])
    truth = PlantModel.from_spec("base+ripple", {"g": 120.0, "tau": 0.05, "delta": 8.0,
                                                  "ripple.amplitude": 30.0, "ripple.frequency": 3.0,
                                                  "ripple.phase": 0.7})
    d = diagnose([meander(truth, (5.0, 20.0), seed=3)])
    assert d.verdict == "missing_effect" and d.best == "ripple", d.summary
    p = d.best_candidate.params
    assert p["ripple.frequency"] == pytest.approx(3.0, rel=0.02)
    assert p["ripple.amplitude"] == pytest.approx(30.0, rel=0.02)
    assert d.best_candidate.rmse <= 0.3 * d.base_eval.rmse


@pytest.mark.slow
def test_the_worked_example_of_the_docs_runs_as_written(tmp_path):
    """docs/your-own-effect.md: the diagnosis stuck, then the page's plug-in named, within 2 %
    of the simulator's law, its model file reloading on its own, the report's error falling to
    the noise floor."""
    for rec in independent_records("supripple", 20240601 + 99, fixed_phase=0.4):
        write_csv(rec, tmp_path / f"{rec.source}.csv")
    data = sorted(str(p.name) for p in tmp_path.glob("*.csv"))
    (tmp_path / "supply_ripple.py").write_text(docs_plugin())

    before = stand("diagnose", *data, "--json", "--no-progress", cwd=tmp_path)
    assert before.returncode == 0, before.stderr
    b = json.loads(before.stdout)
    assert b["verdict"] == "unexplained"
    assert b["unexplained"]["gain_frequency_hz"] == pytest.approx(3.0, abs=0.02)
    assert any("--stage flow" in o and "--effects" in o for o in b["observations"])

    after = stand("diagnose", *data, "--effects", "supply_ripple.py", "--save", "model.toml",
                  "--json", "--no-progress", cwd=tmp_path)
    assert after.returncode == 0, after.stderr
    a = json.loads(after.stdout)
    assert a["verdict"] == "missing_effect" and a["best"] == "supply_ripple", a["summary"]
    best = next(c for c in a["candidates"] if c["effect"] == "supply_ripple")
    assert best["params"]["supply_ripple.ratio"] == pytest.approx(0.15, rel=0.02)
    assert best["params"]["supply_ripple.frequency"] == pytest.approx(3.0, rel=0.02)
    assert best["rmse"] <= 0.3 * a["base"]["rmse"]
    assert 'plugins = ["supply_ripple.py"]' in (tmp_path / "model.toml").read_text()

    for model in ("base", "model.toml"):      # the model file needs no --effects
        res = stand("report", *data, "--model", model, "--out", "report", cwd=tmp_path)
        assert res.returncode == 0, res.stderr
    versions = json.loads((tmp_path / "report" / "history.json").read_text())["versions"]
    assert [v["model"] for v in versions] == ["base", "base+supply_ripple"]
    m0, m1 = versions[0]["metrics"], versions[1]["metrics"]
    assert m1["rmse"] <= 0.3 * m0["rmse"] and m1["rmse"] <= 1.1 * m1["noise_floor_rmse"], (m0, m1)


@pytest.mark.slow
@pytest.mark.e2e
def test_the_emulator_runs_a_plugin_and_the_diagnosis_finds_it_back(tmp_path, bus_spec):
    (tmp_path / "supply_ripple.py").write_text(docs_plugin())
    emu = subprocess.Popen([sys.executable, "-m", "stand", "emulate", "--bus", bus_spec, "--lockstep",
                            "--seed", "4", "--effects", "supply_ripple.py",
                            "--model", "base+reversal+supply_ripple", "--set", "supply_ripple.ratio=0.15",
                            "--set", "supply_ripple.frequency=3"],
                           cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert "emulator ready" in emu.stdout.readline()
        for amp in ("5", "10", "20"):
            res = stand("run", "meander", "--bus", bus_spec, "--lockstep", "--amplitude-pct", amp,
                        "--cycles", "4", "--out", f"m{amp}", cwd=tmp_path, timeout=120)
            assert res.returncode == 0, res.stderr
    finally:
        emu.terminate()
        emu.wait(10)
    res = stand("diagnose", "m5", "m10", "m20", "--model", "base+reversal", "--effects",
                "supply_ripple.py", "--json", "--no-progress", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    d = json.loads(res.stdout)
    assert d["verdict"] == "missing_effect" and d["best"] == "supply_ripple", d["summary"]
    p = next(c for c in d["candidates"] if c["effect"] == "supply_ripple")["params"]
    assert p["supply_ripple.ratio"] == pytest.approx(0.15, rel=0.02)
    assert p["supply_ripple.frequency"] == pytest.approx(3.0, rel=0.02)
