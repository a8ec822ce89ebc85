"""The reference (docs/reference/, stand.reference): the pages are what the code writes now
(the CLI page is `--help`, whatever the terminal), and the hand-written parts hold against the
code: every key a loader accepts is documented and every documented key accepted (probed with
a key it cannot know), the controller files' keys are what the writer writes, the load summary's
and the test status's keys what the code builds, run.json's what a recorded run holds."""
from __future__ import annotations

import argparse
import copy
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from stand.reference import stale
from stand.reference import (controller_file, devices_file, endurance_file, model_files, outputs,
                             rig_file, run_dir)
from stand.reference.cli_page import commands, help_text, invocation

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "docs" / "reference"
PROBE = "zz_not_a_key"


def test_the_reference_pages_are_what_the_code_writes():
    differ = stale(REFERENCE)
    assert not differ, (f"docs/reference/{', '.join(differ)} differ(s) from the code: regenerate with "
                        "`python -m stand.reference docs/reference` and commit the pages")


def test_the_pages_depend_on_the_code_alone_not_the_terminal_the_locale_or_the_directory(tmp_path):
    """`python -m stand.reference --check` from elsewhere, on a narrow terminal in the C locale
    with another loopback namespace, finds the committed pages current (and says which differ
    once one does)."""
    import os
    import subprocess
    import sys
    env = dict(os.environ, COLUMNS="33", LANG="C", LC_ALL="C", HYDROSTAND_LOOPBACK_NAMESPACE="elsewhere")
    check = [sys.executable, "-m", "stand.reference", "--check"]
    done = subprocess.run(check + [str(REFERENCE)], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    (tmp_path / "ref").mkdir()
    (tmp_path / "ref" / "cli.md").write_text((REFERENCE / "cli.md").read_text().replace("--lockstep", "--lock"))
    done = subprocess.run(check + ["ref"], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode == 1 and "ref/cli.md: differs from the code" in done.stderr
    assert "ref/README.md" in done.stderr and "python -m stand.reference ref" in done.stderr


def _plain(s: str) -> str:
    """Markdown or help text as words: escapes, code marks and entities out, blanks as one."""
    s = s.replace("\\|", "|").replace("\\*", "*").replace("\\\\", "\\").replace("&lt;", "<").replace("&gt;", ">")
    return " ".join(s.replace("`", "").split())


def test_every_command_option_and_help_of_stand_help_is_on_the_cli_page():
    from stand.cli import build_parser
    text = (REFERENCE / "cli.md").read_text()
    sections = {}
    for part in re.split(r"^## ", text, flags=re.M)[1:]:
        heading, _, body = part.partition("\n")
        sections[heading.strip()] = _plain(body)
    tree = list(commands(build_parser()))
    assert list(sections) == [c.name for c in tree[1:]]
    for cmd in tree[1:]:
        for action in cmd.parser._actions:
            if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            assert _plain(invocation(cmd.parser, action)) in sections[cmd.name], (cmd.name, action.dest)
            assert _plain(help_text(cmd.parser, action)) in sections[cmd.name], (cmd.name, action.dest)
        if cmd.parser.description and "\n\n" not in cmd.parser.description:
            assert _plain(cmd.parser.description) in sections[cmd.name], cmd.name


# -- the loaders' keys ------------------------------------------------------------------------------
def _listed(message: str) -> set[str]:
    """The keys a refusal of an unknown key lists as the ones it takes."""
    rest = re.split(r"known:|takes|has (?!no)|expected|holds", message.split(";", 1)[1])[-1]
    names = set()
    for part in re.split(r",| and ", rest):
        m = re.search(r"\[*\s*([A-Za-z_][A-Za-z0-9_]*)", part)
        if m and m.group(1) not in ("a", "it"):
            names.add(m.group(1))
    return names


def _refused(load, data, at, key):
    """The message of ``load(data with key added at the table at(data))``, or None."""
    d = copy.deepcopy(data)
    at(d)[key] = 1
    try:
        load(d)
    except Exception as exc:                                  # noqa: BLE001 - a refusal is the answer
        return str(exc)
    return None


def _unknown(message: str | None, key: str) -> bool:
    m = message and re.search(r"(?:unknown (?:key|table)\(s\)|has no key\(s\)|has unknown key\(s\)) ([^;]*)",
                              message)
    return bool(m) and key in [k.strip() for k in m.group(1).split(",")]


def _check_table(load, data, at, table, documented: set[str]):
    message = _refused(load, data, at, PROBE)
    table = table or "the top level"
    assert _unknown(message, PROBE), f"{table}: an unknown key is not refused by name: {message}"
    listed = _listed(message)
    assert listed <= documented, f"{table}: the loader takes {sorted(listed - documented)}, not documented"
    for key in documented - listed:
        assert not _unknown(_refused(load, data, at, key), key), f"{table}: documented {key} is refused"


def _documented(tables, name: str) -> set[str]:
    return next(t for t in tables if t.name == name).names


def test_the_rig_file_page_names_every_key_the_loader_takes():
    from rig.config import rig_from_mapping
    data = tomllib.loads((ROOT / "examples" / "rig.toml").read_text())
    data["structure"]["change"] = [{"channel": "root", "stiffness_factor": 0.9, "from_s": 1.0}]
    tables = rig_file.tables()

    def load(d):
        return rig_from_mapping(d, "rig.toml", ROOT / "examples")
    load(data)
    for name, at in [("", lambda d: d), ("[[bus]]", lambda d: d["bus"][0]),
                     ("[[channel]]", lambda d: d["channel"][0]), ("[structure]", lambda d: d["structure"]),
                     ("[[structure.change]]", lambda d: d["structure"]["change"][0])]:
        _check_table(load, data, at, name, _documented(tables, name))


def test_the_devices_file_page_names_every_key_the_loader_takes():
    from devices import device_set_from_mapping
    folder = ROOT / "examples" / "devices" / "servotek"
    data = tomllib.loads((folder / "devices.toml").read_text())
    tables = devices_file.tables()

    def load(d):
        return device_set_from_mapping(d, "devices.toml", folder)
    load(data)
    for name, at in [("", lambda d: d), ("[valve]", lambda d: d["valve"]),
                     ("[dynamometer]", lambda d: d["dynamometer"])]:
        _check_table(load, data, at, name, _documented(tables, name))


def test_the_test_file_page_names_every_key_the_loader_takes(tmp_path, monkeypatch):
    import plant.config
    from endurance.testfile import load_test_file
    from tests.support.endurance import copy_example
    path = copy_example(tmp_path)
    read = plant.config.read_toml
    data = read(path)
    given = {}
    monkeypatch.setattr(plant.config, "read_toml", lambda p: given["data"] if Path(p) == path else read(p))

    def load(d):
        given["data"] = d
        load_test_file(path, check_controller=False)
    tables = endurance_file.tables()
    stand = dict(data, station="stand", stand={})
    for name, doc, at in [("", data, lambda d: d), ("[stand]", stand, lambda d: d["stand"]),
                          ("[flight.NAME]", data, lambda d: d["flight"]["A"]),
                          ("[block]", data, lambda d: d["block"]),
                          ("[[inspection]]", data, lambda d: d["inspection"][0]),
                          ("[monitor]", data, lambda d: d["monitor"]),
                          ("[monitor.trend]", data, lambda d: d["monitor"]["trend"]),
                          ("[monitor.gain]", data, lambda d: d["monitor"]["gain"]),
                          ("[time_scaling]", dict(data, time_scaling={}), lambda d: d["time_scaling"]),
                          ("[storage]", data, lambda d: d["storage"])]:
        _check_table(load, doc, at, name, _documented(tables, name))


def test_the_model_page_names_every_table_and_key_the_plant_and_rig_model_loaders_take():
    from plant.config import plant_config_from_mapping, rig_model_from_mapping
    from plant.model import BASE_PARAMS
    from plant.sensor import SENSOR_PARAMS

    def plant(d):
        return plant_config_from_mapping(d, "plant.toml")
    base = {"model": "base", "base": {"tau": 0.05}, "sensor": {}, "initial": {}}
    _check_table(plant, base, lambda d: d, "plant file", model_files.plant_tables()[0].names)
    _check_table(plant, base, lambda d: d["base"], "[base]", {p.name for p in BASE_PARAMS})
    _check_table(plant, base, lambda d: d["sensor"], "[sensor]", {p.name for p in SENSOR_PARAMS})
    _check_table(plant, base, lambda d: d["initial"], "[initial]", {"force_kgf"})

    def rig_model(d):
        return rig_model_from_mapping(d, "rig-model.toml")
    tables = model_files.rig_model_tables()
    rm = {"channels": ["a"], "structure": {"G": [[120.0]]}, "channel": {"a": {"model": "base"}}}
    _check_table(rig_model, rm, lambda d: d, "rig model file", _documented(tables, ""))
    _check_table(rig_model, rm, lambda d: d["structure"], "[structure]", _documented(tables, "[structure]"))


def _keys(table: dict, prefix: str = "") -> dict[str, set[str]]:
    """A parsed TOML document as {table path: its keys}, arrays of tables as ``[[path]]``,
    ``[channel.NAME]``-like tables of names folded into one."""
    out: dict[str, set[str]] = {}

    def walk(t: dict, path: str) -> None:
        keys = out.setdefault(path, set())
        for k, v in t.items():
            keys.add(k)
            if isinstance(v, dict):
                walk(v, f"[{path.strip('[]')}.{k}]" if path else f"[{k}]")
            elif isinstance(v, list) and v and all(isinstance(i, dict) for i in v):
                for i in v:
                    walk(i, f"[[{(path.strip('[]') + '.' if path else '')}{k}]]")
    walk(table, prefix)
    return out


def test_the_controller_page_names_every_key_the_design_writes_and_the_reader_reads_it_back(tmp_path):
    from loading.controller_files import load_controller
    from loading.design import ChannelDesign, ControllerDesign
    from loading.margins import LoopMargins, Margins
    m = Margins(120.0, 0.75, 6.5, 62.0, 1.25)
    params = {"g": 120.0, "tau": 0.05, "delta": 8.0, "reversal.boost": 2.0, "reversal.decay": 0.15,
              "reversal.exponent": 1.0}
    stand = ChannelDesign(0.002, "base+reversal", params, 0.04, 0.9, boost=3.0, lambda_s=0.17, nominal=m,
                          boosted=m)
    path = tmp_path / "controller.toml"
    path.write_text(stand.to_toml(path))
    load_controller(path, 0.002)
    written = _keys(tomllib.loads(path.read_text()))
    assert written.pop("") == {"loop", "feedback", "model", "design"}
    assert written.pop("[design.boosted]") == written["[design.nominal]"]
    written["[model]"] = {k if k == "spec" else '"PARAM"' for k in written["[model]"]}
    documented = {t.name: t.names for t in controller_file.stand_tables()}
    documented["[model]"] -= {"plugins"}             # written when the model has plug-ins
    assert written == documented

    rig = ControllerDesign(["a", "b"], np.array([[120.0, 30.0], [30.0, 100.0]]),
                           [ChannelDesign(0.002, "base", {"g": g, "tau": 0.05, "delta": 0.0}, 0.04, 0.9)
                            for g in (120.0, 100.0)], 0.002,
                           margins=[LoopMargins("nominal", [1.0, 1.0], 0.0, 5.0, 60.0, 0.8, 1.3)])
    path.write_text(rig.to_toml(path))
    load_controller(path, 0.002, ["b", "a"])
    written = _keys(tomllib.loads(path.read_text()))
    assert written.pop("[channel]") == {"a", "b"}
    for n in ("a", "b"):
        written["[channel.NAME]"] = written.pop(f"[channel.{n}]")
        written["[channel.NAME.model]"] = {k if k == "spec" else '"PARAM"'
                                           for k in written.pop(f"[channel.{n}.model]")}
    documented = {t.name: t.names for t in controller_file.rig_tables()}
    documented[""] -= {"plugins"}
    assert written == documented


# -- what the commands print and record ---------------------------------------------------------------
def _top(tables) -> set[str]:
    return _documented(tables, "")


def test_the_load_summary_page_names_every_key_of_the_summary(tmp_path):
    from gateway.load import LoadResult, PassTiming
    from loading.gain_monitor import GainMonitor, MonitorOptions
    from loading.programme import sine
    from loading.report import tracking_report
    from plant import PlantModel
    from plant.rig import RigModel
    p = sine(3000, 2000, 0.5, 2, 0.002)
    passes = [tracking_report(p, p.t_s, p.r_kgf + 5.0) for _ in range(2)]
    timing = PassTiming(4.0, 3.0, 0.1, pacing={"waits": 1, "slowed_s": 0.1}, scaling={"land": 3},
                        gain_blocks=[])
    monitor = GainMonitor(RigModel([PlantModel.from_spec("base")], np.array([[120.0]]), ["stand"]), 0.002,
                          MonitorOptions())
    result = LoadResult(tmp_path, passes, [tmp_path / "pass-1", tmp_path / "pass-2"], "error_limit",
                        "stopped", timings=[timing, timing], converged=False, monitor=monitor,
                        schedule=None)
    summary = result.summary()
    tables = outputs.load_tables()
    figures = {k.name for k in outputs.FIGURES}
    assert set(summary) == _top(tables)
    assert all(set(p) <= _top(tables) - {"schema", "end_reason", "end_message", "passes", "runs",
                                          "schedule", "converged", "gain"} for p in summary["passes"])
    assert set(summary["channels"]["stand"]) == figures
    assert set(summary["peak_valley_error_pct"]) == {"max", "p95"}
    assert set(summary["gain"]) == _documented(tables, "gain")


def test_the_test_status_page_names_every_key_of_the_status(tmp_path):
    from endurance.journal import EndPoint, Journal
    from endurance.report import status
    j = Journal.create(tmp_path / "t", "a test", 10, ["root", "tip"], "abc")
    j.start()
    j.begin_flight(1, "A", 1, 1, 2)
    j.commit_load_case(1, 0, [EndPoint(c, 100.0, 101.0, 5.0) for c in ("root", "tip")])
    j.add_event("inspection", "look at the root", channel="root", flight=1, load_case=0)
    s = status(j)
    j.close()
    tables = outputs.status_tables()
    assert set(s) == _top(tables)
    assert set(s["events"][-1]) == _documented(tables, "events[]")
    assert set(s["flight"]) == {"number", "type", "block", "position", "load_cases", "attempt"}


@pytest.mark.e2e
def test_the_run_page_names_every_key_of_a_recorded_run(start_emulator, bus_spec, tmp_path):
    import json
    from gateway import Gateway
    from gateway.config import GatewayConfig
    from gateway.experiments import make_experiment
    start_emulator()
    with Gateway(GatewayConfig(bus=bus_spec, lockstep=True)) as gw:
        result = gw.run(make_experiment("meander", {"cycles": 1, "period_s": 0.5}), tmp_path / "run",
                        progress=False)
    meta = json.loads((result.path / "run.json").read_text())
    top, conditional, limits, stats = run_dir.tables()
    assert top.names <= set(meta) <= top.names | conditional.names, set(meta) ^ top.names
    assert set(meta["limits"]) == limits.names
    assert set(meta["stats"]) <= stats.names
    assert set(meta["nodes"]) == {"valve", "dynamometer"}


def test_stand_diagnose_help_names_every_verdict_the_diagnosis_gives():
    """The verdicts are written in the code as literals; the help is built from
    analysis.defaults.VERDICTS: every literal must be one of them (stepwise also ends at
    max_effects, which its option's help names)."""
    from analysis.defaults import VERDICTS
    from stand.cli import build_parser
    given = set()
    for module in ("verdict", "stepwise"):
        source = (ROOT / "analysis" / "diagnosis" / f"{module}.py").read_text()
        given |= set(re.findall(r'Conclusion\("(\w+)"', source))
        given |= set(re.findall(r'verdict = "(\w+)"', source))
    assert given - {"max_effects"} == set(VERDICTS), given
    help_text = build_parser()._subparsers._group_actions[0].choices["diagnose"].format_help()
    assert all(v in " ".join(help_text.split()) for v in VERDICTS)


def test_the_shipped_sample_tables_read_alike_in_both_loggers_styles():
    """examples/meander.csv (English) and examples/meander-logger.csv (a Russian logger:
    Windows-1251, semicolons, decimal commas, ms, V, kN) are one recording: read by the rules of
    docs/reference/tables.md they give the same samples in s, %, kgf, each conversion noted."""
    from analysis.records.load import load
    english, russian = load(ROOT / "examples" / "meander.csv"), load(ROOT / "examples" / "meander-logger.csv")
    for rec in (english, russian):
        assert len(rec.t) == 3000 and rec.dt == pytest.approx(0.004)
        assert np.allclose(np.abs(rec.u), 4.999, atol=1e-3) and 800 < np.abs(rec.y).max() < 900
    assert np.array_equal(english.t, russian.t) and np.array_equal(english.u, russian.u)
    assert np.array_equal(english.y, russian.y)
    assert any("Windows-1251" in n for n in russian.notes) and not any("UTF-8" in n for n in english.notes)
    assert sum("read as" in n for n in russian.notes) == 4 and sum("read as" in n for n in english.notes) == 3


def test_every_link_of_the_reference_goes_to_a_page_and_heading_that_exist():
    from stand.reference.markdown import anchor
    for page in sorted(REFERENCE.glob("*.md")):
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if target.startswith(("http://", "https://")):
                continue
            path, _, heading = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            if file.is_dir():
                file = file / "README.md"
            assert file.exists(), f"{page.name}: {target}: no such file"
            if heading:
                anchors = {anchor(h) for h in re.findall(r"^#+ (.*)$", file.read_text(), re.M)}
                assert heading in anchors, f"{page.name}: {target}: no such heading"
