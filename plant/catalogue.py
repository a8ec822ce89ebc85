"""The catalogue: every effect a model can name, the project's own first.

Importing this module registers the built-in effects (:data:`plant.effects.BUILTIN_MODULES`)
through the loader every plug-in goes through (:mod:`plant.loader`), checking what they declare;
the test suite runs each of them as :func:`plant.plugins.check_effect` runs a user's. Plug-ins
join later (:mod:`plant.plugins`). :func:`order` is the catalogue's order: the built-ins as
listed, then plug-ins as loaded; a model applies the effects of one stage in it.
"""
from __future__ import annotations

from .contract import CATALOGUE, Effect
from .effects import BUILTIN_MODULES
from .loader import check_class, load_module
from .params import ModelError

__all__ = ["CATALOGUE", "BUILTINS", "effect_class", "look_alikes", "order"]

#: the built-in effects' names, in the catalogue's order
BUILTINS: tuple[str, ...] = tuple(n for m in BUILTIN_MODULES for n in load_module(m, check_class, builtin=True))
_RANK = {name: i for i, name in enumerate(BUILTINS)}


def order(name: str) -> tuple[int, int]:
    """Sort key of an effect in the catalogue's order (built-ins first)."""
    if name in _RANK:
        return (0, _RANK[name])
    return (1, list(CATALOGUE).index(name) if name in CATALOGUE else len(CATALOGUE))


def effect_class(name: str) -> type[Effect]:
    """Look up an effect by name, with a helpful error. Effects of installed packages are
    looked up once they are loaded: :func:`plant.plugins.load_installed` (every command that
    takes a model does it; so does :func:`plant.config.load_model_file`)."""
    try:
        return CATALOGUE[name]
    except KeyError:
        names = sorted(CATALOGUE, key=order)
        raise ModelError(
            f"unknown effect {name!r}; the catalogue has: {', '.join(names)} (see `stand "
            f"effects`); an effect of your own is loaded with --effects FILE.py") from None


def look_alikes(name: str) -> list[str]:
    """The diagnosable effects that look like ``name``: those it names in its
    :attr:`~plant.Effect.look_alikes` and those that name it, in the catalogue's order (the
    base model's gain, delay and trend are not effects: dropping ``name`` tries them)."""
    own = CATALOGUE[name].look_alikes
    return sorted((n for n, cls in CATALOGUE.items() if n != name and cls.diagnosable
                   and (n in own or name in cls.look_alikes)), key=order)
