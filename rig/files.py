"""Writing a rig back as a rig file, and the same rig on other buses.

``rig_to_toml`` writes what :func:`rig.config.load_rig_file` reads (buses, channels with their
plants inline, the structure), so a rig built or changed in code can be handed to ``stand
emulate --rig`` and to the gateway as one file. ``on_private_loopback`` moves every bus of a rig
onto a loopback channel of its own (``udp_loopback:TAG-BUS``): what a demo, a benchmark or a test
uses so that it never touches a bench's interfaces nor another demo's buses.
"""
from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path

import numpy as np

from plant.config import model_to_toml

from .config import RigConfig


def on_private_loopback(rig: RigConfig, tag: str) -> RigConfig:
    """``rig`` with every bus on the loopback channel ``udp_loopback:{tag}-{bus name}``
    (nothing else changes; bit rates stay, so the bus budget counts the same buses)."""
    buses = [dataclasses.replace(b, spec=f"udp_loopback:{tag}-{b.name}") for b in rig.buses]
    return dataclasses.replace(rig, buses=buses, path=None)


def write_as_run(rig: RigConfig, path: Path, source, command: str) -> None:
    """Write ``rig`` (on private loopback buses) to ``path`` as the rig ``command`` ran, from
    the file ``source``, and make ``path`` its file."""
    path.write_text(rig_to_toml(rig, header=f"{source} as {command} ran it, on private loopback "
                                            "buses", path=path))
    rig.path = path


def rig_to_toml(rig: RigConfig, header: str = "", path: str | Path | None = None) -> str:
    """A rig file for ``rig`` (round-trips through :func:`rig.config.rig_from_mapping`);
    ``path``: where it will be written (a plant's plug-in files are named relative to it).
    The structure is written as the file gave it: K with the flow gains, or G (none when the
    channels' plants gave it), with its scheduled changes."""
    lines = [f"# {line}" for line in header.splitlines()]
    lines += [f"name = {json.dumps(rig.name)}", f"period_ms = {_num(rig.period_s * 1e3)}",
              f"bus_load_limit_pct = {_num(rig.bus_load_limit * 100)}",
              f"heartbeat_ms = {int(rig.heartbeat_ms)}"]
    structure = rig.structure_from in ("G", "K")     # else the plants' own g is G's diagonal
    for b in rig.buses:
        lines += ["", "[[bus]]", f"name = {json.dumps(b.name)}", f"spec = {json.dumps(b.spec)}",
                  f"bitrate = {int(b.bitrate)}"]
        if b.fd:
            lines += ["fd = true", f"data_bitrate = {int(b.data_bitrate or b.bitrate)}"]
    for c in rig.channels:
        lines += ["", "[[channel]]", f"name = {json.dumps(c.name)}", f"bus = {json.dumps(c.bus)}",
                  f"valve_id = {int(c.valve_id)}", f"dynamometer_id = {int(c.dynamometer_id)}",
                  f"range_kgf = {_num(c.range_kgf)}"]
        if c.force_limit_kgf is not None:
            lines.append(f"force_limit_kgf = {_num(c.force_limit_kgf)}")
        if c.devices.path is not None:      # (the emulated pair is the default)
            lines.append(f"devices = {json.dumps(str(c.devices.path.resolve()))}")
        if c.plant is not None:
            lines += _plant_lines(c.plant, path, with_g=not structure)
    if structure or rig.changes:
        lines += ["", "[structure]"]
        if rig.structure_from == "K" and rig.K is not None:
            gains = np.diag(rig.G) / np.diag(rig.K)
            lines.append("K = " + _matrix(rig.K))
            lines.append("flow_gain_mm_per_pct_s = [" + ", ".join(_num(v) for v in gains) + "]")
        elif structure:
            lines.append("G = " + _matrix(rig.G))
    for c in rig.changes:
        lines += ["", "[[structure.change]]", f"channel = {json.dumps(rig.names[c.channel])}",
                  f"stiffness_factor = {_num(c.stiffness_factor)}", f"from_s = {_num(c.from_s)}",
                  f"ramp_s = {_num(c.ramp_s)}"]
    return "\n".join(lines) + "\n"


def _plant_lines(plant, path: str | Path | None, with_g: bool) -> list[str]:
    """A channel's plant as ``[channel.plant]`` tables: the plant file's tables one level
    down (a model file's text, its headers moved under ``channel.plant``); g only ``with_g``
    (else the structure's diagonal gives it)."""
    text = model_to_toml(plant.model, path=path)
    out = ["[channel.plant]"]
    for line in text.splitlines():
        m = re.match(r"^\[(.+)\]$", line)
        if m:
            out.append(f"[channel.plant.{m.group(1)}]")
        elif with_g or not line.startswith("g = "):
            out.append(line)
    if plant.sensor:
        out.append("[channel.plant.sensor]")
        out += [f"{k} = {_num(v)}" for k, v in plant.sensor.items()]
    if plant.initial_force_kgf:
        out += ["[channel.plant.initial]", f"force_kgf = {_num(plant.initial_force_kgf)}"]
    return [line for line in out if line != ""]


def _matrix(m: np.ndarray) -> str:
    return "[" + ",\n     ".join("[" + ", ".join(_num(v) for v in row) + "]" for row in m) + "]"


def _num(v: float) -> str:
    v = float(v)
    if not math.isfinite(v):
        raise ValueError(f"a rig file holds finite numbers only, not {v}")
    return repr(v)
