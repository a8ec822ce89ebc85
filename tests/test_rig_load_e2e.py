"""``stand load PROGRAMME --rig RIG.toml --controller C.toml`` end to end: the example rig (4
channels, neighbours coupled 30 %, each its own g, τ, Δ and reversal boost) served by ``stand
emulate --rig --lockstep`` in its own process, a decoupled controller designed (``stand design``)
from a rig model file of the emulator's truth, 6 load cases at 2500 kgf/s, 2 passes with
per-channel compensation, each step a ``stand`` command in a subprocess. And the refusals,
before anything is opened."""
from __future__ import annotations

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from gateway import load_run
from loading.controller_files import read_rig_model
from plant.config import rig_model_to_toml
from tests.support.rig import EXAMPLE_RIG

NAMES = ["root", "inner", "outer", "tip"]
#: the one-channel summary's tracking keys (stand load --json, schema hydrostand-load/1)
ONE_CHANNEL_KEYS = {"peak_valley_error_pct", "rms_error_pct", "extra_cycles", "largest_extra_cycle_kgf",
                    "overshoot_max_pct", "range_kgf", "turning_points"}
CASES = """case,root,inner,outer,tip
1,1000,800,500,400
2,4000,3000,2500,2000
3,1500,1200,800,600
4,5000,4500,2800,2500
5,800,2000,600,1500
6,3500,1000,2200,700
"""


def stand(*args, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "stand", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)


@pytest.fixture(scope="module")
def decoupled(tmp_path_factory):
    """A decoupled controller from a rig model file of the example's truth (``stand design``:
    about 10 s, so once for the module)."""
    tmp_path = tmp_path_factory.mktemp("design")
    model, _ = read_rig_model(EXAMPLE_RIG)
    (tmp_path / "truth-model.toml").write_text(rig_model_to_toml(model, "the example rig's truth"))
    done = stand("design", tmp_path / "truth-model.toml", "-o", tmp_path / "decoupled.toml")
    assert done.returncode == 0, done.stderr
    return tmp_path / "decoupled.toml"


@pytest.mark.e2e
@pytest.mark.slow
def test_stand_load_rig_tracks_load_cases_on_every_channel_and_reports_per_channel(
        tmp_path, start_rig_emulator, decoupled):
    rig = start_rig_emulator()
    (tmp_path / "cases.csv").write_text(CASES)
    out = tmp_path / "load"
    done = stand("load", tmp_path / "cases.csv", "--rig", rig, "--controller", decoupled, "--rate", 2500,
                 "--repeat", 2, "--lockstep", "--json", "--no-progress", "--out", out)
    assert done.returncode == 0, done.stderr + done.stdout
    doc = json.loads(done.stdout)
    assert doc == json.loads((out / "report.json").read_text())
    # today's keys for the worst channel, plus every channel's and the ratio error
    assert doc["schema"] == "hydrostand-load/1" and doc["end_reason"] == "complete"
    assert ONE_CHANNEL_KEYS <= set(doc) and doc["worst_channel"] in NAMES
    assert set(doc["channels"]) == set(NAMES)
    for name in NAMES:
        assert set(doc["channels"][name]) == ONE_CHANNEL_KEYS
    assert {k: doc[k] for k in ONE_CHANNEL_KEYS} == doc["channels"][doc["worst_channel"]]
    assert len(doc["passes"]) == 2 and doc["programme_time_s"] > 0
    # Bounds: the controller is designed from the truth, so only noise (2 kgf), quantization and
    # the reversal boosts' unmodelled timing remain; offline on the same plant 16 load cases held
    # p95 <= 0.3 % and max <= 0.5 % (tests/test_rig_loading.py). The goal is p95 <= 0.5 %,
    # max <= 1 %: every pass here must meet max <= 0.5 % on every channel, no extra cycle.
    for k, p in enumerate(doc["passes"], start=1):
        for name, f in p["channels"].items():
            assert f["peak_valley_error_pct"]["max"] <= 0.5, (k, name, f)
            assert f["extra_cycles"] == 0, (k, name, f)
        assert p["ratio_error_pct"] <= 0.5, (k, p["ratio_error_pct"])
    assert (out / "compensation.toml").is_file() and (out / "tracking.png").is_file()
    assert "worst channel" in (out / "report.txt").read_text()
    # each pass is a rig run: every channel's reference recorded and its own tracking
    for k in (1, 2):
        run = load_run(out / f"pass-{k}")
        meta = json.loads((out / f"pass-{k}" / "run.json").read_text())
        assert meta["experiment"]["name"] == "load" and meta["rig"]["driven"] == NAMES
        for name in NAMES:
            r = run.signals[f"r.{name}"]
            assert np.isfinite(r).sum() > 0.8 * len(r) / 2, name
        assert (out / f"pass-{k}" / "tracking.json").is_file()


@pytest.mark.e2e
@pytest.mark.slow
def test_stand_load_rig_fastest_scales_the_load_cases_to_the_valves_and_the_schedule_replays(
        tmp_path, start_rig_emulator, decoupled):
    """--fastest with no rate: from twice the valve-limited minimum through G, shortened pass by
    pass while every channel holds 0.5 %; the schedule it saves replays, and --plan reads it."""
    rig = start_rig_emulator()
    (tmp_path / "cases.csv").write_text(CASES)
    plan = stand("load", tmp_path / "cases.csv", "--rig", rig, "--controller", decoupled, "--fastest",
                 "--plan", "--json", "--lockstep")
    assert plan.returncode == 0, plan.stderr
    start = json.loads(plan.stdout)
    assert start["ratio"] == pytest.approx(2.0, abs=0.01) and start["segments"] == 5
    assert set(start["segments_set_by"]) <= set(NAMES)
    minimum = start["minimum_time_s"]
    out = tmp_path / "fast"
    done = stand("load", tmp_path / "cases.csv", "--rig", rig, "--controller", decoupled, "--fastest",
                 "--repeat", 6, "--lockstep", "--json", "--no-progress", "--out", out)
    assert done.returncode == 0, done.stderr + done.stdout
    doc = json.loads(done.stdout)
    times = [p["programme_time_s"] for p in doc["passes"]]
    assert times[0] == pytest.approx(2 * minimum, abs=0.01) and min(times) < 0.7 * times[0], times
    assert all(p["minimum_time_s"] == pytest.approx(minimum) for p in doc["passes"])
    assert all({"land", "hold", "miss", "met_accuracy"} <= set(p["scaling"]) for p in doc["passes"])
    sched = doc["schedule"]
    assert sched is not None and sched["verified"] and sched["accuracy_pct"] == 0.5
    # never under the floor (whole periods), and it met 0.5 % on every channel in its pass
    assert minimum - 0.002 * 5 <= sched["time_s"] < 0.7 * times[0]
    met = [p for p in doc["passes"] if p["programme_time_s"] == pytest.approx(sched["time_s"], abs=1e-6)]
    assert met and all(f["peak_valley_error_pct"]["p95"] <= 0.5 and f["peak_valley_error_pct"]["max"] <= 1.0
                       and f["extra_cycles"] == 0 for f in met[0]["channels"].values()), met
    from loading.time_scaling import Schedule
    saved = Schedule.load(out / "schedule.toml")
    assert saved.channels == NAMES and saved.verified and saved.time_s == pytest.approx(sched["time_s"])
    assert "valve-limited minimum" in (out / "report.txt").read_text()
    # a production run replays the schedule (no --rate needed) and --plan reads it
    again = stand("load", tmp_path / "cases.csv", "--rig", rig, "--controller", decoupled, "--schedule",
                  out / "schedule.toml", "--lockstep", "--json", "--no-progress", "--out", tmp_path / "replay")
    assert again.returncode == 0, again.stderr + again.stdout
    replay = json.loads(again.stdout)
    assert replay["programme_time_s"] == pytest.approx(sched["time_s"], abs=0.002)
    # it replays with the corrections its pass ran with, so it holds what the schedule promised
    assert saved.compensation_path.is_file()
    for name, f in replay["channels"].items():
        pv = f["peak_valley_error_pct"]
        assert pv["p95"] <= 0.5 and pv["max"] <= 1.0 and f["extra_cycles"] == 0, (name, f)
    text = stand("load", tmp_path / "cases.csv", "--rig", rig, "--controller", decoupled, "--schedule",
                 out / "schedule.toml", "--plan", "--lockstep")
    assert text.returncode == 0 and "the schedule:" in text.stdout and "segments set by" in text.stdout, text


@pytest.mark.e2e
@pytest.mark.slow
def test_stand_load_rig_gain_alarm_on_a_softened_structure_unloads_every_channel_keeping_the_ratios(
        tmp_path, start_rig_emulator, decoupled, channel):
    """The emulated structure 10 % softer at root's attachment than the model the controller
    was designed from (a crack): --gain watch finds root's gain fallen, the others not, and
    its unload action unloads every channel keeping the load ratios."""
    from tests.support.rig import example_rig_text
    text = example_rig_text(channel)
    cracked = text.replace("K = [[10.0,  3.0,", "K = [[ 9.0,  3.0,")
    assert cracked != text
    rig = start_rig_emulator(cracked)
    (tmp_path / "cases.csv").write_text(CASES)
    out = tmp_path / "load"
    done = stand("load", tmp_path / "cases.csv", "--rig", rig, "--controller", decoupled, "--rate", 2500,
                 "--gain", "watch", "--gain-block-s", 2, "--gain-alarm-action", "unload", "--lockstep",
                 "--json", "--no-progress", "--out", out)
    assert done.returncode == 1, done.stderr + done.stdout
    assert "gain alarm (fall): channel root: block 2" in done.stderr, done.stderr
    doc = json.loads(done.stdout)
    assert doc["end_reason"] == "gain_alarm" and doc["gain"]["alarm_channel"] == "root"
    gains = doc["gain"]["channels"]
    assert gains["root"]["last_g"] == pytest.approx(0.9 * 120.0, rel=0.03), gains["root"]
    for name, g in (("inner", 100.0), ("outer", 140.0), ("tip", 110.0)):
        assert gains[name]["last_g"] == pytest.approx(g, rel=0.02), (name, gains[name])
    blocks = json.loads((out / "pass-1" / "gain.json").read_text())["blocks"]
    assert set(blocks) == set(NAMES) and [b["alarm"] for b in blocks["root"]] == [None, "fall"]
    # the rig's unload: every channel, the ratios kept within 2 % of each channel's range
    safety = json.loads((out / "pass-1" / "run.json").read_text())["safety"]
    assert safety["reason"] == "gain_alarm" and safety["channel"] == "root" and safety["action"] == "unload"
    unload = safety["unload"]
    assert unload["outcome"] == "unloaded" and set(unload["channels"]) == set(NAMES)
    for name, c in unload["channels"].items():
        assert c["unloaded"] and abs(c["to_kgf"]) < 100 and c["max_deviation_pct_of_range"] < 2.0, (name, c)
    report = (out / "report.txt").read_text()
    assert "pass 1 stopped (gain_alarm)" in report and "gain root" in report
    # the test's page: every channel's gain through the test, the alarm on root's
    page = stand("report", out)
    assert page.returncode == 0, page.stderr
    html = (out / "report.html").read_text()
    assert all((out / f"gain-{n}.png").is_file() for n in NAMES) and "alarm: fall" in html


def with_slow_outer(text: str, limit_pct: float) -> str:
    """The example rig's text with outer's valve passing at most ``limit_pct`` of flow (a flow
    limit the controller's model lacks)."""
    head, sep, rest = text.partition('name = "outer"')
    rest = rest.replace('model = "base+reversal"', 'model = "base+reversal+saturation"', 1)
    rest = rest.replace("decay = 0.2\n", f"decay = 0.2\n[channel.plant.effects.saturation]\nlimit = {limit_pct}\n", 1)
    assert "saturation" in rest
    return head + sep + rest


@pytest.mark.e2e
@pytest.mark.slow
def test_stand_load_rig_pacing_waits_for_a_slow_valve_and_keeps_the_load_cases(
        tmp_path, start_rig_emulator, decoupled, channel):
    """Outer's valve passes at most 12 % of flow; the load cases at 5000 kgf/s ask up to 17 %:
    without pacing outer misses them and the ratios bend; with --pacing static the rig's one
    clock waits for it at the load cases, with dynamic it also slows for it between them."""
    from tests.support.rig import example_rig_text
    rig = start_rig_emulator(with_slow_outer(example_rig_text(channel), 12.0))
    (tmp_path / "cases.csv").write_text(CASES)
    docs = {}
    for mode in ("off", "static", "dynamic"):     # without pacing it lags: let it finish, measured
        done = stand("load", tmp_path / "cases.csv", "--rig", rig, "--controller", decoupled, "--rate", 5000,
                     "--pacing", mode, "--error-limit", 2000, "--lockstep", "--json", "--no-progress",
                     "--out", tmp_path / mode)
        assert done.returncode == 0, done.stderr + done.stdout
        docs[mode] = json.loads(done.stdout)
    off, on = docs["off"], docs["static"]
    outer_off = off["channels"]["outer"]["peak_valley_error_pct"]["max"]
    outer_on = on["channels"]["outer"]["peak_valley_error_pct"]["max"]
    assert outer_off > 1.5 and outer_on < 0.5 * outer_off, (outer_off, outer_on)
    assert on["ratio_error_pct"] < 0.5 * off["ratio_error_pct"], (off["ratio_error_pct"], on["ratio_error_pct"])
    assert "pacing" not in off["passes"][0]
    rec = on["passes"][0]["pacing"]
    assert rec["waits"] >= 1 and on["passes"][0]["pacing_s"] > 0.5, rec
    meta = json.loads((tmp_path / "static" / "pass-1" / "run.json").read_text())
    assert meta["experiment"]["params"]["pacing"] == "static"
    assert "pacing" in (tmp_path / "static" / "report.txt").read_text()
    dyn = docs["dynamic"]
    assert dyn["channels"]["outer"]["peak_valley_error_pct"]["max"] <= 0.5, dyn["channels"]["outer"]
    assert dyn["ratio_error_pct"] <= 0.5 and dyn["passes"][0]["pacing"]["slowed_s"] > 0.2, dyn["passes"][0]
    assert on["passes"][0]["pacing"]["slowed_s"] == 0


def in_process(capsys, *args) -> tuple[int, str]:
    """``stand ARGS`` in this process (quicker than a subprocess): exit code and stderr."""
    from stand.cli import main
    rc = main([str(a) for a in args])
    return rc, capsys.readouterr().err


def test_stand_load_rig_refuses_before_anything_is_opened(tmp_path, decoupled, capsys):
    # no emulator runs: each refusal comes before the gateway opens a bus
    rig = tmp_path / "rig.toml"
    rig.write_text(EXAMPLE_RIG.read_text().replace("udp_loopback:rig-", "udp_loopback:nobody-"))
    (tmp_path / "cases.csv").write_text(CASES)
    (tmp_path / "other.csv").write_text(CASES.replace("tip", "wingtip"))
    (tmp_path / "high.csv").write_text(CASES.replace("5000,4500,2800,2500", "5000,4500,4800,2500"))
    (tmp_path / "sequences.toml").write_text("".join(
        f'[channel.{n}]\nprogramme = "sine:mean=1000,amplitude=300,frequency=0.5,cycles=2"\n' for n in NAMES))
    from loading.time_scaling import Schedule
    Schedule(np.array([1000.0, 4000.0]), np.array([1.0]), 0.002, source="one channel").save(tmp_path / "one.toml")
    out = tmp_path / "never"
    base = ("--rig", rig, "--controller", decoupled, "--lockstep", "--out", out)
    cases = [
        (("other.csv", "--rate", 2500), "column 'wingtip' is not a channel of the rig"),
        (("high.csv", "--rate", 2500), "channel outer: .*4800 kgf.* force limit ±4500"),
        (("cases.csv", "--rate", 25000), "needs a valve command of .* its valve cannot follow"),
        (("cases.csv",), "load cases need --rate"),
        (("sequences.toml", "--rate", 2500, "--pacing", "static"), "pacing waits at load cases; per-channel"),
        (("cases.csv", "--fastest", "--schedule", "one.toml"), "give one or the other"),
        (("cases.csv", "--accuracy", 50), "accuracy 50.0 %: give a share of the range"),
        (("cases.csv", "--schedule", tmp_path / "one.toml"), "one channel's: it cannot time a rig's load cases"),
        (("sequences.toml", "--rate", 2500, "--fastest"), "holds per-channel sequences, which share no"),
        (("cases.csv", "--rate", 2500, "--force-limit", 4000), "a rig's force limits are per channel"),
    ]
    for args, message in cases:
        rc, err = in_process(capsys, "load", tmp_path / args[0], *args[1:], *base)
        assert rc == 2 and re.search(message, err), (args, err)
    # a controller for other channels; a one-channel controller; a rig controller without --rig
    swapped = tmp_path / "swapped.toml"
    swapped.write_text(decoupled.read_text().replace('"tip"', '"wingtip"').replace("channel.tip", "channel.wingtip"))
    rc, err = in_process(capsys, "load", tmp_path / "cases.csv", "--rig", rig, "--controller", swapped,
                         "--rate", 2500, "--out", out)
    assert rc == 2 and "the rig has root, inner, outer, tip" in err, err
    rc, err = in_process(capsys, "load", tmp_path / "cases.csv", "--controller", decoupled, "--rate", 2500,
                         "--out", out)
    assert rc == 2 and "load a rig with --rig RIG.toml" in err, err
    assert not out.exists()
