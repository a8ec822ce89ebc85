"""Effects as plug-ins: a user's effect classes, loaded from a file, a directory, a module or an
installed package, and checked before anything runs.

A plug-in is Python code that defines one or more subclasses of :class:`plant.Effect` (with a
``name``, a ``stage``, its ``params`` and the hook of its stage; ``@plant.register`` above the
class is optional here), exactly as the project's own effects in :mod:`plant.effects` do. Once
loaded, an effect is part of the catalogue: every command that takes a model takes it
(``--model base+my_effect``), ``stand diagnose`` offers it as a candidate, the emulator runs it,
``stand effects`` lists it with where it came from::

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

Every effect is checked when it is loaded (:func:`check_effect`): what it declares
(:func:`plant.loader.check_class`: a valid name that is not the catalogue's, parameters with
finite defaults inside finite bounds, the hook of its stage), then that hook called on a small
block, and a whole model with it simulated as the emulator and the fit do, returning finite
values of the right shape. A plug-in that fails (a syntax error, an import error, a wrong shape,
NaN) raises one :class:`PluginError` naming the file, the effect and what is wrong; nothing of it
stays registered.
"""
from __future__ import annotations

import hashlib
import re
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from .contract import CATALOGUE, Effect, Stage
from .loader import (ENTRY_POINT_GROUP, NAME_RE, ORIGINS, STAGE_HOOKS, WARNINGS,  # noqa: F401
                     Origin, PluginError, check_class, is_plugin, label_of, load_entry_points,
                     origin)
from . import loader
from .model import PlantModel
from .params import ModelError

_installed_loaded = False


def load_plugins(sources: Iterable[str | Path], base_dir: str | Path | None = None) -> list[str]:
    """Load every source (file, directory or module name; relative paths from ``base_dir``,
    default the current directory), check each effect (:func:`check_effect`) and return the
    names of the effects they define. A source loaded before is not loaded again."""
    names: list[str] = []
    for source in sources:
        names += load_source(source, base_dir)
    return names


def load_source(source: str | Path, base_dir: str | Path | None = None) -> list[str]:
    return loader.load_source(source, check_effect, base_dir)


def load_installed() -> list[str]:
    """The effects of installed packages (entry points ``hydrostand.effects``), once."""
    global _installed_loaded
    if _installed_loaded:
        return [n for n, o in ORIGINS.items() if o.kind == "entry point"]
    _installed_loaded = True
    return load_entry_points(check_effect)


# ------------------------------------------------------------------------------------------
# the check on load
# ------------------------------------------------------------------------------------------
#: the test block: trajectories x steps at the step, s
CHECK_N, CHECK_K, CHECK_DT = 2, 400, 0.002


def check_effect(cls: type[Effect], where: str = "") -> list[str]:
    """Raise :class:`PluginError` unless ``cls`` is a usable effect (see the module
    docstring); return warnings (a non-finite result at a parameter's bound)."""
    check_class(cls, where)
    label = label_of(cls, where)
    params = cls.params
    _run_block(cls, {p.name: p.default for p in params}, label, "with its default parameters")
    _check_prepared_from(cls, label)
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


def _check_prepared_from(cls: type[Effect], label: str) -> None:
    """A FLOW effect's :attr:`~plant.contract.Effect.prepared_from` names parameters it has,
    and moving any other one to its bounds leaves what :meth:`prepare` returns as it was (a
    fit reuses it while it moves them: a wrong claim would fit a model that is not there)."""
    names = cls.prepared_from
    if cls.stage is not Stage.FLOW or names is None:
        return
    known = [p.name for p in cls.params]
    unknown = [n for n in names if n not in known]
    if unknown:
        raise PluginError(f"{label}: prepared_from names {', '.join(unknown)}, which are not its "
                          f"parameters ({', '.join(known) or 'none'})")
    u = check_command()
    defaults = {p.name: p.default for p in cls.params}

    def prepared(values: dict):
        eff = cls(**values)
        return eff.prepare(u.copy(), CHECK_DT, eff.init_state(u.shape[0], u[:, 0].copy()),
                           **_hook_keywords(eff, u))

    ref = prepared(defaults)
    for p in cls.params:
        if p.name in names:
            continue
        for bound in (p.lower, p.upper):
            got = prepared({**defaults, p.name: bound})
            same = (got is None and ref is None) or (
                got is not None and ref is not None
                and np.array_equal(np.asarray(got), np.asarray(ref), equal_nan=True))
            if not same:
                raise PluginError(
                    f"{label}: prepare() changes with {p.name} (at {bound:g}), which prepared_from "
                    f"({', '.join(names) or 'none'}) leaves out: add it there, or leave "
                    "prepared_from out (every parameter)")


def _hook_keywords(eff: Effect, u: np.ndarray) -> dict:
    """The keywords a stage hook gets on the check block ``u``: the steps' times if the effect
    reads them, the undelayed command if its ``prepare`` reads it."""
    n, k = u.shape
    extra = {"t": np.broadcast_to(np.arange(k) * CHECK_DT, (n, k)).copy()} if eff.reads_time else {}
    if eff.stage is Stage.FLOW and eff.reads_command:
        extra["command"] = u
    return extra


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
    path = Path(sys.modules[cls.__module__].__file__).resolve() \
        if getattr(sys.modules.get(cls.__module__), "__file__", None) else None
    try:
        eff = cls(**values)
    except ModelError as exc:
        raise PluginError(f"{label}: {exc}") from None
    except Exception as exc:  # noqa: BLE001
        raise PluginError(f"{label}: creating it {how} raised {type(exc).__name__}: {exc}"
                          f"{loader._line(exc, path)}") from None
    u = check_command()
    n, k = u.shape
    dt = CHECK_DT
    hook = STAGE_HOOKS[cls.stage][0]
    try:
        state = eff.init_state(n, u[:, 0].copy())
        if not isinstance(state, dict):
            raise PluginError(f"{label}: init_state() must return a dict (its state), got "
                              f"{type(state).__name__}")
        extra = _hook_keywords(eff, u)
        if cls.stage is Stage.VALVE:
            out = eff.shape(u.copy(), dt, state, **extra)
        elif cls.stage is Stage.FLOW:
            aux = eff.prepare(u.copy(), dt, state, **extra)
            y = np.full((n, k), 1000.0)
            out = eff.gain(u, aux, y)
            hook = "gain"
            if eff.depends_on_force:
                one = eff.gain(u[:, 5], None if aux is None else np.asarray(aux)[:, 5], y[:, 5])
                _check_array(one, (n,), label, "gain() for one step (n,)", how)
        elif cls.stage is Stage.DISTURBANCE:
            out = eff.disturbance(np.broadcast_to(np.arange(k) * dt, (n, k)).copy(), dt)
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
                          f"{loader._line(exc, path)}") from None


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


# ------------------------------------------------------------------------------------------
# plug-ins for other processes (worker processes, a cluster's workers)
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ShippedPlugin:
    """A plug-in loaded here, as another process loads it: a file by its text (a cluster's
    worker may not see the file), a module by its name (installed there too), an installed
    package's entry points by nothing (loaded there from its own packages)."""

    kind: str                    #: "file" | "module" | "entry point"
    where: str                   #: the file's path here, or the module's name
    source: str                  #: the file's text ("" otherwise)
    effects: tuple[str, ...]     #: the effects it registered here

    @property
    def digest(self) -> str:
        return hashlib.sha1(self.source.encode()).hexdigest()[:12]


#: plug-in files loaded from shipped text in this process: digest -> effect names
_SHIPPED: dict[str, tuple[str, ...]] = {}
_SHIP_DIR: Path | None = None


def shippable_plugins() -> list[ShippedPlugin]:
    """Every plug-in loaded in this process (files with their text as it is now), for
    :func:`load_shipped` in another one. Picklable: plain strings."""
    groups: dict[tuple[str, str], list[str]] = {}
    for name, org in ORIGINS.items():
        if name in CATALOGUE:
            groups.setdefault((org.kind, org.where), []).append(name)
    out = []
    for (kind, where), names in groups.items():
        source = ""
        if kind == "file":
            try:
                source = Path(where).read_text()
            except OSError as exc:
                raise PluginError(f"effect plug-in {where}: cannot read it to hand it to the "
                                  f"workers: {exc}") from None
        out.append(ShippedPlugin(kind, where, source, tuple(names)))
    return out


def load_shipped(items: Iterable[ShippedPlugin]) -> list[str]:
    """Load what :func:`shippable_plugins` gave in another process, once per process: a file
    from its original path if this process sees it with the same text (so its module has the
    same name as there), else from a private copy of the text; a plug-in already loaded here
    with the same text is left as it is; one loaded from another text (a worker that lives
    across runs, the file edited in between) is replaced. Returns the effect names."""
    global _SHIP_DIR
    names: list[str] = []
    for item in items:
        if item.kind == "entry point":
            load_installed()
            names += list(item.effects)
            continue
        if item.kind == "module":
            names += load_source(item.where)
            continue
        if _SHIPPED.get(item.digest) == item.effects and all(n in CATALOGUE for n in item.effects):
            names += list(item.effects)
            continue
        here = [n for n in item.effects if n in CATALOGUE]
        same = all(ORIGINS.get(n) is not None and ORIGINS[n].where == item.where for n in here)
        original = Path(item.where)
        try:
            unchanged = original.is_file() and original.read_text() == item.source
        except OSError:
            unchanged = False
        if here and same and unchanged:        # loaded here from the same file (a fork)
            _SHIPPED[item.digest] = item.effects
            names += list(item.effects)
            continue
        for n in here:                          # another version: replaced
            del CATALOGUE[n]
            ORIGINS.pop(n, None)
        loader._LOADED.pop(str(original.resolve()), None)
        if unchanged:
            path = original
        else:
            if _SHIP_DIR is None:
                _SHIP_DIR = Path(tempfile.mkdtemp(prefix="hydrostand-plugins-"))
            stem = re.sub(r"\W", "_", original.stem)
            path = _SHIP_DIR / f"{stem}_{item.digest}.py"
            path.write_text(item.source)
        names += load_source(path)
        _SHIPPED[item.digest] = item.effects
    return names
