"""Effects as plug-ins: loaded from a file, a directory, a module or an installed package,
checked before anything runs, named in model and controller files, listed and started by
`stand effects`, run by the emulator."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from plant import PlantModel, model_to_toml, plugins
from plant.catalogue import BUILTINS, CATALOGUE
from plant.plugins import PluginError, load_plugins
from plant.skeleton import skeleton
from tests.support.plugins import RIPPLE

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.usefixtures("isolated_catalogue")


def stand(*args: str, cwd: Path | None = None, env: dict | None = None,
          timeout: float = 120) -> subprocess.CompletedProcess:
    import os
    return subprocess.run([sys.executable, "-m", "stand", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd, env={**os.environ, **(env or {})})


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


# ------------------------------------------------------------------------------------------
# loading
# ------------------------------------------------------------------------------------------
def test_a_plugin_file_joins_the_catalogue_with_its_origin(tmp_path):
    f = write(tmp_path / "ripple.py", RIPPLE)
    assert load_plugins([f]) == ["ripple"]
    assert "ripple" in CATALOGUE and plugins.origin("ripple") == f"file {f.resolve()}"
    m = PlantModel.from_spec("base+ripple", {"ripple.frequency": 3.0, "ripple.amplitude": 30.0})
    y = m.simulate(np.zeros(500), 0.002)
    # a disturbance alone: the force is A·(sin(2πft) − sin(0)), exactly
    t = np.arange(500) * 0.002
    assert np.allclose(y, 30.0 * np.sin(2 * np.pi * 3.0 * t), atol=1e-9)
    assert load_plugins([f]) == ["ripple"]          # loading it again changes nothing


def test_a_directory_and_a_module_name_are_sources_too(tmp_path, monkeypatch):
    d = tmp_path / "effects"
    d.mkdir()
    write(d / "ripple.py", RIPPLE)
    write(d / "_helpers.py", "raise RuntimeError('not a plug-in: starts with _')\n")
    write(d / "soft.py", skeleton("soft_valve", "valve"))
    assert sorted(load_plugins([d])) == ["ripple", "soft_valve"]
    pkg = tmp_path / "mypkg"
    pkg.mkdir()
    write(pkg / "__init__.py", "")
    write(pkg / "effects.py", skeleton("my_gain", "flow"))
    monkeypatch.syspath_prepend(str(tmp_path))
    assert load_plugins(["mypkg.effects"]) == ["my_gain"]
    assert plugins.origin("my_gain") == "module mypkg.effects"


@pytest.mark.parametrize("stage", ["valve", "flow", "disturbance", "force", "sensor"])
def test_every_stage_s_skeleton_is_a_working_effect(tmp_path, stage):
    f = write(tmp_path / f"my_{stage}.py", skeleton(f"my_{stage}", stage))
    assert load_plugins([f]) == [f"my_{stage}"]
    m = PlantModel.from_spec(f"base+my_{stage}")
    u = np.where(np.arange(2000) % 500 < 250, 10.0, -10.0)
    y = m.simulate(u, 0.002)
    assert np.all(np.isfinite(y)) and np.ptp(y) > 100     # it moves, it is finite
    assert not np.allclose(y, PlantModel.from_spec("base").simulate(u, 0.002))  # it acts


# ------------------------------------------------------------------------------------------
# the check on load: one clear error, nothing registered
# ------------------------------------------------------------------------------------------
BROKEN = {
    "syntax": ("class Oops(:\n", "syntax error at line 1"),
    "import": ("import no_such_module_here\n", "cannot import it: No module named 'no_such_module_here'"),
    "clash": (RIPPLE.replace('name = "ripple"', 'name = "lag"'), "effect name 'lag'"),
    "shape": (RIPPLE.replace("w = 2 * np.pi * self.frequency\n",
                             "return self.amplitude * np.ones(t.shape[1])\n"),
              "returned shape (400,), expected (2, 400)"),
    "nan": (RIPPLE.replace("return self.amplitude *", "return np.nan + self.amplitude *"),
            "non-finite value"),
    "raises": (RIPPLE.replace("w = 2 * np.pi * self.frequency", "w = 2 * np.pi * self.frequncy"),
               "disturbance() raised AttributeError"),
    "bounds": (RIPPLE.replace('Param("amplitude", 20.0, 0.0, 500.0', 'Param("amplitude", 900.0, 0.0, 500.0'),
               "default 900 is outside its bounds [0, 500]"),
    "log": (RIPPLE.replace('Param("frequency", 1.0, 0.1, 50.0', 'Param("frequency", 1.0, 0.0, 50.0'),
            "log=True needs a positive lower bound"),
    "hook": (RIPPLE.replace("def disturbance(self, t, dt):", "def disturbanse(self, t, dt):"),
             "a disturbance effect must define disturbance()"),
    "stage": (RIPPLE.replace("stage = Stage.DISTURBANCE", 'stage = "disturbance"'),
              "stage must be one of plant.Stage.VALVE"),
    "empty": ("import numpy\n", "defines no effect"),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_a_broken_plugin_is_one_clear_error_naming_the_file_and_nothing_stays(tmp_path, case):
    text, expected = BROKEN[case]
    f = write(tmp_path / f"broken_{case}.py", text)
    before = dict(CATALOGUE)
    with pytest.raises(PluginError) as err:
        load_plugins([f])
    msg = str(err.value)
    assert str(f.resolve()) in msg and expected in msg, msg
    assert "Traceback" not in msg
    assert CATALOGUE == before
    if case in ("shape", "nan", "raises"):
        assert "effect 'ripple'" in msg


def test_the_command_line_says_what_is_wrong_without_a_traceback_and_runs_nothing(tmp_path):
    f = write(tmp_path / "broken.py", BROKEN["nan"][0])
    data = write(tmp_path / "d.csv", "t,u,y\n" + "".join(f"{k * 0.002},5,{k * 1.2}\n" for k in range(500)))
    res = stand("fit", str(data), "--model", "base", "--effects", str(f))
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr and str(f.resolve()) in res.stderr
    assert "non-finite value" in res.stderr and res.stdout == ""
    res = stand("diagnose", str(data), "--effects", "deadzone,lag")
    assert res.returncode == 2 and "--candidates deadzone,lag" in res.stderr, res.stderr


# ------------------------------------------------------------------------------------------
# model and controller files name their plug-ins
# ------------------------------------------------------------------------------------------
def test_a_saved_model_names_its_plugin_and_reloads_on_its_own(tmp_path):
    (tmp_path / "lib").mkdir()
    f = write(tmp_path / "lib" / "ripple.py", RIPPLE)
    load_plugins([f])
    m = PlantModel.from_spec("base+ripple", {"g": 110.0, "ripple.frequency": 3.0})
    out = tmp_path / "models" / "m.toml"
    out.parent.mkdir()
    out.write_text(model_to_toml(m, "test", out))
    assert 'plugins = ["../lib/ripple.py"]' in out.read_text()
    code = ("from plant import load_model_file, plugins\n"
            f"m = load_model_file({str(out)!r})\n"
            "print(m.spec, m.params()['ripple.frequency'], plugins.origin('ripple'))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["base+ripple", "3.0", "file", str(f.resolve())]


def test_a_controller_designed_from_a_plugin_model_loads_on_its_own(tmp_path):
    write(tmp_path / "gainy.py", skeleton("gainy", "flow"))
    model = write(tmp_path / "m.toml", 'plugins = ["gainy.py"]\nmodel = "base+gainy"\n'
                                       "[base]\ng = 120.0\ntau = 0.05\ndelta = 0.0\n[effects.gainy]\nk = 1.0\n")
    res = stand("design", str(model), "-o", str(tmp_path / "c.toml"), "--json")
    assert res.returncode == 0, res.stderr
    design = json.loads(res.stdout)
    assert design["boost"] == pytest.approx(1.1)        # G = 1 + k·|q|/100 at |q| = 10 %
    assert 'plugins = ["gainy.py"]' in (tmp_path / "c.toml").read_text()
    code = ("from loading.controller_files import load_controller\n"
            f"c = load_controller({str(tmp_path / 'c.toml')!r})\n"
            "print(c.channels[0].model.spec)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and res.stdout.strip() == "base+gainy", res.stderr


# ------------------------------------------------------------------------------------------
# stand effects: lists plug-ins with their origin, starts new ones; installed packages
# ------------------------------------------------------------------------------------------
def test_stand_effects_new_prints_a_skeleton_that_loads(tmp_path):
    res = stand("effects", "--new", "pump_ripple", "--stage", "disturbance")
    assert res.returncode == 0, res.stderr
    f = write(tmp_path / "pump_ripple.py", res.stdout)
    res = stand("effects", "--effects", str(f), "--json")
    assert res.returncode == 0, res.stderr
    row = next(r for r in json.loads(res.stdout) if r["effect"] == "pump_ripple")
    assert row["origin"] == f"file {f.resolve()}" and row["stage"] == "disturbance"
    assert [p["name"] for p in row["params"]] == ["amplitude", "frequency", "phase"]
    res = stand("effects", "--new", "Bad-Name")
    assert res.returncode == 2 and "lower-case letters" in res.stderr


def test_an_installed_package_s_effects_load_through_the_entry_point_group(tmp_path):
    site = tmp_path / "site"
    (site / "acme_effects").mkdir(parents=True)
    write(site / "acme_effects" / "__init__.py", RIPPLE.replace('"ripple"', '"acme_ripple"'))
    dist = site / "acme_effects-1.0.dist-info"
    dist.mkdir()
    write(dist / "METADATA", "Metadata-Version: 2.1\nName: acme-effects\nVersion: 1.0\n")
    write(dist / "entry_points.txt", "[hydrostand.effects]\nripple = acme_effects\n")
    env = {"PYTHONPATH": str(site)}
    res = stand("effects", "--json", env=env)
    assert res.returncode == 0, res.stderr
    row = next(r for r in json.loads(res.stdout) if r["effect"] == "acme_ripple")
    assert row["origin"] == "entry point acme-effects: ripple = acme_effects"
    res = stand("effects", env=env)
    assert "[plug-in: entry point acme-effects: ripple = acme_effects]" in res.stdout


# ------------------------------------------------------------------------------------------
# the emulator runs a plug-in
# ------------------------------------------------------------------------------------------
@pytest.mark.e2e
def test_the_emulator_runs_a_plugin_and_a_recorded_run_shows_it(tmp_path, bus_spec):
    f = write(tmp_path / "ripple.py", RIPPLE)
    emu = subprocess.Popen([sys.executable, "-m", "stand", "emulate", "--bus", bus_spec, "--lockstep",
                            "--seed", "3", "--effects", str(f), "--model", "base+ripple",
                            "--set", "ripple.amplitude=40", "--set", "ripple.frequency=2.5"],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        line = emu.stdout.readline()
        assert "emulator ready" in line and "base+ripple" in line, line
        res = stand("run", "meander", "--bus", bus_spec, "--lockstep", "--amplitude-pct", "5",
                    "--cycles", "2", "--out", str(tmp_path / "run"), timeout=120)
        assert res.returncode == 0, res.stderr
    finally:
        emu.terminate()
        emu.wait(10)
    from analysis import read_run
    rec = read_run(tmp_path / "run")
    # the force ripples at 2.5 Hz on top of the meander's ramps: the detrended force's spectrum
    resid = np.diff(rec.y) / rec.dt - np.convolve(np.diff(rec.y) / rec.dt, np.ones(51) / 51, "same")
    spec = np.abs(np.fft.rfft(resid[100:-100] * np.hanning(len(resid) - 200)))
    freqs = np.fft.rfftfreq(len(resid) - 200, rec.dt)
    band = (freqs > 0.5) & (freqs < 20)
    assert freqs[band][np.argmax(spec[band])] == pytest.approx(2.5, abs=0.1)


def test_an_emulator_configuration_with_a_plugin_names_it_for_the_emulator_process(tmp_path):
    """stand demo, stand campaign and the tests start the emulator from a written plant file:
    it names the plug-in's file, so the emulator process loads it."""
    from plant import load_plant_config
    from plant_emulator.process import config_to_toml
    f = write(tmp_path / "ripple.py", RIPPLE)
    load_plugins([f])
    config = load_plant_config(None, "base+ripple", {"ripple.frequency": 2.5})
    plant_file = write(tmp_path / "elsewhere.toml", config_to_toml(config))
    code = ("from plant import load_plant_config\n"
            f"c = load_plant_config({str(plant_file)!r})\n"
            "print(c.model.spec, c.model.params()['ripple.frequency'])")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["base+ripple", "2.5"]


# ------------------------------------------------------------------------------------------
# the catalogue's own effects are plug-ins of the same contract
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", BUILTINS)
def test_every_built_in_effect_passes_the_check_a_plug_in_must(name):
    """What a user's plug-in must pass on load (its hook and a model with it simulated at its
    defaults and at each bound), every built-in passes: none relies on anything a plug-in lacks."""
    assert plugins.check_effect(CATALOGUE[name], f"plant/effects ({name})") == []


def test_a_built_in_module_loads_as_a_user_plug_in_file_would(tmp_path):
    """A copy of a built-in's module, renamed, is a working plug-in file: the built-ins are
    written to the contract docs/your-own-effect.md gives, nothing more."""
    text = (ROOT / "plant" / "effects" / "stiffness.py").read_text()
    text = text.replace('name = "stiffness"', 'name = "my_stiffness"')
    names = load_plugins([write(tmp_path / "my_stiffness.py", text)])
    assert names == ["my_stiffness"]
    assert plugins.origin("my_stiffness").startswith("file ")
    y = PlantModel.from_spec("base+my_stiffness", {"my_stiffness.k_abs": 1.5}).simulate(
        np.full(500, 10.0), 0.002)
    ref = PlantModel.from_spec("base+stiffness", {"stiffness.k_abs": 1.5}).simulate(
        np.full(500, 10.0), 0.002)
    assert np.array_equal(y, ref)


def test_the_catalogue_lists_the_built_ins_first_in_stage_order():
    stages = [CATALOGUE[n].stage for n in BUILTINS]
    assert stages == sorted(stages)
    assert list(BUILTINS) == [n for n in CATALOGUE if n in BUILTINS][:len(BUILTINS)]


def test_a_wrong_prepared_from_claim_is_refused_and_a_right_one_reuses_the_drive():
    """prepared_from lets a fit reuse the prepared flow while it moves the other parameters; a
    claim that leaves out a parameter prepare() reads would fit a model that is not there, so
    the plug-in check refuses it, naming the parameter. The reversal's claim (only its decay)
    keeps the drive across a change of its boost, and the simulation is still the model's."""
    from plant.effects.reversal import Reversal

    class Wrong(Reversal):
        name = "wrong_reversal"
        prepared_from = ("boost",)          # prepare() reads the decay, not the boost

    with pytest.raises(PluginError, match="prepare\\(\\) changes with decay"):
        plugins.check_effect(Wrong, "test")

    class Unknown(Reversal):
        name = "unknown_reversal"
        prepared_from = ("decay", "speed")

    with pytest.raises(PluginError, match="speed, which are not its parameters"):
        plugins.check_effect(Unknown, "test")

    a = PlantModel.from_spec("base+reversal", {"reversal.boost": 2.0})
    b = PlantModel.from_spec("base+reversal", {"reversal.boost": 3.0})
    c = PlantModel.from_spec("base+reversal", {"reversal.decay": 0.3})
    assert a.drive_key() == b.drive_key() != c.drive_key()
    u = np.where(np.arange(2000) % 400 < 200, 10.0, -10.0)
    assert not np.allclose(a.simulate(u, 0.002), b.simulate(u, 0.002))
