"""Start ``stand emulate`` as a separate process and wait until it is on the bus.

Used by ``stand demo``, ``stand campaign``, the end-to-end tests and the benchmarks::

    with EmulatorProcess("udp_loopback:demo-1", config, lockstep=True, seed=1) as emu:
        ...   # the gateway talks to it over the bus

A rig (``stand emulate --rig RIG.toml``: one process serving every bus of the rig)::

    with RigEmulatorProcess("rig.toml", lockstep=True, seed=1) as emu:
        ...   # every bus is served; emu.truth() is the rig's truth.json
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any, Mapping

from plant.config import PlantConfig, model_to_toml

READY = "emulator ready"


def config_to_toml(config: PlantConfig) -> str:
    """An emulator config file for ``config`` (model, sensor, initial force)."""
    text = model_to_toml(config.model, header="emulator configuration written by hydrostand")
    if config.sensor:
        text += "\n[sensor]\n" + "".join(f"{k} = {float(v)!r}\n" for k, v in config.sensor.items())
    text += f"\n[initial]\nforce_kgf = {float(config.initial_force_kgf)!r}\n"
    return text


def serve_until_signalled(make_stand, bus_spec: str | Mapping[str, str], ready_line):
    """Run an emulated stand or rig in *this* process (the body of ``stand emulate`` and
    ``stand replay --as-plant``) until SIGINT or SIGTERM: open the bus (or every bus of
    ``{name: spec}``), build the stand with ``make_stand(bus)`` (or ``make_stand({name:
    bus})``), start it, print ``ready_line(stand)`` (the line :class:`EmulatorProcess` waits
    for: every bus is served by then), then stop it and close the buses whatever happens.
    Returns the stopped stand."""
    from standbus import open_bus

    specs = {None: bus_spec} if isinstance(bus_spec, str) else dict(bus_spec)
    buses: dict = {}
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        for name, spec in specs.items():
            buses[name] = open_bus(spec)
        stand = make_stand(buses[None] if isinstance(bus_spec, str) else buses)
        try:
            stand.start()
            print(f"{READY}: {ready_line(stand)}", flush=True)
            while not stop.wait(0.5):
                pass
        finally:
            stand.stop()
    finally:
        for bus in buses.values():
            bus.shutdown()
    return stand


class EmulatorProcess:
    """A ``stand emulate`` child process; terminated (SIGTERM, then SIGKILL) on exit."""

    def __init__(self, bus: str, config: PlantConfig | None = None, lockstep: bool = True,
                 seed: int | None = 1, extra_args: list[str] | None = None,
                 ready_timeout_s: float = 20.0, devices=None) -> None:
        self.bus = bus
        self.config = config
        #: the devices to impersonate: a device file's path, or a DeviceSet (None: the default)
        self.devices = getattr(devices, "path", devices)
        self.lockstep = lockstep
        self.seed = seed
        self.extra_args = list(extra_args or [])
        self.ready_timeout_s = ready_timeout_s
        self.proc: subprocess.Popen | None = None
        self.output: list[str] = []
        self._tmp: tempfile.TemporaryDirectory | None = None

    def command(self) -> list[str]:
        cmd = [sys.executable, "-m", "stand", "emulate", "--bus", self.bus]
        if self.lockstep:
            cmd.append("--lockstep")
        if self.seed is not None:
            cmd += ["--seed", str(self.seed)]
        if self.config is not None:
            self._tmp = tempfile.TemporaryDirectory(prefix="stand-emulator-")
            path = Path(self._tmp.name) / "plant.toml"
            path.write_text(config_to_toml(self.config))
            cmd += ["--config", str(path)]
        if self.devices is not None:
            cmd += ["--devices", str(self.devices)]
        return cmd + self.extra_args

    def start(self) -> "EmulatorProcess":
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(self.command(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, env=env)
        ready = threading.Event()

        def pump() -> None:
            for line in self.proc.stdout:
                self.output.append(line.rstrip("\n"))
                if READY in line:
                    ready.set()
            ready.set()

        threading.Thread(target=pump, name="emulator-output", daemon=True).start()
        if not ready.wait(self.ready_timeout_s) or self.proc.poll() is not None:
            out = "\n".join(self.output[-20:])
            self.stop()
            raise RuntimeError(f"the emulator did not start (exit code {self.proc.returncode}):\n{out}")
        return self

    @property
    def pid(self) -> int:
        return self.proc.pid

    def signal(self, sig: int) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.kill(self.proc.pid, sig)

    def stop(self, timeout_s: float = 5.0) -> int | None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGCONT)  # in case a test froze it
            self.proc.terminate()
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        return self.proc.returncode if self.proc is not None else None

    def __enter__(self) -> "EmulatorProcess":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


class RigEmulatorProcess(EmulatorProcess):
    """``stand emulate --rig RIG.toml`` as a child process: ready when every bus of the rig is
    served (every node booted on its bus)."""

    def __init__(self, rig: str | Path, lockstep: bool = True, seed: int | None = 1,
                 extra_args: list[str] | None = None, ready_timeout_s: float = 30.0,
                 changes: list[str] | tuple[str, ...] = ()) -> None:
        super().__init__("", None, lockstep=lockstep, seed=seed, extra_args=extra_args,
                         ready_timeout_s=ready_timeout_s)
        self.rig = Path(rig)
        #: the structure's changes on the command line (``--change``, e.g. "inner:0.97@600")
        self.changes = list(changes)

    def command(self) -> list[str]:
        cmd = [sys.executable, "-m", "stand", "emulate", "--rig", str(self.rig)]
        if self.lockstep:
            cmd.append("--lockstep")
        if self.seed is not None:
            cmd += ["--seed", str(self.seed)]
        for change in self.changes:
            cmd += ["--change", change]
        return cmd + self.extra_args

    def truth(self) -> dict[str, Any]:
        """The emulated rig's truth, as a run's ``truth.json`` holds it
        (:func:`rig.emulated.rig_truth`), the changes given on its command line included."""
        from rig.config import load_rig_file, parse_change, with_changes
        from rig.emulated import rig_truth
        rig = load_rig_file(self.rig)
        return rig_truth(with_changes(rig, [parse_change(c, rig) for c in self.changes]))
