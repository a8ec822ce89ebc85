"""Model files (a stand's and a rig's) and emulator configuration (TOML).

A model file (also the ``[base]``/``[effects.*]`` part of an emulator config)::

    [base]
    g = 120.0        # kgf/(%·s)
    tau = 0.05       # s
    delta = 8.0      # kgf/s

    [effects.reversal]   # one table per effect, keys are its parameters
    boost = 2.0
    decay = 0.15

    [effects.lag]
    enabled = false      # keep the numbers, switch the effect off

A model with effects of one's own names their plug-ins at the top (paths relative to the
file, or module names), so the file loads on its own (:mod:`plant.plugins`)::

    plugins = ["ripple.py"]
    model = "base+ripple"

An emulator config adds the measuring device and the start::

    [sensor]
    noise_kgf = 2.0
    resolution_kgf = 0.5
    range_kgf = 10000

    [initial]
    force_kgf = 0.0

**A rig model file** (:func:`load_rig_model`, :func:`rig_model_to_toml`): the coupled plant of
a rig as identified, G plus each channel's model; What ``stand estimate --save`` and ``stand diagnose --rig-model ... --save`` write and what
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
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from core.tomlfile import read_toml as core_read_toml

from .catalogue import CATALOGUE, effect_class
from .model import BASE_PARAMS, PlantModel
from .params import ModelError, Param
from .plugins import ORIGINS, load_installed, load_plugins
from .rig import RigModel
from .sensor import Dynamometer

#: The emulator's default plant: the paper's model with its reversal effect and a small trend.
DEFAULT_MODEL = "base+reversal"
DEFAULT_VALUES = {"g": 120.0, "tau": 0.05, "delta": 8.0}


def read_toml(path: str | Path) -> dict[str, Any]:
    """A model or emulator file, parsed; a :class:`ModelError` naming it when it cannot be."""
    return core_read_toml(path, ModelError)


def model_from_mapping(data: Mapping[str, Any], where: str = "model",
                       base_dir: str | Path | None = None, complete: bool = False) -> PlantModel:
    """Build a model from the ``[base]`` and ``[effects.NAME]`` tables of a parsed TOML file,
    after loading the plug-ins it names (``plugins``, relative to ``base_dir``). A parameter the
    file leaves out takes its default, unless ``complete`` (a model something is designed from:
    every value must be the stand's, so one left out is an error naming it)."""
    load_named_plugins(data, where, base_dir)
    base = _table(data, "base", where)
    known_base = {p.name for p in BASE_PARAMS}
    unknown = set(base) - known_base
    if unknown:
        raise ModelError(f"{where}: [base] has no key(s) {', '.join(sorted(unknown))}; "
                         f"known: g, tau, delta")
    values: dict[str, float] = dict(base)
    names: list[str] = []
    effects = _table(data, "effects", where)
    for name, table in effects.items():
        known_effect(name)  # validates the name
        if not isinstance(table, Mapping):
            raise ModelError(f"{where}: effects.{name} must be a table like [effects.{name}], "
                             f"got {table!r}")
        table = dict(table)
        enabled = table.pop("enabled", True)
        if not isinstance(enabled, bool):
            raise ModelError(f"{where}: effects.{name}.enabled must be true or false")
        if enabled:
            names.append(name)
            values.update({f"{name}.{k}": v for k, v in table.items()})
    if "model" in data:  # effects named only in `model = "..."` take their defaults
        listed = [p.strip() for p in str(data["model"]).split("+") if p.strip()]
        if listed[:1] != ["base"]:
            raise ModelError(f"{where}: model = {data['model']!r} must start with 'base'")
        disabled = [n for n in listed[1:] if n in effects and n not in names]
        if disabled:
            raise ModelError(f"{where}: {', '.join(disabled)} is listed in `model` but its "
                             "table says enabled = false")
        for n in listed[1:]:
            known_effect(n)
        names += [n for n in listed[1:] if n not in names]
    spec = "+".join(["base"] + names)
    if complete:
        missing = [p.name for p in BASE_PARAMS if p.name not in values]
        missing += [f"{n}.{p.name}" for n in names for p in effect_class(n).params if f"{n}.{p.name}" not in values]
        if missing:
            raise ModelError(f"{where}: no value for {', '.join(missing)}; a controller is designed from "
                             "the stand's identified values, not defaults: give every parameter of "
                             f"{spec} (stand fit --save and stand diagnose --stepwise --save write them all)")
    return PlantModel.from_spec(spec, values)


def known_effect(name: str) -> type:
    """The effect class of ``name``: the catalogue's, a plug-in's loaded before, or an installed
    package's (loaded now if the name is not known yet)."""
    if name not in CATALOGUE:
        load_installed()
    return effect_class(name)


def load_named_plugins(data: Mapping[str, Any], where: str,
                       base_dir: str | Path | None) -> list[str]:
    """Load the plug-ins a model file names: ``plugins = ["my_effect.py", "pkg.effects"]``."""
    sources = data.get("plugins", [])
    if isinstance(sources, str):
        sources = [sources]
    if not isinstance(sources, list) or not all(isinstance(x, str) for x in sources):
        raise ModelError(f"{where}: plugins must be a list of files or module names, e.g. "
                         f'plugins = ["my_effect.py"], got {sources!r}')
    return load_plugins(sources, base_dir)


def plugin_sources(model: PlantModel, relative_to: str | Path | None = None) -> list[str]:
    """What a model file must name for ``model``'s effects of one's own: their files
    (relative to ``relative_to`` when given) and modules; installed ones load themselves."""
    out: list[str] = []
    for eff in model.effects:
        org = ORIGINS.get(eff.name)
        if org is None or org.kind == "entry point":
            continue
        src = org.where
        if org.kind == "file" and relative_to is not None:
            src = os.path.relpath(src, Path(relative_to).resolve())
        if src not in out:
            out.append(src)
    return out


def _table(data: Mapping[str, Any], name: str, where: str) -> dict[str, Any]:
    value = data.get(name, {})
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ModelError(f"{where}: '{name}' must be a table ([{name}]), got {value!r}")
    return dict(value)


def load_model_file(path: str | Path, complete: bool = False) -> PlantModel:
    """The model a TOML model file describes (see :func:`model_from_mapping`)."""
    return model_from_mapping(read_toml(path), where=str(path), base_dir=Path(path).parent,
                              complete=complete)


def model_to_toml(model: PlantModel, header: str = "", path: str | Path | None = None) -> str:
    """Write a model back as a model file (round-trips through :func:`model_from_mapping`);
    ``path``: where it will be written (plug-in files are named relative to it)."""
    lines = [f"# {line}" for line in header.splitlines()]
    sources = plugin_sources(model, Path(path).parent if path is not None else None)
    if sources:
        lines.append("plugins = [" + ", ".join(json.dumps(s) for s in sources) + "]")
    lines.append(f'model = "{model.spec}"')
    lines.append("")
    lines.append("[base]")
    for p in BASE_PARAMS:
        lines.append(f"{p.name} = {_num(getattr(model, p.name))}    # {p.unit}, {p.doc}")
    for eff in model.effects:
        lines.append("")
        lines.append(f"[effects.{eff.name}]")
        for p in eff.params:
            lines.append(f"{p.name} = {_num(eff.values[p.name])}    # {p.unit}, {p.doc}")
    return "\n".join(lines) + "\n"


def _num(v: float) -> str:
    return repr(float(v)) if math.isfinite(v) else "nan"


#: ``[initial]`` keys: where the plant starts
INITIAL_PARAMS: tuple[Param, ...] = (
    Param("force_kgf", 0.0, -1e6, 1e6, "kgf", "force at the start"),
)


@dataclass
class PlantConfig:
    """What the emulator needs: the true model, the dynamometer and the initial force."""

    model: PlantModel = field(default_factory=lambda: PlantModel.from_spec(DEFAULT_MODEL, DEFAULT_VALUES))
    sensor: dict[str, float] = field(default_factory=dict)
    initial_force_kgf: float = 0.0

    def validate(self) -> "PlantConfig":
        """Raise :class:`ModelError` unless the emulator can run this (finite initial force in
        range, a valid sensor table); returns self."""
        for p in INITIAL_PARAMS:
            p.validate(getattr(self, "initial_" + p.name), "initial")
        self.dynamometer(seed=0)
        return self

    def dynamometer(self, seed: int | None) -> Dynamometer:
        return Dynamometer.from_mapping(self.sensor, seed=seed)

    def to_dict(self) -> dict[str, Any]:
        """The truth, as written into a run's ``truth.json`` (never read by the analysis)."""
        return {
            "model": self.model.spec,
            "params": self.model.params(),
            "sensor": {**{k: v for k, v in vars(Dynamometer()).items() if not k.startswith("_")
                          and k != "seed"}, **self.sensor},
            "initial_force_kgf": self.initial_force_kgf,
        }


def load_plant_config(path: str | Path | None = None, model_spec: str | None = None,
                      overrides: Mapping[str, Any] | None = None) -> PlantConfig:
    """Emulator configuration from an optional TOML file, an optional model spec (which effects)
    and ``--set NAME=VALUE`` overrides (``g``, ``reversal.boost``, ``sensor.noise_kgf``,
    ``initial.force_kgf``)."""
    if not path:
        return plant_config_from_mapping(None, "defaults", None, model_spec, overrides)
    return plant_config_from_mapping(read_toml(path), str(path), Path(path).parent, model_spec,
                                     overrides)


def plant_config_from_mapping(data: Mapping[str, Any] | None, where: str,
                              base_dir: str | Path | None = None, model_spec: str | None = None,
                              overrides: Mapping[str, Any] | None = None) -> PlantConfig:
    """Emulator configuration from the tables of a parsed plant file (``[base]``,
    ``[effects.NAME]``, ``[sensor]``, ``[initial]``; None: the default plant), then a model spec
    and overrides as :func:`load_plant_config` takes them."""
    unknown_tables = set(data or {}) - {"base", "effects", "sensor", "initial", "model", "plugins"}
    if unknown_tables:
        raise ModelError(f"{where}: unknown table(s) {', '.join(sorted(unknown_tables))}; "
                         "expected [base], [effects.NAME], [sensor], [initial]")
    if data is None:
        model, data = PlantModel.from_spec(DEFAULT_MODEL, DEFAULT_VALUES), {}
    else:
        model = model_from_mapping(data, where, base_dir)
    sensor = _table(data, "sensor", where)
    initial = _table(data, "initial", where)
    known_initial = {p.name for p in INITIAL_PARAMS}
    bad = set(initial) - known_initial
    if bad:
        raise ModelError(f"{where}: [initial] has no key(s) {', '.join(sorted(bad))}; "
                         f"known: {', '.join(sorted(known_initial))}")
    params = model.params()
    spec = model.spec
    if model_spec:
        spec = model_spec
        keep = PlantModel.from_spec(model_spec).params()
        params = {k: params.get(k, v) for k, v in keep.items()}
    for key, value in (overrides or {}).items():
        if key.startswith("sensor."):
            sensor[key.split(".", 1)[1]] = value
        elif key.startswith("initial."):
            name = key.split(".", 1)[1]
            if name not in known_initial:
                raise ModelError(f"--set {key}: [initial] has no key {name!r}; "
                                 f"known: {', '.join(sorted(known_initial))}")
            initial[name] = value
        else:
            params[key] = value
    model = PlantModel.from_spec(spec, params)
    force = INITIAL_PARAMS[0].validate(initial.get("force_kgf", 0.0), "initial")
    return PlantConfig(model=model, sensor=sensor, initial_force_kgf=force).validate()


# -- a rig's model file ------------------------------------------------------------------------
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
