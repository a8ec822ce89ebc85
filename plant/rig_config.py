"""Rig model files: the coupled plant of a rig as identified, G plus each channel's model (TOML).

What ``stand estimate --save`` and ``stand diagnose --rig-model ... --save`` write and what
``--rig-model`` reads; it loads as a :class:`~plant.rig.RigModel`::

    # from runs/sim: stand estimate (simultaneous), ...
    channels = ["root_left", "root_right"]      # the order of G's rows and columns
    plugins = ["ripple.py"]                      # effects of one's own, as a model file names them

    [structure]
    G = [[120.0, -30.0],                         # kgf/(%·s); row i: channel i's force,
         [-36.0, 100.0]]                         # column j: channel j's valve; G_ii its own g

    [channel.root_left]                          # a model file's tables, per channel:
    model = "base+reversal"                      # its effects
    [channel.root_left.base]                     # tau, delta (g is G's diagonal; if given it
    tau = 0.04                                   # must agree)
    delta = 8.0
    [channel.root_left.effects.reversal]
    boost = 1.5

    [channel.root_right]
    model = "base"
    [channel.root_right.base]
    tau = 0.05

A rig file (``rig.toml``, :mod:`rig.config`) says what the rig *is* (buses, nodes, limits, and
for the emulator the plants); a rig model file says what its plant was *found to be*. Every
mistake is one :class:`~plant.params.ModelError` naming the file, the table and what to do.
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .config import _num, load_named_plugins, model_from_mapping, plugin_sources, read_toml
from .model import BASE_PARAMS
from .params import ModelError
from .rig import RigModel

NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_-]*$")


def load_rig_model(path: str | Path) -> RigModel:
    """The rig model a rig model file describes (module docstring)."""
    path = Path(path)
    return rig_model_from_mapping(read_toml(path), str(path), path.parent)


def rig_model_from_mapping(data: Mapping[str, Any], where: str = "rig model",
                           base_dir: str | Path | None = None) -> RigModel:
    """Build a :class:`RigModel` from the tables of a parsed rig model file."""
    known = {"channels", "plugins", "structure", "channel"}
    unknown = set(data) - known
    if unknown:
        raise ModelError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}; a rig model "
                         f"file has channels, plugins, [structure] G and a [channel.NAME] table "
                         "per channel")
    names = data.get("channels")
    if not isinstance(names, list) or not names or not all(
            isinstance(n, str) and NAME_RE.match(n) for n in names):
        raise ModelError(f"{where}: channels must list the channels' names in the order of G's "
                         f"rows, e.g. channels = [\"left\", \"right\"], got {names!r}")
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ModelError(f"{where}: channel(s) {', '.join(dupes)} listed twice in channels")
    n = len(names)
    structure = data.get("structure")
    if not isinstance(structure, Mapping) or "G" not in structure:
        raise ModelError(f"{where}: no [structure] G: give G as {n} rows of {n} numbers "
                         "(kgf/(%·s)), in the order of channels")
    extra = set(structure) - {"G"}
    if extra:
        raise ModelError(f"{where}: [structure] has unknown key(s) {', '.join(sorted(extra))}; "
                         "it holds G")
    try:
        G = np.array(structure["G"], dtype=float)
    except (TypeError, ValueError):
        raise ModelError(f"{where}: [structure] G must be {n} rows of {n} numbers") from None
    if G.shape != (n, n):
        raise ModelError(f"{where}: [structure] G is {'x'.join(map(str, G.shape)) or 'a number'}"
                         f", the file has {n} channel(s): give {n} rows of {n} numbers")
    if not np.all(np.isfinite(G)):
        raise ModelError(f"{where}: [structure] G has a value that is not a finite number (an "
                         "unknown column? identify it first: a meander on that channel)")
    if np.any(np.diag(G) <= 0):
        bad = [names[i] for i in np.flatnonzero(np.diag(G) <= 0)]
        raise ModelError(f"{where}: G's diagonal (each channel's own gain g) must be positive; "
                         f"it is not for {', '.join(bad)}")
    load_named_plugins(data, where, base_dir)
    tables = data.get("channel", {})
    if not isinstance(tables, Mapping):
        raise ModelError(f"{where}: 'channel' must hold a [channel.NAME] table per channel")
    missing = [nm for nm in names if nm not in tables]
    if missing:
        raise ModelError(f"{where}: no [channel.{missing[0]}] table"
                         + (f" (nor for {', '.join(missing[1:])})" if len(missing) > 1 else "")
                         + ": every channel listed needs its model")
    stray = [nm for nm in tables if nm not in names]
    if stray:
        raise ModelError(f"{where}: [channel.{stray[0]}] is not in channels = {names}")
    models = []
    for i, nm in enumerate(names):
        table = tables[nm]
        if not isinstance(table, Mapping):
            raise ModelError(f"{where}: channel.{nm} must be a table ([channel.{nm}])")
        here = f"{where}: [channel.{nm}]"
        model = model_from_mapping(table, here, base_dir)
        base = table.get("base", {})
        g = base.get("g") if isinstance(base, Mapping) else None
        if g is not None and not math.isclose(float(g), G[i, i], rel_tol=1e-9):
            raise ModelError(f"{here}: its base says g = {g:g} but G[{i + 1},{i + 1}] = "
                             f"{G[i, i]:g}: a channel's own gain is G's diagonal; leave g out "
                             "of the channel's table")
        models.append(model)
    return RigModel(models, G, names)


def rig_model_to_toml(rig: RigModel, header: str = "", path: str | Path | None = None) -> str:
    """Write a rig model back as a rig model file (round-trips through
    :func:`rig_model_from_mapping`); ``path``: where it will be written (plug-in files are named
    relative to it)."""
    lines = [f"# {line}" for line in header.splitlines()]
    sources: list[str] = []
    for m in rig.channels:
        for src in plugin_sources(m, Path(path).parent if path is not None else None):
            if src not in sources:
                sources.append(src)
    lines.append("channels = [" + ", ".join(json.dumps(n) for n in rig.names) + "]")
    if sources:
        lines.append("plugins = [" + ", ".join(json.dumps(s) for s in sources) + "]")
    lines += ["", "[structure]", "# kgf/(%·s); row i: channel i's force, column j: channel j's "
              "valve; the diagonal is each channel's own g", "G = ["]
    lines += ["    [" + ", ".join(_num(v) for v in row) + "]," for row in rig.G]
    lines.append("]")
    for nm, m in zip(rig.names, rig.channels):
        lines += ["", f"[channel.{nm}]", f'model = "{m.spec}"', f"[channel.{nm}.base]"]
        lines += [f"{p.name} = {_num(getattr(m, p.name))}    # {p.unit}, {p.doc}"
                  for p in BASE_PARAMS if p.name != "g"]
        for eff in m.effects:
            lines.append(f"[channel.{nm}.effects.{eff.name}]")
            lines += [f"{p.name} = {_num(eff.values[p.name])}    # {p.unit}, {p.doc}"
                      for p in eff.params]
    return "\n".join(lines) + "\n"
