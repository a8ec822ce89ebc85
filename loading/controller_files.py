"""Controller files (``stand design -o``, ``stand load --controller``): a one-channel stand's
(:data:`loading.design.SCHEMA`: ``[loop]``, ``[feedback]``, ``[model]``, ``[design]``) and a rig's
(:data:`loading.design.STATION_SCHEMA`: ``channels``, ``[loop]``, ``[structure] G``, a
``[channel.NAME]`` table per channel), both read as the station's
:class:`~loading.design.ControllerDesign`; and the rig models a design starts from."""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Sequence

import numpy as np

from core.errors import ParameterError
from plant import PlantModel
from plant.params import ModelError
from plant.rig import RigModel

from .design import (COMMAND_LIMIT_PCT, COUPLING_ERROR, FEEDBACKS, FEEDFORWARDS, ChannelDesign, ControllerDesign,
                     check_model)
from .margins import LoopMargins
from .programme import STAND

def read_rig_model(path: str | Path) -> tuple[RigModel, str]:
    """The rig model a design starts from, and where it came from: a rig model file
    (``stand estimate --save`` / ``stand diagnose --rig-model ... --save``: ``channels``,
    ``[structure] G``, a ``[channel.NAME]`` model each), or a rig file whose channels have
    plants (the emulator's truth: ``examples/rig.toml``). The one place that reads either."""
    from plant.config import read_toml
    path = Path(path)
    try:
        data = read_toml(path)
    except ModelError as exc:
        raise ParameterError(str(exc)) from None
    if isinstance(data.get("channel"), list):            # a rig file: [[channel]] tables
        from rig.config import RigError, load_rig_file
        try:
            rig = load_rig_file(path)
        except RigError as exc:
            raise ParameterError(str(exc)) from None
        lacking = [c.name for c in rig.channels if c.plant is None]
        if lacking:
            raise ParameterError(f"{path}: a rig file without plants for {', '.join(lacking)}; "
                                 "design from a rig model file (stand estimate RUNS --save, stand "
                                 "diagnose --rig-model ... --save) or a rig file with a plant per channel")
        return (RigModel([c.plant.model for c in rig.channels], rig.G, rig.names),
                f"{path.name} (the rig file's plants: the emulator's truth)")
    from plant.config import load_rig_model
    try:
        return load_rig_model(path), f"{path.name} (rig model file)"
    except ModelError as exc:
        raise ParameterError(str(exc)) from None


def is_rig_file(path: str | Path) -> bool:
    """True if ``path`` is a rig model file, a rig file or a rig controller file (TOML with
    ``channels`` or ``[[channel]]``), False for a one-channel model or controller file."""
    from plant.config import read_toml
    p = Path(path)
    if not p.is_file() or p.suffix.lower() != ".toml":
        return False
    try:
        data = read_toml(p)
    except ModelError:
        return False
    return "channels" in data or isinstance(data.get("channel"), list)


def load_controller(path: str | Path, period_s: float | None = None,
                    names: Sequence[str] | None = None) -> ControllerDesign:
    """A controller file, validated (module docstring): every value finite, every model
    complete, the period the loop's (if given). ``names``: the station's channels, if given: a
    rig's file must name them (in any order, put in the station's); a one-channel file drives a
    station of one channel (a one-channel stand's, :data:`~loading.programme.STAND`, unless
    named)."""
    from plant.config import read_toml
    path = Path(path)
    names = None if names is None else list(names)
    try:
        data = read_toml(path)
    except ModelError as exc:
        raise ParameterError(str(exc)) from None
    if "channels" not in data:
        if names is not None and len(names) > 1:
            raise ParameterError(f"{path}: not a rig controller file (no channels = [...]); a "
                                 "one-channel controller drives one stand: design the rig's with "
                                 "`stand design RIG-MODEL.toml -o FILE`")
        return ControllerDesign.of(_channel_design(path, data, period_s), names[0] if names else STAND)
    if names == [STAND]:
        raise ParameterError(f"{path} is a rig's controller (stand design RIG-MODEL.toml): load a rig "
                             "with --rig RIG.toml and a programme per channel")
    return _station_design(path, data, period_s, names)


def _station_design(path: Path, data: dict, period_s: float | None, names: list[str] | None) -> ControllerDesign:
    """A rig's controller file (module docstring), validated; its channels put in ``names``'s
    order (if given)."""
    from plant.config import load_named_plugins
    try:
        load_named_plugins(data, str(path), path.parent)
        file_names = [str(n) for n in data["channels"]]
        loop = data["loop"]
        G = np.array(data["structure"]["G"], float)
        des = data.get("design", {})
        chans = []
        for n in file_names:
            t = data["channel"][n]
            mdl = dict(t["model"])
            spec = str(mdl.pop("spec"))
            chans.append(ChannelDesign(
                period_s=float(loop["period_s"]), model_spec=spec,
                model_params={k: float(v) for k, v in mdl.items()},
                kp_pct_per_kgf=float(t["kp_pct_per_kgf"]), ti_s=float(t["ti_s"]),
                command_limit_pct=float(loop.get("command_limit_pct", COMMAND_LIMIT_PCT)),
                boost=float(t.get("boost", 1.0)), lambda_s=float(t.get("lambda_s", math.nan))))
        stated = [LoopMargins(str(m["label"]), [float(f) for f in m["factors"]], float(m["coupling_error"]),
                              float(m["gain_margin"]), float(m["phase_margin_deg"]), float(m["crossover_hz"]),
                              float(m["peak_sensitivity"])) for m in des.get("margins", [])]
        c = ControllerDesign(file_names, G, chans, float(loop["period_s"]),
                             float(loop.get("command_limit_pct", COMMAND_LIMIT_PCT)),
                             str(loop.get("feedback", "decoupled")), str(loop.get("feedforward", "rig")),
                             float(des.get("detuning", 1.0)), float(des.get("coupling_error", COUPLING_ERROR)),
                             stated)
    except KeyError as exc:
        raise ParameterError(f"{path}: no {exc.args[0]!r}; a rig controller file has channels, [loop] "
                             "period_s, [structure] G and a [channel.NAME] table per channel with "
                             "kp_pct_per_kgf, ti_s and [channel.NAME.model] (write one with `stand "
                             "design RIG-MODEL.toml -o FILE`)") from None
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{path}: a value is not a number ({exc})") from None
    except ModelError as exc:
        raise ParameterError(f"{path}: {exc}") from None
    n = len(file_names)
    if G.shape != (n, n) or not np.all(np.isfinite(G)):
        raise ParameterError(f"{path}: [structure] G must be {n} rows of {n} finite numbers")
    if c.feedback not in FEEDBACKS or c.feedforward not in FEEDFORWARDS:
        raise ParameterError(f"{path}: [loop] feedback is one of {', '.join(FEEDBACKS)} and feedforward "
                             f"one of {', '.join(FEEDFORWARDS)}")
    for name, ch in zip(file_names, c.channels):
        where = f"{path}: [channel.{name}]"
        _check_channel(ch, where, f"{where}.model")
        if not math.isclose(ch.model.g, G[file_names.index(name)][file_names.index(name)], rel_tol=1e-9):
            raise ParameterError(f"{where}: its model's g = {ch.model.g:g} is not G's diagonal "
                                 f"{G[file_names.index(name)][file_names.index(name)]:g}")
    if not (c.period_s > 0 and 0 < c.command_limit_pct <= 100):
        raise ParameterError(f"{path}: period_s must be positive and command_limit_pct from 0 to 100")
    if period_s is not None and abs(c.period_s - period_s) > 1e-9:
        raise ParameterError(f"{path} was designed for a period of {c.period_s * 1e3:g} ms but the loop "
                             f"runs at {period_s * 1e3:g} ms; design it again with "
                             f"`stand design RIG-MODEL --period-ms {period_s * 1e3:g}`")
    if names is None:
        return c
    if sorted(names) != sorted(file_names):
        raise ParameterError(f"{path} is for the channels {', '.join(file_names)}; the rig has "
                             f"{', '.join(names)}")
    order = [file_names.index(nm) for nm in names]
    return replace(c, names=names, G=G[np.ix_(order, order)], channels=[c.channels[i] for i in order])


def _channel_design(path: Path, data: dict, period_s: float | None) -> ChannelDesign:
    """A one-channel stand's controller file, validated: its period the loop's (if given),
    every value finite."""
    from plant.config import load_named_plugins
    try:
        loop, fb, mdl = data["loop"], data["feedback"], dict(data["model"])
        spec = mdl.pop("spec")
        load_named_plugins({"plugins": mdl.pop("plugins", [])}, f"{path} [model]", path.parent)
        c = ChannelDesign(period_s=float(loop["period_s"]), model_spec=str(spec),
                          model_params={k: float(v) for k, v in mdl.items()},
                          kp_pct_per_kgf=float(fb["kp_pct_per_kgf"]), ti_s=float(fb["ti_s"]),
                          command_limit_pct=float(loop.get("command_limit_pct", COMMAND_LIMIT_PCT)),
                          feedforward=bool(loop.get("feedforward", True)),
                          boost=float(data.get("design", {}).get("boost", 1.0)),
                          lambda_s=float(data.get("design", {}).get("lambda_s", math.nan)))
    except KeyError as exc:
        raise ParameterError(f"{path}: no {exc.args[0]!r}; a controller file has [loop] period_s, "
                             "[feedback] kp_pct_per_kgf and ti_s, [model] spec and its parameters "
                             "(write one with `stand design MODEL.toml -o FILE`)") from None
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{path}: a value is not a number ({exc})") from None
    for name, v in (("period_s", c.period_s), ("command_limit_pct", c.command_limit_pct)):
        if not (v > 0 and math.isfinite(v)):
            raise ParameterError(f"{path}: {name} = {v} must be a positive number")
    if c.command_limit_pct > 100:
        raise ParameterError(f"{path}: command_limit_pct = {c.command_limit_pct} is over 100 %")
    _check_channel(c, str(path), f"{path}: [model]")
    if period_s is not None and abs(c.period_s - period_s) > 1e-9:
        raise ParameterError(f"{path} was designed for a period of {c.period_s * 1e3:g} ms but the loop "
                             f"runs at {period_s * 1e3:g} ms; design it again with "
                             f"`stand design MODEL --period-ms {period_s * 1e3:g}`")
    return c


def _check_channel(c: ChannelDesign, where: str, model_table: str) -> None:
    """A channel's controller as a file gives it (``where``; ``model_table``: the table of its
    model): every parameter of its model given (a value left out would silently be the default
    stand's), its model's values finite, its PI's gains positive."""
    try:
        needed = set(PlantModel.from_spec(c.model_spec).params())
    except ModelError as exc:
        raise ParameterError(f"{where}: {exc}") from None
    missing = sorted(needed - set(c.model_params))
    if missing:
        raise ParameterError(f"{model_table} lacks {', '.join(missing)} of {c.model_spec}; every "
                             "parameter of the model must be given (stand design writes them all)")
    for key, v in (("kp_pct_per_kgf", c.kp_pct_per_kgf), ("ti_s", c.ti_s)):
        if not (v > 0 and (math.isfinite(v) or key == "ti_s" and v == math.inf)):
            raise ParameterError(f"{where}: {key} = {v} must be a positive number")
    try:
        check_model(c.model, where)
    except ModelError as exc:
        raise ParameterError(f"{where}: {exc}") from None
