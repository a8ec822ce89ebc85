"""Effects as plug-ins: a user's effect classes, loaded from a file, a directory, a module or an
installed package, and checked before anything runs.

A plug-in is Python code that defines one or more subclasses of :class:`plant.Effect` (with a
``name``, a ``stage``, its ``params`` and the hook of its stage; ``@plant.register`` above the
class is optional here). Once loaded, an effect is part of the catalogue: every command that
takes a model takes it (``--model base+my_effect``), ``stand diagnose`` offers it as a
candidate, the emulator runs it, ``stand effects`` lists it with where it came from::

    stand effects --new ripple --stage disturbance > ripple.py   # a commented skeleton
    stand diagnose data.csv --effects ripple.py
    stand emulate --effects ripple.py --model base+ripple --set ripple.frequency=3

Sources, as ``--effects`` takes them (repeatable):

* ``FILE.py``: one file;
* ``DIR``: every ``*.py`` in it (not those starting with ``_``), in name order;
* ``MODULE``: an importable module name, e.g. ``mypackage.effects``;
* installed packages: entry points of the group ``hydrostand.effects`` (each naming a module or
  an effect class), loaded by every command that takes a model (:func:`load_installed`).

A model file names the plug-ins it needs (``plugins = ["ripple.py"]``, relative to the file),
so a saved model reloads on its own (:mod:`plant.config`).

Every effect is checked when it is loaded (:func:`check_effect`): a valid name that is not the
catalogue's, parameters with finite defaults inside finite bounds, the hook of its stage, and
that hook called on a small block returning finite values of the right shape. A plug-in that
fails (a syntax error, an import error, a wrong shape, NaN) raises one :class:`PluginError`
naming the file, the effect and what is wrong; nothing of it stays registered.
"""
from __future__ import annotations

import hashlib
import importlib
import importlib.machinery
import importlib.util
import inspect
import keyword
import math
import re
import sys
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from .effects import CATALOGUE, Effect, Stage
from .params import ModelError, Param

#: the entry-point group installed packages declare their effects under
ENTRY_POINT_GROUP = "hydrostand.effects"
#: the package under which plug-in files are imported (``sys.modules`` names)
MODULE_PREFIX = "hydrostand_plugins"
NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")


class PluginError(ModelError):
    """A plug-in cannot be used; the message names the file, the effect and what is wrong."""


@dataclass(frozen=True)
class Origin:
    """Where an effect came from: ``kind`` is ``file``, ``module`` or ``entry point``; ``where``
    the file's path, the module's name or ``distribution: entry point``."""

    kind: str
    where: str

    def __str__(self) -> str:
        return f"{self.kind} {self.where}"


#: effect name -> where it came from (catalogue effects are not listed)
ORIGINS: dict[str, Origin] = {}
#: source key (resolved path or module name) -> the effects it defined
_LOADED: dict[str, list[str]] = {}
#: what the checks found worth saying but not refusing (a non-finite result at a bound)
WARNINGS: list[str] = []
_installed_loaded = False


def origin(name: str) -> str:
    """``catalogue`` or where a plug-in effect came from."""
    o = ORIGINS.get(name)
    return "catalogue" if o is None else str(o)


def is_plugin(name: str) -> bool:
    return name in ORIGINS


# ------------------------------------------------------------------------------------------
# loading
# ------------------------------------------------------------------------------------------
def load_plugins(sources: Iterable[str | Path], base_dir: str | Path | None = None) -> list[str]:
    """Load every source (file, directory or module name; relative paths from ``base_dir``,
    default the current directory) and return the names of the effects they define. A source
    loaded before is not loaded again."""
    names: list[str] = []
    for source in sources:
        names += load_source(source, base_dir)
    return names


def load_source(source: str | Path, base_dir: str | Path | None = None) -> list[str]:
    text = str(source).strip()
    if not text:
        raise PluginError("--effects needs a file, a directory or a module name, got ''")
    listed = [part.strip() for part in text.split(",")]
    if all(part in CATALOGUE for part in listed):
        raise PluginError(f"--effects {text}: --effects loads effects of your own (a .py file, a "
                          f"directory or a module); {', '.join(listed)} "
                          f"{'is' if len(listed) == 1 else 'are'} in the catalogue already (to "
                          f"try only some effects in stand diagnose: --candidates {text})")
    path = Path(text).expanduser()
    if base_dir is not None and not path.is_absolute():
        path = Path(base_dir) / path
    if path.is_dir():
        files = sorted(p for p in path.glob("*.py") if not p.name.startswith("_"))
        if not files:
            raise PluginError(f"effect plug-ins: directory {path} has no .py files")
        return [n for f in files for n in _load_file(f)]
    if path.is_file():
        return _load_file(path)
    if text.endswith(".py") or "/" in text or "\\" in text:
        raise PluginError(f"effect plug-in {path} does not exist (give a .py file, a directory "
                          "of them or an importable module name)")
    if not all(part.isidentifier() for part in text.split(".")):
        raise PluginError(f"effect plug-in {text!r} is neither a file, a directory nor a module "
                          "name")
    return _load_module(text)


def _load_file(path: Path) -> list[str]:
    path = path.resolve()
    key = str(path)
    if key in _LOADED:
        return list(_LOADED[key])
    digest = hashlib.sha1(key.encode()).hexdigest()[:8]
    stem = re.sub(r"\W", "_", path.stem)
    modname = f"{MODULE_PREFIX}.{stem}_{digest}"
    where = str(path)

    def run() -> object:
        if MODULE_PREFIX not in sys.modules:   # a namespace for the plug-ins' modules
            pkg = importlib.util.module_from_spec(importlib.machinery.ModuleSpec(MODULE_PREFIX, None))
            pkg.__path__ = []
            sys.modules[MODULE_PREFIX] = pkg
        spec = importlib.util.spec_from_file_location(modname, path)
        if spec is None or spec.loader is None:
            raise PluginError(f"effect plug-in {where}: cannot be imported as Python")
        module = importlib.util.module_from_spec(spec)
        sys.modules[modname] = module        # before running it: dataclasses, pickling
        try:
            spec.loader.exec_module(module)
        except BaseException:
            sys.modules.pop(modname, None)
            raise
        return module

    names = _register_from(run, Origin("file", where), where, path)
    _LOADED[key] = names
    return names


def _load_module(name: str) -> list[str]:
    if name in _LOADED:
        return list(_LOADED[name])
    names = _register_from(lambda: importlib.import_module(name), Origin("module", name),
                           f"module {name}", None)
    _LOADED[name] = names
    return names


def load_installed() -> list[str]:
    """The effects of installed packages (entry points ``hydrostand.effects``), once."""
    global _installed_loaded
    if _installed_loaded:
        return [n for n, o in ORIGINS.items() if o.kind == "entry point"]
    _installed_loaded = True
    from importlib.metadata import entry_points
    names: list[str] = []
    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        dist = getattr(getattr(ep, "dist", None), "name", None) or "an installed package"
        label = f"{dist}: {ep.name} = {ep.value}"
        key = f"entry point {ep.value}"
        if key in _LOADED:
            continue

        def run(ep=ep) -> object:
            obj = ep.load()
            if inspect.isclass(obj):
                return _ClassHolder(obj)
            return obj

        found = _register_from(run, Origin("entry point", label),
                               f"installed plug-in {label} (entry point group "
                               f"{ENTRY_POINT_GROUP}; fix or uninstall the package)", None)
        _LOADED[key] = found
        names += found
    return names


class _ClassHolder:
    """An entry point that names one effect class: look at it as a module holding it."""

    def __init__(self, cls: type) -> None:
        self.__name__ = cls.__module__
        self.cls = cls


def _register_from(run, org: Origin, where: str, path: Path | None) -> list[str]:
    """Run ``run()`` (an import), register the effect classes it defined, check them; on any
    failure nothing it registered stays and one :class:`PluginError` says what went wrong."""
    before = dict(CATALOGUE)
    try:
        try:
            module = run()
        except PluginError:
            raise
        except ModelError as exc:      # plant.register refusing a name, a bad Param
            raise PluginError(f"effect plug-in {where}: {exc}{_line(exc, path)}") from None
        except SyntaxError as exc:
            raise PluginError(f"effect plug-in {where}: syntax error at line {exc.lineno}: "
                              f"{exc.msg}") from None
        except ImportError as exc:
            raise PluginError(f"effect plug-in {where}: cannot import it: {exc}"
                              f"{_line(exc, path)}") from None
        except Exception as exc:  # noqa: BLE001 - anything a user's module raises at import
            raise PluginError(f"effect plug-in {where}: raised {type(exc).__name__} when "
                              f"imported: {exc}{_line(exc, path)}") from None
        classes = _effect_classes(module)
        new = [n for n in CATALOGUE if n not in before]
        for cls in classes:           # defined but not decorated with @register
            if CATALOGUE.get(getattr(cls, "name", None)) is not cls:
                _register_checked(cls, where)
                new.append(cls.name)
        if not new:
            raise PluginError(f"effect plug-in {where} defines no effect: subclass plant.Effect "
                              "with a name, a stage, params and the stage's hook (see "
                              "`stand effects --new NAME --stage STAGE`)")
        warnings = [w for name in new for w in check_effect(CATALOGUE[name], where)]
    except BaseException:
        for name in [n for n in CATALOGUE if n not in before]:
            del CATALOGUE[name]
        raise
    for name in new:
        ORIGINS[name] = org
    WARNINGS.extend(warnings)
    return new


def _register_checked(cls: type[Effect], where: str) -> None:
    name = getattr(cls, "name", None)
    if not isinstance(name, str):
        raise PluginError(f"effect plug-in {where}: class {cls.__name__} has no name "
                          "(set name = \"my_effect\" in the class)")
    if name in CATALOGUE:
        other = ORIGINS.get(name)
        said = f"the {other} one" if other else "the catalogue's"
        raise PluginError(f"effect plug-in {where}: effect name {name!r} (class "
                          f"{cls.__name__}) is taken by {said}: choose another name")
    CATALOGUE[name] = cls


def _effect_classes(module: object) -> list[type[Effect]]:
    """The effect classes a module defines itself (not those it imports), in source order."""
    if isinstance(module, _ClassHolder):
        return [module.cls] if _is_effect_class(module.cls) else []
    modname = getattr(module, "__name__", None)
    out = [obj for obj in vars(module).values()
           if _is_effect_class(obj) and obj.__module__ == modname and "name" in vars(obj)]
    return sorted(out, key=lambda c: _source_line(c))


def _is_effect_class(obj: object) -> bool:
    return inspect.isclass(obj) and issubclass(obj, Effect) and obj is not Effect


def _source_line(cls: type) -> int:
    try:
        return inspect.getsourcelines(cls)[1]
    except (OSError, TypeError):
        return 0


def _line(exc: BaseException, path: Path | None) -> str:
    """`` (line N)`` of the innermost frame of ``exc`` in the plug-in's file, if any."""
    if path is None or exc.__traceback__ is None:
        return ""
    lines = [f.lineno for f in traceback.extract_tb(exc.__traceback__)
             if f.filename and Path(f.filename).resolve() == path]
    return f" (line {lines[-1]})" if lines else ""


# ------------------------------------------------------------------------------------------
# the check on load
# ------------------------------------------------------------------------------------------
#: the hook(s) each stage must override
STAGE_HOOKS = {
    Stage.VALVE: ("shape",),
    Stage.FLOW: ("gain",),
    Stage.DISTURBANCE: ("disturbance",),
    Stage.FORCE: ("force_rate",),
    Stage.SENSOR: ("filter_rate", "filter_states", "force_minus_reading"),
}
#: the test block: trajectories x steps at the step, s
CHECK_N, CHECK_K, CHECK_DT = 2, 400, 0.002


def check_effect(cls: type[Effect], where: str = "") -> list[str]:
    """Raise :class:`PluginError` unless ``cls`` is a usable effect (see the module
    docstring); return warnings (a non-finite result at a parameter's bound)."""
    label = f"effect plug-in {where}: effect {getattr(cls, 'name', cls.__name__)!r}"
    name = getattr(cls, "name", None)
    if not isinstance(name, str) or not NAME_RE.match(name) or keyword.iskeyword(name) \
            or name == "base":
        raise PluginError(f"{label}: name {name!r} must be lower-case letters, digits and _ , "
                          "starting with a letter, and not 'base' (it is written in "
                          "--model base+NAME and in NAME.param)")
    stage = getattr(cls, "stage", None)
    if not isinstance(stage, Stage):
        raise PluginError(f"{label}: stage must be one of plant.Stage."
                          f"{', plant.Stage.'.join(s.name for s in Stage)}, got {stage!r}")
    params = getattr(cls, "params", None)
    if not isinstance(params, tuple) or not all(isinstance(p, Param) for p in params):
        raise PluginError(f"{label}: params must be a tuple of plant.Param(...), got {params!r}")
    seen = set()
    for p in params:
        _check_param(p, label)
        if p.name in seen:
            raise PluginError(f"{label}: parameter {p.name!r} is declared twice")
        seen.add(p.name)
    missing = [h for h in STAGE_HOOKS[stage] if getattr(cls, h) is getattr(Effect, h)]
    if missing:
        raise PluginError(f"{label}: a {stage.name.lower()} effect must define "
                          f"{', '.join(m + '()' for m in missing)} (see `stand effects --new "
                          f"{name} --stage {stage.name.lower()}`)")
    _run_block(cls, {p.name: p.default for p in params}, label, "with its default parameters")
    warnings = []
    for p in params:
        for bound in (p.lower, p.upper):
            values = {q.name: q.default for q in params}
            values[p.name] = bound
            try:
                _run_block(cls, values, label, f"with {p.name} = {bound:g}")
            except PluginError as exc:
                warnings.append(str(exc) + " (the fit explores the whole range: narrow the "
                                           "bounds to what is physical)")
    return warnings


def _check_param(p: Param, label: str) -> None:
    if not (isinstance(p.name, str) and p.name.isidentifier()):
        raise PluginError(f"{label}: parameter name {p.name!r} must be an identifier")
    nums = {"default": p.default, "lower": p.lower, "upper": p.upper}
    for k, v in nums.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise PluginError(f"{label}: parameter {p.name}: {k} must be a finite number, "
                              f"got {v!r}")
    if not p.lower < p.upper:
        raise PluginError(f"{label}: parameter {p.name}: lower bound {p.lower:g} must be below "
                          f"the upper bound {p.upper:g}")
    if not p.lower <= p.default <= p.upper:
        raise PluginError(f"{label}: parameter {p.name}: default {p.default:g} is outside its "
                          f"bounds [{p.lower:g}, {p.upper:g}]")
    if p.log and p.lower <= 0:
        raise PluginError(f"{label}: parameter {p.name}: log=True needs a positive lower bound, "
                          f"got {p.lower:g}")


def check_command(n: int = CHECK_N, k: int = CHECK_K, dt: float = CHECK_DT) -> np.ndarray:
    """The test block's command (n, k): square waves of 5 and 20 % with a reversal every
    0.2 s, one starting at rest."""
    t = np.arange(k) * dt
    square = np.where((t // 0.2) % 2 == 0, 1.0, -1.0)
    amps = np.array([5.0, 20.0] + [10.0] * max(0, n - 2))[:n]
    u = amps[:, None] * square[None, :]
    u[0, :10] = 0.0
    return u


def _run_block(cls: type[Effect], values: dict, label: str, how: str) -> None:
    """Build the effect, call its stage's hook on the test block, then a whole model with it
    (block by block as the emulator does, and whole as the fit does); any exception, a wrong
    shape or a non-finite value is a :class:`PluginError`."""
    from .model import PlantModel
    path = Path(sys.modules[cls.__module__].__file__).resolve() \
        if getattr(sys.modules.get(cls.__module__), "__file__", None) else None
    try:
        eff = cls(**values)
    except ModelError as exc:
        raise PluginError(f"{label}: {exc}") from None
    except Exception as exc:  # noqa: BLE001
        raise PluginError(f"{label}: creating it {how} raised {type(exc).__name__}: {exc}"
                          f"{_line(exc, path)}") from None
    u = check_command()
    n, k = u.shape
    dt = CHECK_DT
    hook = STAGE_HOOKS[cls.stage][0]
    try:
        state = eff.init_state(n, u[:, 0].copy())
        if not isinstance(state, dict):
            raise PluginError(f"{label}: init_state() must return a dict (its state), got "
                              f"{type(state).__name__}")
        t = np.broadcast_to(np.arange(k) * dt, (n, k)).copy()
        extra = {"t": t} if eff.reads_time else {}
        if cls.stage is Stage.VALVE:
            out = eff.shape(u.copy(), dt, state, **extra)
        elif cls.stage is Stage.FLOW:
            if eff.reads_command:
                extra["command"] = u
            aux = eff.prepare(u.copy(), dt, state, **extra)
            y = np.full((n, k), 1000.0)
            out = eff.gain(u, aux, y)
            hook = "gain"
            if eff.depends_on_force:
                one = eff.gain(u[:, 5], None if aux is None else np.asarray(aux)[:, 5], y[:, 5])
                _check_array(one, (n,), label, "gain() for one step (n,)", how)
        elif cls.stage is Stage.DISTURBANCE:
            out = eff.disturbance(t, dt)
        elif cls.stage is Stage.FORCE:
            y = np.linspace(-5000.0, 5000.0, n * k).reshape(n, k)
            out = eff.force_rate(y)
        else:
            out = eff.filter_rate(np.full((n, k), 100.0), dt, state)
        _check_array(out, (n, k), label, f"{hook}() for a block of shape ({n}, {k})", how)
        model = PlantModel(g=120.0, tau=0.05, effects=[cls(**values)])
        st = model.new_state(n, dt, 0.0, u[:, 0])
        blocks = [model.advance(st, u[:, i:i + 4], dt) for i in range(0, 40, 4)]
        _check_array(np.concatenate(blocks, axis=1), (n, 40), label,
                     "the emulator's simulation (blocks of 4 steps)", how)
        whole = model.simulate(u[1], dt)
        _check_array(whole, (k,), label, "a record's simulation", how)
    except PluginError:
        raise
    except Exception as exc:  # noqa: BLE001 - whatever a user's hook raises
        raise PluginError(f"{label}: {how}, {hook}() raised {type(exc).__name__}: {exc}"
                          f"{_line(exc, path)}") from None


def _check_array(out: object, shape: tuple, label: str, what: str, how: str) -> None:
    try:
        arr = np.asarray(out, dtype=float)
    except (TypeError, ValueError):
        raise PluginError(f"{label}: {how}, {what} returned {type(out).__name__}, not an array "
                          "of numbers") from None
    if arr.shape != shape:
        raise PluginError(f"{label}: {how}, {what} returned shape {arr.shape}, expected "
                          f"{shape} (one value per trajectory and step)")
    bad = ~np.isfinite(arr)
    if bad.any():
        i = tuple(int(v) for v in np.argwhere(bad)[0])
        raise PluginError(f"{label}: {how}, {what} returned a non-finite value "
                          f"({arr[i]}) at index {i}")
