"""Documentation that runs (issue 38): every ``sh`` block of README.md and docs/*.md runs, page by
page, against the emulator on the page's private loopback buses, and what it prints is checked
against the output the page shows; the markers say what cannot run here and why.

Our own collector rather than a plugin: pytest-markdown-docs, phmdoctest and pytest-examples run
Python blocks only; mktestdocs runs shell blocks without checking their output; pytest-codeblocks
compares a block's output exactly (no tolerance for figures from another run, no ``...``) and
leaves ``&`` processes running; prysk/cram read their own ``.t`` files, not Markdown; Sybil makes
each block a test, which xdist spreads over processes, and a page here is a workflow whose blocks
share a directory and the emulators. The parts: tests/support/docblocks.py (the page and its
markers), docshell.py (running a page), docoutput.py (printed against shown); the rules for
writers: docs/testing.md.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.support.docblocks import Block, parse_page
from tests.support.docoutput import compare
from tests.support.docshell import ROOT, CommandFailed, PageRun

PAGES = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]


@dataclass
class Outcome:
    """What became of one block: passed, skipped, xfailed (with why) and its time."""

    where: str
    status: str
    seconds: float = 0.0
    why: str = ""

    def row(self) -> str:
        return f"{self.where:<28} {self.status:<8} {self.seconds:7.1f} s  {self.why}"


def _params():
    for page in PAGES:
        blocks = parse_page(ROOT / page, page)
        shell = [b for b in blocks if b.is_shell]
        if not shell:
            continue
        marks = [pytest.mark.e2e]
        if any(b.marks.slow for b in shell):
            marks.append(pytest.mark.slow)
        if all(b.marks.skip and not b.marks.run for b in shell):
            marks.append(pytest.mark.skip(reason="; ".join(f"{b.where}: {b.marks.skip}" for b in shell)))
        yield pytest.param(page, marks=marks, id=page)


class BlockFailed(AssertionError):
    """A block's command failed or its output differs from the page's."""


def run_block(run: PageRun, block: Block) -> None:
    """Run one shell block's commands; check their output against the shown output."""
    printed = []
    for line, command in block.commands():
        printed.append(run.run(command, f"{block.page}:{line}"))
    if block.output is not None and block.marks.unchecked is None:
        why = compare(block.output, "".join(printed), block.marks.tolerance)
        if why:
            raise BlockFailed(f"{block.where}: {why}\n--- printed:\n{''.join(printed)[-6000:]}")


def run_page(page: str, directory: Path, outcomes: list[Outcome]) -> None:
    """Every block of the page in order (module doc), each one's outcome added to ``outcomes``;
    the first failure raises."""
    run = PageRun.start(page, directory)
    try:
        for block in parse_page(ROOT / page, page):
            for name, source in block.marks.given:
                run.given(name, source)
            if block.marks.file:
                run.write(block.marks.file, block.text)
            if not block.is_shell:
                continue
            if block.marks.skip and not block.marks.run:
                outcomes.append(Outcome(block.where, "skipped", why=block.marks.skip))
                continue
            start = time.monotonic()
            try:
                try:
                    run_block(run, block)
                finally:
                    run.stop()
            except (CommandFailed, BlockFailed) as exc:
                if not block.marks.xfail:
                    raise BlockFailed(f"{exc}\n\nblocks before it:\n"
                                      + "\n".join(o.row() for o in outcomes)) from None
                first = str(exc).splitlines()[0]
                outcomes.append(Outcome(block.where, "xfailed", time.monotonic() - start,
                                        f"{block.marks.xfail} [{first}]"))
                continue
            if block.marks.xfail:
                raise BlockFailed(f"{block.where}: XPASS(strict): marked xfail "
                                  f"({block.marks.xfail}) but it ran: remove the marker")
            notes = [f"skipped {lines}: {why}" for lines, why in _line_ranges(block.marks.skip_lines)]
            if block.marks.skip:
                notes.append(f"ran {' && '.join(block.marks.run)} instead: {block.marks.skip}")
            outcomes.append(Outcome(block.where, "passed", time.monotonic() - start, "; ".join(notes)))
    finally:
        run.stop()


def _line_ranges(skipped: dict[int, str]) -> list[tuple[str, str]]:
    """``{3: a, 4: a, 6: b}`` as ``[("lines 3-4", a), ("line 6", b)]``."""
    runs: list[list] = []
    for line, why in sorted(skipped.items()):
        if runs and runs[-1][1] == line - 1 and runs[-1][2] == why:
            runs[-1][1] = line
        else:
            runs.append([line, line, why])
    return [(f"line {a}" if a == b else f"lines {a}-{b}", why) for a, b, why in runs]


@pytest.mark.parametrize("page", list(_params()))
def test_the_page_runs_as_documented(page, tmp_path, record_property):
    outcomes: list[Outcome] = []
    try:
        run_page(page, tmp_path / "page", outcomes)
    finally:
        record_property("doc_blocks", [o.row() for o in outcomes])
        print("\n".join(o.row() for o in outcomes))
    xfailed = [f"{o.where}: {o.why}" for o in outcomes if o.status == "xfailed"]
    if xfailed:
        pytest.xfail("; ".join(xfailed))
