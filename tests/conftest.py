"""Shared fixtures: private bus channels and emulator processes (plain helpers: tests/support/)."""
from __future__ import annotations

import itertools
import os
import uuid

import pytest

from plant.config import PlantConfig
from plant_emulator.process import EmulatorProcess, RigEmulatorProcess
# every capture an end-to-end test leaves is read by tshark's CANopen dissector after it
from tests.support.wire_plugin import pytest_runtest_setup, pytest_runtest_teardown, wire_summary  # noqa: F401

_counter = itertools.count()


def pytest_collection_modifyitems(config, items):
    """A test in user-mode Linux runs alone too (one UML at a time, on the wall clock)."""
    for item in items:
        if item.get_closest_marker("uml") is not None:
            item.add_marker(pytest.mark.serial)


@pytest.fixture
def channel() -> str:
    """A loopback-bus channel no other test (or developer) uses."""
    return f"t{os.getpid()}-{next(_counter)}-{uuid.uuid4().hex[:6]}"


@pytest.fixture
def bus_spec(channel: str) -> str:
    return f"udp_loopback:{channel}"


@pytest.fixture
def start_emulator(bus_spec):
    """Factory: start ``stand emulate`` as a real separate process on this test's bus."""
    started: list[EmulatorProcess] = []

    def start(config: PlantConfig | None = None, lockstep: bool = True, seed: int | None = 1,
              extra_args: list[str] | None = None, bus: str | None = None) -> EmulatorProcess:
        proc = EmulatorProcess(bus or bus_spec, config, lockstep=lockstep, seed=seed, extra_args=extra_args)
        proc.start()
        started.append(proc)
        return proc

    yield start
    for proc in started:
        proc.stop()


@pytest.fixture
def start_rig_emulator(tmp_path, channel):
    """Factory: write a rig file (the example rig on this test's private loopback buses
    ``{channel}-can0``/``-can1`` unless ``text`` is given; ``quiet``: its dynamometers without
    noise) and start ``stand emulate --rig`` on it as a real separate process; returns the
    file's path."""
    from tests.support.rig import example_rig_text, write_rig
    started: list[RigEmulatorProcess] = []

    def start(text: str | None = None, lockstep: bool = True, quiet: bool = False,
              seed: int | None = 3, extra_args: list[str] | None = None):
        path = write_rig(tmp_path / f"rig{len(started)}.toml", text or example_rig_text(channel, quiet))
        started.append(RigEmulatorProcess(path, lockstep=lockstep, seed=seed, extra_args=extra_args).start())
        return path

    yield start
    for proc in started:
        proc.stop()


@pytest.fixture
def isolated_catalogue():
    """A test that loads plug-ins leaves the effect catalogue as it found it."""
    from tests.support.plugins import isolated_catalogue as isolated
    with isolated():
        yield


def pytest_terminal_summary(terminalreporter):
    """Each documentation block's outcome and time (tests/test_docs.py records them), and what
    the wire check read (tests/support/wire_plugin.py)."""
    rows = []
    reports = [r for rs in terminalreporter.stats.values() for r in rs]
    for report in reports:
        if getattr(report, "when", None) == "call":
            rows += dict(getattr(report, "user_properties", ())).get("doc_blocks", [])
    if rows:
        terminalreporter.write_sep("-", "documentation blocks (tests/test_docs.py)")
        for row in rows:
            terminalreporter.write_line(row)
    wire = wire_summary(reports)
    if wire:
        terminalreporter.write_sep("-", "the wire, read by tshark's CANopen dissector")
        for line in wire:
            terminalreporter.write_line(line)
