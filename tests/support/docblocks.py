"""The documentation's code blocks as tests: a Markdown page read into its blocks and markers.

A fenced ``sh`` block is a sequence of commands; the fenced block right after it (only blank
lines between, ``text`` or a bare fence) is what they print. An HTML comment just before a
block (invisible to readers) marks it, keys separated by ``;``::

    <!-- docs-test: skip: needs a CAN bench (socketcan:can0) -->
    <!-- docs-test: skip 3-5: need vcan0 and a CAN bench -->     (those lines of the block)
    <!-- docs-test: slow -->                                     (the page takes over ~30 s)
    <!-- docs-test: xfail: stand report KeyError on a rig load (bug) -->
    <!-- docs-test: output: within 20 % -->                      (numbers' tolerance)
    <!-- docs-test: output: unchecked: another stand's figures -->
    <!-- docs-test: given: rig.toml from examples/rig.toml -->   (a file the reader brings)
    <!-- docs-test: file: supply_ripple.py -->                   (this block is that file)
    <!-- docs-test: skip: installs the machine; run: .venv/bin/stand demo -->  (this instead)
    <!-- docs-test: run: stand emulate --lockstep & -->          (this first, as the text says)
    <!-- docs-test: optional: keep -->                           (run [--lockstep] with it)

An option in brackets, ``[--json]``, is left out unless the block says ``optional: keep``.

How they run: :mod:`tests.support.docshell`; how output is compared: :mod:`tests.support.docoutput`;
the rules for writers: docs/testing.md.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

#: a marker is a line of its own (the same text quoted inside a line is prose)
MARKER = re.compile(r"^\s*<!--\s*docs-test:(.*?)-->\s*$")
FENCE = re.compile(r"^(`{3,})\s*([\w+-]*)\s*$")
#: the fences whose block is shown output
OUTPUT_LANGS = {"", "text", "console", "output"}
#: the language of commands
SHELL_LANGS = {"sh", "bash", "shell"}
#: ``[--option value]`` in a command: an optional part
_OPTIONAL = re.compile(r"\s*\[(--[^\[\]]*)\]")


class MarkerError(ValueError):
    """A ``docs-test`` marker the runner does not understand (fails the page's collection)."""


@dataclass(frozen=True)
class Tolerance:
    """How near a printed number must be to the one shown: within ``rel`` of it, or ``abs``, or
    ``last_digits`` in the last decimal shown (0.07 % printed with two decimals: ±0.02; an
    integer, 0 extra cycles, exactly)."""

    rel: float = 0.05
    abs: float = 0.0
    last_digits: int = 2

    def allows(self, shown: float, printed: float, decimals: int = 0) -> bool:
        rounding = self.last_digits * 10.0 ** -decimals if decimals else 0.0
        return abs(printed - shown) <= max(self.rel * abs(shown), self.abs, rounding)

    def __str__(self) -> str:
        return (f"{self.rel * 100:g} %" + (f" or {self.abs:g}" if self.abs else "")
                + f" or {self.last_digits} in the last decimal shown")


@dataclass
class Marks:
    """What a block's markers say (empty: run it, check its output at the default tolerance)."""

    skip: str | None = None
    skip_lines: dict[int, str] = field(default_factory=dict)
    slow: bool = False
    xfail: str | None = None
    tolerance: Tolerance = field(default_factory=Tolerance)
    unchecked: str | None = None
    given: list[tuple[str, str]] = field(default_factory=list)
    file: str | None = None
    run: list[str] = field(default_factory=list)
    keep_optional: bool = False
    needs: list[str] = field(default_factory=list)     #: programs the block runs (skipped without them)


@dataclass
class Block:
    """One fenced block of a page, with the output block shown after it and its markers."""

    page: str
    line: int
    lang: str
    text: str
    marks: Marks = field(default_factory=Marks)
    output: str | None = None

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"

    @property
    def is_shell(self) -> bool:
        return self.lang in SHELL_LANGS

    def commands(self) -> list[tuple[int, str]]:
        """``(line in the page, command)`` of every command to run: continued lines joined,
        comment-only lines, the lines marked ``skip N-M`` and optional ``[--parts]`` left out
        (unless ``optional: keep``); after what ``run:`` says, or only that with ``skip:``."""
        first = [(self.line, command) for command in self.marks.run]
        if self.marks.skip:
            return first
        out: list[tuple[int, str]] = []
        pending: list[str] = []
        start = 0
        for i, raw in enumerate(self.text.splitlines(), start=1):
            if i in self.marks.skip_lines:
                continue
            if not pending:
                start = self.line + i
            if raw.rstrip().endswith("\\"):
                pending.append(raw.rstrip()[:-1])
                continue
            text = " ".join(part.strip() for part in [*pending, raw])
            pending = []
            if text and not text.startswith("#"):
                out.append((start, _OPTIONAL.sub(r" \1" if self.marks.keep_optional else "", text)))
        return first + out


def parse_marker(text: str, where: str) -> Marks:
    """The keys of one ``<!-- docs-test: ... -->`` comment (its inside, ``where`` for errors)."""
    marks = Marks()
    add_marker(marks, text, where)
    return marks


def add_marker(marks: Marks, text: str, where: str) -> None:
    for part in (p.strip() for p in text.split(";")):
        if not part:
            continue
        key, _, value = (s.strip() for s in part.partition(":"))
        lines = re.fullmatch(r"skip\s+(\d+)(?:\s*-\s*(\d+))?", key)
        if key == "skip":
            marks.skip = _reason(value, key, where)
        elif lines:
            first, last = int(lines[1]), int(lines[2] or lines[1])
            for n in range(first, last + 1):
                marks.skip_lines[n] = _reason(value, key, where)
        elif key == "slow":
            marks.slow = True
        elif key == "xfail":
            marks.xfail = _reason(value, key, where)
        elif key == "output":
            _output(marks, value, where)
        elif key == "given":
            name, sep, source = value.partition(" from ")
            if not sep or not name.strip() or not source.strip():
                raise MarkerError(f"{where}: 'given' is 'given: NAME from REPO/PATH', got {value!r}")
            marks.given.append((name.strip(), source.strip()))
        elif key == "file":
            marks.file = _reason(value, key, where)
        elif key == "run":
            marks.run.append(_reason(value, key, where))
        elif key == "optional" and value == "keep":
            marks.keep_optional = True
        elif key == "needs":
            marks.needs += _reason(value, key, where).split()
        else:
            raise MarkerError(f"{where}: unknown docs-test key {key!r} (skip, skip N-M, slow, "
                              "xfail, output, given, file, run, optional: keep, needs: docs/testing.md)")


def _reason(value: str, key: str, where: str) -> str:
    if not value:
        raise MarkerError(f"{where}: '{key}' needs a reason or a name after ':'")
    return value


def _output(marks: Marks, value: str, where: str) -> None:
    kind, _, rest = (s.strip() for s in value.partition(":"))
    if kind == "unchecked":
        marks.unchecked = _reason(rest, "output: unchecked", where)
        return
    m = re.fullmatch(r"within\s+([\d.]+)\s*%(?:\s+or\s+([\d.]+))?", value)
    if not m:
        raise MarkerError(f"{where}: 'output' is 'within N %', 'within N % or ABS' or "
                          f"'unchecked: REASON', got {value!r}")
    marks.tolerance = Tolerance(float(m[1]) / 100, float(m[2] or 0))


def parse_page(path: Path, name: str) -> list[Block]:
    """Every fenced block of a Markdown page in order, each with its markers; a shell block
    with the output block that follows it (that block is not listed on its own)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks: list[Block] = []
    pending: list[tuple[str, int]] = []     # markers since the last block
    i = 0
    while i < len(lines):
        fence = FENCE.match(lines[i])
        if not fence:
            marker = MARKER.match(lines[i])
            if marker:
                pending.append((marker[1], i + 1))
            elif pending and lines[i].strip():
                raise MarkerError(f"{name}:{pending[0][1]}: a docs-test marker goes right "
                                  "before its block (only blank lines or markers between)")
            i += 1
            continue
        end = _closing(lines, i, fence[1])
        block = Block(name, i + 1, fence[2], "\n".join(lines[i + 1:end]))
        for text, line in pending:
            add_marker(block.marks, text, f"{name}:{line}")
        pending = []
        following = _next_nonblank(lines, end + 1)
        if block.is_shell and following is not None:
            nxt = FENCE.match(lines[following])
            if nxt and nxt[2] in OUTPUT_LANGS:
                close = _closing(lines, following, nxt[1])
                block.output = "\n".join(lines[following + 1:close])
                end = close
        blocks.append(block)
        i = end + 1
    return blocks


def _closing(lines: list[str], start: int, ticks: str) -> int:
    for j in range(start + 1, len(lines)):
        if lines[j].strip() == ticks:
            return j
    raise MarkerError(f"line {start + 1}: a code fence that is never closed")


def _next_nonblank(lines: list[str], start: int) -> int | None:
    for j in range(start, len(lines)):
        if lines[j].strip():
            return j
    return None
