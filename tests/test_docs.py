"""Documentation that runs (issue 38): every ``sh`` block of README.md and docs/*.md runs, page by
page, against the emulator on the page's private loopback buses, and what it prints is checked
against the output the page shows; the markers say what cannot run here and why.

Our own collector rather than a plugin: pytest-markdown-docs, phmdoctest and pytest-examples run
Python blocks only; mktestdocs runs shell blocks without checking their output; pytest-codeblocks
compares a block's output exactly (no tolerance for figures from another run, no ``...``) and
leaves ``&`` processes running; prysk/cram read their own ``.t`` files, not Markdown; Sybil makes
each block a test, which xdist spreads over processes, and a page here is a workflow whose blocks
share a directory and the emulators. The parts: tests/support/docblocks.py (the page and its
markers), docpage.py (a page's blocks in order), docshell.py (running commands), docoutput.py
(printed against shown); the rules for writers: docs/testing.md.
"""
from __future__ import annotations

import pytest

from tests.support.docblocks import parse_page
from tests.support.docpage import Outcome, run_page
from tests.support.docshell import ROOT

PAGES = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]


def _params():
    """A test per page with shell blocks: e2e; slow when a block says so; skipped at once when
    every block is."""
    for page in PAGES:
        shell = [b for b in parse_page(ROOT / page, page) if b.is_shell]
        if not shell:
            continue
        marks = [pytest.mark.e2e]
        if any(b.marks.slow for b in shell):
            marks.append(pytest.mark.slow)
        if all(b.marks.skip and not b.marks.run for b in shell):
            marks.append(pytest.mark.skip(reason="; ".join(f"{b.where}: {b.marks.skip}" for b in shell)))
        yield pytest.param(page, marks=marks, id=page)


@pytest.mark.parametrize("page", list(_params()))
def test_the_page_runs_as_documented(page, tmp_path, record_property):
    outcomes: list[Outcome] = []
    try:
        run_page(ROOT / page, page, tmp_path / "page", outcomes)
    finally:
        record_property("doc_blocks", [o.row() for o in outcomes])
        print("\n".join(o.row() for o in outcomes))
    xfailed = [f"{o.where}: {o.why}" for o in outcomes if o.status == "xfailed"]
    if xfailed:
        pytest.xfail("; ".join(xfailed))
