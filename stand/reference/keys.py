"""The key tables of the file-format pages: a file's table (``[[bus]]``, ``[monitor.trend]``,
run.json's ``stats``) and its keys, each with its meaning and default, rendered as one
Markdown table; and the ``#:`` comments of a dataclass's fields, read from its source, where the
code documents a field itself."""
from __future__ import annotations

import ast
import dataclasses
import inspect
import math
import textwrap
from dataclasses import dataclass
from typing import Any, Iterable, Mapping

from . import markdown as md


@dataclass(frozen=True)
class Key:
    """One key of a table: its name, what it means (Markdown), its default as shown
    (``required``, a value, or blank) and what it holds."""

    name: str
    meaning: str
    default: str = ""
    kind: str = ""


@dataclass(frozen=True)
class Table:
    """A table of a file: ``name`` as the file writes it (``""``: the top level), its keys."""

    name: str
    keys: tuple[Key, ...]
    intro: str = ""

    @property
    def names(self) -> set[str]:
        return {k.name for k in self.keys}

    def markdown(self, heading: str = "###") -> str:
        title = f"{heading} {md.code(self.name) if self.name else 'The top level'}"
        parts = [title, self.intro, self.key_table()]
        return "\n\n".join(p for p in parts if p)

    def key_table(self) -> str:
        """The keys as a table; the 'holds' and 'default' columns only where a key fills them."""
        columns = [("key", lambda k: md.code(k.name)), ("holds", lambda k: k.kind),
                   ("default", lambda k: k.default), ("what it is", lambda k: k.meaning)]
        used = [(h, f) for h, f in columns if h in ("key", "what it is") or any(f(k) for k in self.keys)]
        return md.table([h for h, _ in used], [[f(k) for _, f in used] for k in self.keys])


def value(v: Any) -> str:
    """A default as the reference shows it: the TOML/JSON spelling of ``v`` as code."""
    if isinstance(v, bool):
        return md.code("true" if v else "false")
    if isinstance(v, float):
        if math.isinf(v):
            return md.code("inf")
        return md.code(f"{v:g}")
    if isinstance(v, str):
        return md.code(f'"{v}"')
    if v is None:
        return ""
    return md.code(v)


def field_docs(cls: type) -> dict[str, str]:
    """The ``#:`` comment of every field of the dataclass ``cls`` that has one: the lines right
    above the field, or one after it on the same line (the Sphinx convention the code follows)."""
    source = textwrap.dedent(inspect.getsource(cls))
    lines = source.splitlines()
    body = ast.parse(source).body[0]
    out: dict[str, str] = {}
    for node in body.body:                       # type: ignore[attr-defined]
        if not isinstance(node, ast.AnnAssign) or not isinstance(node.target, ast.Name):
            continue
        line = lines[node.lineno - 1]
        doc = []
        if "#:" in line:
            doc = [line.split("#:", 1)[1].strip()]
        else:
            i = node.lineno - 2
            while i >= 0 and lines[i].strip().startswith("#:"):
                doc.insert(0, lines[i].strip()[2:].strip())
                i -= 1
        if doc:
            out[node.target.id] = " ".join(doc)
    return out


def field_defaults(cls: type) -> dict[str, Any]:
    """Every field of the dataclass ``cls`` with its default (``dataclasses.MISSING`` when it
    has none)."""
    out = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            out[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:      # type: ignore[misc]
            out[f.name] = f.default_factory()                   # type: ignore[misc]
        else:
            out[f.name] = dataclasses.MISSING
    return out


class Undescribed(RuntimeError):
    """A field or key the code has and the reference does not describe: say it where it is
    described (stand/reference/)."""


def dataclass_keys(cls: type, described: Mapping[str, str] | None = None,
                   skip: Iterable[str] = (), show_defaults: bool = True) -> tuple[Key, ...]:
    """A key per field of ``cls`` (less ``skip``), in the class's order: its meaning from
    ``described`` (Markdown) or else the field's ``#:`` comment, its default from the class. A field with
    neither raises :class:`Undescribed`, so a field added to the code cannot be left out of the
    reference unnoticed; a description of a field the class no longer has raises it too."""
    described = dict(described or {})
    docs = field_docs(cls)
    defaults = field_defaults(cls)
    skip = set(skip)
    stale = set(described) - set(defaults)
    if stale:
        raise Undescribed(f"{cls.__qualname__} has no field(s) {', '.join(sorted(stale))}: "
                          "remove their descriptions from stand/reference/")
    out = []
    for name, default in defaults.items():
        if name in skip:
            continue
        meaning = described.get(name) or (md.text(md.rst(docs[name])) if name in docs else "")
        if not meaning:
            raise Undescribed(f"{cls.__module__}.{cls.__qualname__}.{name} has no description: "
                              "give it a #: comment in the code or one in stand/reference/")
        shown = "" if default is dataclasses.MISSING or not show_defaults else value(default)
        out.append(Key(name, meaning, shown))
    return tuple(out)
