"""A page's blocks run in order, each with its outcome and time (tests/test_docs.py).

Shell blocks run through :class:`~tests.support.docshell.PageRun`; a block's background
processes are stopped when it ends. A failing block stops the page (the blocks after it would
fail for its sake); a block marked ``xfail`` that fails is recorded and the page goes on; one
that passes fails the page (strict: the bug it names is fixed, the marker must go).
"""
from __future__ import annotations

import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from tests.support.docblocks import Block, parse_page
from tests.support.docoutput import compare
from tests.support.docshell import CommandFailed, PageRun


@dataclass
class Outcome:
    """What became of one shell block: passed, skipped or xfailed (with why), and its time."""

    where: str
    status: str
    seconds: float = 0.0
    why: str = ""

    def row(self) -> str:
        return f"{self.where:<28} {self.status:<8} {self.seconds:7.1f} s  {self.why}"


class BlockFailed(AssertionError):
    """A block's command failed, its output differs from the page's, or an xfail block passed."""


def run_block(run: PageRun, block: Block) -> None:
    """Run one shell block's commands; check what they printed against the shown output."""
    printed = [run.run(command, f"{block.page}:{line}") for line, command in block.commands()]
    if block.output is not None and block.marks.unchecked is None:
        why = compare(block.output, "".join(printed), block.marks.tolerance)
        if why:
            raise BlockFailed(f"{block.where}: {why}\n--- printed:\n{''.join(printed)[-6000:]}")


def run_page(path: Path, name: str, directory: Path, outcomes: list[Outcome]) -> None:
    """Every block of the page in order, each shell block's outcome added to ``outcomes``
    (module doc); the first failure raises :class:`BlockFailed`, naming the blocks before it."""
    run = PageRun.start(name, directory)
    try:
        for block in parse_page(path, name):
            for target, source in block.marks.given:
                run.given(target, source)
            if block.marks.file:
                run.write(block.marks.file, block.text)
            if block.is_shell:
                outcomes.append(_run_one(run, block, outcomes))
    finally:
        run.stop()


def _run_one(run: PageRun, block: Block, before: list[Outcome]) -> Outcome:
    if block.marks.skip and not block.marks.run:
        return Outcome(block.where, "skipped", why=block.marks.skip)
    missing = [program for program in block.marks.needs if shutil.which(program) is None]
    if missing:
        return Outcome(block.where, "skipped", why=f"{', '.join(missing)} not installed "
                                                    "(bash scripts/setup as root installs it)")
    start = time.monotonic()
    try:
        try:
            run_block(run, block)
        finally:
            run.stop()
    except (CommandFailed, BlockFailed) as exc:
        if not block.marks.xfail:
            raise BlockFailed(f"{exc}\n\nblocks before it:\n"
                              + "\n".join(o.row() for o in before)) from None
        first = str(exc).splitlines()[0]
        return Outcome(block.where, "xfailed", time.monotonic() - start, f"{block.marks.xfail} [{first}]")
    if block.marks.xfail:
        raise BlockFailed(f"{block.where}: XPASS(strict): marked xfail ({block.marks.xfail}) "
                          "but it ran as documented: the bug is fixed, remove the marker")
    notes = [f"skipped {lines}: {why}" for lines, why in _line_ranges(block.marks.skip_lines)]
    if block.marks.skip:
        notes.append(f"ran {' && '.join(block.marks.run)} instead: {block.marks.skip}")
    return Outcome(block.where, "passed", time.monotonic() - start, "; ".join(notes))


def _line_ranges(skipped: dict[int, str]) -> list[tuple[str, str]]:
    """``{3: a, 4: a, 6: b}`` as ``[("lines 3-4", a), ("line 6", b)]``."""
    runs: list[list] = []
    for line, why in sorted(skipped.items()):
        if runs and runs[-1][1] == line - 1 and runs[-1][2] == why:
            runs[-1][1] = line
        else:
            runs.append([line, line, why])
    return [(f"line {a}" if a == b else f"lines {a}-{b}", why) for a, b, why in runs]
