"""User mistakes give one clear message and exit code 2, never a traceback."""
from __future__ import annotations

import re
import subprocess
import sys
import threading

import can
import pytest

from standbus.spec import open_bus


def stand(*args, timeout=60):
    res = subprocess.run([sys.executable, "-m", "stand", *args], capture_output=True, text=True, timeout=timeout)
    assert "Traceback" not in res.stderr + res.stdout, res.stderr
    return res


def test_unknown_interface(tmp_path):
    res = stand("run", "meander", "--bus", "nosuch:x", "--out", str(tmp_path / "r"))
    assert res.returncode == 2
    assert "unknown CAN interface 'nosuch'" in res.stderr and "socketcan" in res.stderr


def test_socketcan_device_that_does_not_exist(tmp_path):
    res = stand("run", "meander", "--bus", "socketcan:nosuchcan0", "--out", str(tmp_path / "r"))
    assert res.returncode == 2 and "cannot open CAN bus 'socketcan:nosuchcan0'" in res.stderr


def test_node_that_never_boots_is_named(bus_spec, tmp_path):
    res = stand("run", "meander", "--bus", bus_spec, "--boot-timeout", "0.5", "--out", str(tmp_path / "r"))
    assert res.returncode == 2
    assert "node 1 did not boot" in res.stderr and "nothing heard from it" in res.stderr


def test_node_that_boots_but_never_answers_sdo_is_named_with_the_timeout(bus_spec, tmp_path):
    # two nodes that answer an NMT reset with their boot-up message, and nothing else
    bus = open_bus(bus_spec)
    stop = threading.Event()

    def nodes() -> None:
        while not stop.is_set():
            msg = bus.recv(0.05)
            if msg is not None and msg.arbitration_id == 0 and msg.data[0] == 0x81:
                for nid in (1, 2):
                    bus.send(can.Message(arbitration_id=0x700 + nid, data=[0], is_extended_id=False))

    thread = threading.Thread(target=nodes, daemon=True)
    thread.start()
    try:
        res = stand("run", "meander", "--bus", bus_spec, "--sdo-timeout", "150", "--out", str(tmp_path / "r"))
    finally:
        stop.set()
        thread.join(2)
        bus.shutdown()
    assert res.returncode == 2, res.stderr
    assert ("valve node 1: cannot read its identity (0x1018) over SDO: No SDO response received "
            "within 150 ms") in res.stderr, res.stderr
    assert "--sdo-timeout" in res.stderr and not (tmp_path / "r").exists()


@pytest.mark.e2e
def test_wrong_identity_is_refused(bus_spec, start_emulator, tmp_path):
    # swapped node ids: node 1 answers as the dynamometer
    start_emulator(None, lockstep=True, extra_args=["--valve-id", "2", "--dynamometer-id", "1"])
    res = stand("run", "meander", "--bus", bus_spec, "--lockstep", "--out", str(tmp_path / "r"))
    assert res.returncode == 2
    assert "node 1 is not the expected valve" in res.stderr and "swapped node ids" in res.stderr


@pytest.mark.parametrize("args,message", [
    (["--amplitude-pct", "150"], "amplitude_pct = 150.0 % is out of range"),
    (["--period-s", "-1"], "period_s = -1.0 s is out of range"),
    (["--cycles", "2.5"], "cycles = 2.5 is out of range: it must be an integer"),
])
def test_experiment_parameter_out_of_range(args, message, tmp_path):
    res = stand("run", "meander", *args, "--out", str(tmp_path / "r"))
    assert res.returncode == 2 and message in res.stderr


def test_lockstep_against_a_realtime_stand_is_refused(bus_spec, start_emulator, tmp_path):
    start_emulator(None, lockstep=False)
    res = stand("run", "meander", "--bus", bus_spec, "--lockstep", "--out", str(tmp_path / "r"))
    assert res.returncode == 2 and "this stand runs in real time" in res.stderr


def test_existing_run_is_never_overwritten(bus_spec, start_emulator, tmp_path):
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "run.json").write_text("{}")
    start_emulator(None, lockstep=True)
    res = stand("run", "meander", "--bus", bus_spec, "--lockstep", "--out", str(tmp_path / "r"))
    assert res.returncode == 2 and "already holds a run" in res.stderr


def test_diagnose_max_effects_out_of_range(tmp_path):
    res = stand("diagnose", str(tmp_path / "none.csv"), "--stepwise", "--max-effects", "0")
    assert res.returncode == 2 and "--max-effects 0 is out of range: give 1 or more" in res.stderr
    res = stand("diagnose", str(tmp_path / "none.csv"), "--jobs", "0")
    assert res.returncode == 2 and "--jobs 0 is out of range: give 1 or more" in res.stderr


def test_every_commands_help_prints_cleanly():
    """Each subcommand's help renders (a stray ``%`` in a help string is an argparse crash) and
    shows no escaped ``%%``: descriptions are not %-formatted, help strings are."""
    import argparse

    from stand.cli import build_parser
    parser = build_parser()
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    pages = {name: sub.format_help() for name, sub in subparsers.choices.items()}
    for name, sub in subparsers.choices.items():     # stand run's experiments too
        for a in sub._actions:
            if isinstance(a, argparse._SubParsersAction):
                pages.update({f"{name} {n}": s.format_help() for n, s in a.choices.items()})
    assert {"fit", "compare", "diagnose", "estimate", "campaign", "run", "decode", "design", "load",
            "run meander", "run relay"} <= set(pages)
    assert not [name for name, page in pages.items() if "%%" in page]
    # plain words: no reST literals or roles, no argparse dest-style metavars (X_AMPLITUDE_PCT)
    assert not [name for name, page in pages.items() if "``" in page or ":mod:" in page]
    assert not [name for name, page in pages.items() if re.search(r"\bX_[A-Z]", page)]


def test_the_help_imports_no_numerics_and_no_can_stack():
    """`stand --help` and `stand X --help` stay snappy: scipy, pyarrow, matplotlib, canopen,
    python-can's io and numpy are imported only by the commands that run."""
    heavy = ["scipy", "pyarrow", "matplotlib", "canopen", "can", "can.io", "numpy", "cantools"]
    code = ("import sys, argparse\n"
            "from stand.cli import build_parser\n"
            "p = build_parser()\n"
            "sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))\n"
            "for s in sub.choices.values(): s.format_help()\n"
            f"print(sorted(m for m in {heavy!r} if m in sys.modules))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "[]", f"imported for --help: {res.stdout}"


@pytest.mark.slow
def test_a_stepwise_diagnosis_into_a_log_writes_a_line_per_step_and_no_bar(tmp_path):
    """Progress bars belong on a terminal; a log (stderr not a tty) gets one line per step."""
    import numpy as np

    from analysis.records.synthetic import meander
    from plant import PlantModel
    rec = meander(PlantModel.from_spec("base+reversal", {"g": 120.0, "tau": 0.05}), (5.0, 20.0),
                  seed=1)
    files = []
    for i, r in enumerate(rec if isinstance(rec, list) else [rec]):
        f = tmp_path / f"m{i}.csv"
        np.savetxt(f, np.c_[r.t, r.u, r.y], delimiter=",", header="t,u,y", comments="")
        files.append(str(f))
    res = stand("diagnose", *files, "--stepwise", "--max-effects", "1", timeout=300)
    assert res.returncode == 0, res.stderr
    assert "\r" not in res.stderr
    steps = [ln for ln in res.stderr.splitlines() if ln.startswith("diagnose --stepwise:")]
    assert 1 <= len(steps) <= 3 and all("diagnosing base" in ln for ln in steps), res.stderr
