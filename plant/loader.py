"""Finding effect classes in Python code and registering them: the mechanics every effect goes
through, the project's own (:mod:`plant.catalogue`) and a user's (:mod:`plant.plugins`).

A source is a file, a directory of files, an importable module or an entry point of the group
:data:`ENTRY_POINT_GROUP`; importing it defines subclasses of :class:`plant.Effect`, and each
one it defines itself (not those it imports) is registered under its ``name`` in
:data:`plant.contract.CATALOGUE`, after ``check(cls, where)`` accepts it. If anything fails (an
import error, a name taken, a check), nothing of the source stays registered and one
:class:`PluginError` names the source, the effect and what is wrong.

This module runs no effect: what a check does is the caller's (:func:`check_class`, the
declarations only, for the built-ins the test suite runs; :func:`plant.plugins.check_effect`,
which also simulates, for a user's code).
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
from typing import Callable

from .contract import CATALOGUE, Effect, Stage
from .params import ModelError, Param

#: the entry-point group installed packages declare their effects under
ENTRY_POINT_GROUP = "hydrostand.effects"
#: the package under which plug-in files are imported (``sys.modules`` names)
MODULE_PREFIX = "hydrostand_plugins"
NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")
#: the hook(s) each stage must override
STAGE_HOOKS = {
    Stage.VALVE: ("shape",),
    Stage.FLOW: ("gain",),
    Stage.DISTURBANCE: ("disturbance",),
    Stage.FORCE: ("force_rate",),
    Stage.SENSOR: ("filter_rate", "filter_states", "force_minus_reading"),
}

#: ``check(cls, where)``: raises :class:`PluginError` to refuse an effect, returns warnings
Check = Callable[[type[Effect], str], list[str]]


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


#: effect name -> where it came from (the project's own effects are not listed)
ORIGINS: dict[str, Origin] = {}
#: source key (resolved path or module name) -> the effects it defined
_LOADED: dict[str, list[str]] = {}
#: what the checks found worth saying but not refusing (a non-finite result at a bound)
WARNINGS: list[str] = []


def origin(name: str) -> str:
    """``catalogue`` or where a plug-in effect came from."""
    o = ORIGINS.get(name)
    return "catalogue" if o is None else str(o)


def is_plugin(name: str) -> bool:
    return name in ORIGINS


# ------------------------------------------------------------------------------------------
# sources
# ------------------------------------------------------------------------------------------
def load_source(source: str | Path, check: Check, base_dir: str | Path | None = None) -> list[str]:
    """Load one source (a file, a directory or a module name; a relative path from ``base_dir``,
    default the current directory) and return the names of the effects it defines. A source
    loaded before is not loaded again."""
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
        return [n for f in files for n in _load_file(f, check)]
    if path.is_file():
        return _load_file(path, check)
    if text.endswith(".py") or "/" in text or "\\" in text:
        raise PluginError(f"effect plug-in {path} does not exist (give a .py file, a directory "
                          "of them or an importable module name)")
    if not all(part.isidentifier() for part in text.split(".")):
        raise PluginError(f"effect plug-in {text!r} is neither a file, a directory nor a module "
                          "name")
    return load_module(text, check)


def _load_file(path: Path, check: Check) -> list[str]:
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

    names = _register_from(run, Origin("file", where), where, path, check)
    _LOADED[key] = names
    return names


def load_module(name: str, check: Check, builtin: bool = False) -> list[str]:
    """Load an importable module's effects (``builtin``: one of the project's own, not listed
    in :data:`ORIGINS`)."""
    if name in _LOADED:
        return list(_LOADED[name])
    names = _register_from(lambda: importlib.import_module(name),
                           None if builtin else Origin("module", name), f"module {name}", None,
                           check)
    _LOADED[name] = names
    return names


def load_entry_points(check: Check) -> list[str]:
    """The effects of installed packages: entry points of :data:`ENTRY_POINT_GROUP`, each naming
    a module or an effect class, in name order."""
    from importlib.metadata import entry_points   # 60 ms: only when installed plug-ins are asked for
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
                               f"{ENTRY_POINT_GROUP}; fix or uninstall the package)", None, check)
        _LOADED[key] = found
        names += found
    return names


class _ClassHolder:
    """An entry point that names one effect class: look at it as a module holding it."""

    def __init__(self, cls: type) -> None:
        self.__name__ = cls.__module__
        self.cls = cls
def _register_from(run, org: Origin | None, where: str, path: Path | None,
                   check: Check) -> list[str]:
    """Run ``run()`` (an import), register the effect classes it defined, ``check`` them; on any
    failure nothing it registered stays and one :class:`PluginError` says what went wrong.
    ``org``: where they came from (None: the project's own)."""
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
        warnings = [w for name in new for w in check(CATALOGUE[name], where)]
    except BaseException:
        for name in [n for n in CATALOGUE if n not in before]:
            del CATALOGUE[name]
        raise
    if org is not None:
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
# what an effect must declare
# ------------------------------------------------------------------------------------------
def label_of(cls: type, where: str) -> str:
    return f"effect plug-in {where}: effect {getattr(cls, 'name', cls.__name__)!r}"


def check_class(cls: type[Effect], where: str = "") -> list[str]:
    """Raise :class:`PluginError` unless ``cls`` declares what an effect must: a valid name
    that is not the base model's, a stage, parameters with finite defaults inside finite bounds,
    and the hook(s) of its stage. Runs nothing; returns no warnings."""
    label = label_of(cls, where)
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
    return []
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


