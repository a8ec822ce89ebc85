"""The documentation runner itself (tests/test_docs.py): reading blocks and markers, comparing
printed with shown output, and a page's shell session."""
from __future__ import annotations

import os
import sys
import textwrap

import pytest

from tests.support.docblocks import MarkerError, Tolerance, parse_page
from tests.support.docoutput import compare
from tests.support.docpage import BlockFailed, Outcome, run_page
from tests.support.docshell import CommandFailed, PageRun


def page(tmp_path, text: str):
    path = tmp_path / "page.md"
    path.write_text(textwrap.dedent(text))
    return parse_page(path, "page.md")


def test_a_shell_block_takes_the_output_block_right_after_it_and_its_markers(tmp_path):
    blocks = page(tmp_path, """\
        # A page
        <!-- docs-test: skip 4: needs a bench; output: within 10 % or 0.5 -->
        ```sh
        stand emulate --lockstep &   # the stand
        stand run meander --out runs/m5 \\
            --lockstep [--seed 3]
        stand run meander --bus socketcan:can0
        ```

        ```
        run complete: 10000 cycles
        ```
        Some text.
        ```sh
        stand estimate runs/m5
        ```
        Text between.
        ```
        not its output
        ```
        """)
    first, second, third = blocks
    assert first.output == "run complete: 10000 cycles"
    assert first.marks.tolerance == Tolerance(0.10, 0.5) and first.marks.skip_lines == {4: "needs a bench"}
    assert first.commands() == [(4, "stand emulate --lockstep &   # the stand"),
                                (5, "stand run meander --out runs/m5 --lockstep")]
    assert second.output is None and third.lang == "" and not third.is_shell


def test_run_comes_first_skip_leaves_only_it_and_optional_parts_can_be_kept(tmp_path):
    blocks = page(tmp_path, """\
        <!-- docs-test: run: stand emulate --lockstep &; optional: keep -->
        ```sh
        stand run relay --out runs/r1 [--lockstep]
        ```
        <!-- docs-test: skip: installs the machine; run: .venv/bin/stand demo -->
        ```sh
        bash scripts/setup && .venv/bin/stand demo
        ```
        """)
    assert [c for _, c in blocks[0].commands()] == ["stand emulate --lockstep &",
                                                    "stand run relay --out runs/r1 --lockstep"]
    assert [c for _, c in blocks[1].commands()] == [".venv/bin/stand demo"]


def test_a_marker_quoted_in_prose_is_not_a_marker(tmp_path):
    block, = page(tmp_path, "Mark it `<!-- docs-test: skip: a bench -->` like this:\n```sh\nls\n```\n")
    assert block.marks.skip is None


@pytest.mark.parametrize("text, message", [
    ("<!-- docs-test: skipp: typo -->\n```sh\nls\n```\n", "unknown docs-test key 'skipp'"),
    ("<!-- docs-test: xfail -->\n```sh\nls\n```\n", "'xfail' needs a reason"),
    ("<!-- docs-test: output: roughly -->\n```sh\nls\n```\n", "'output' is 'within N %'"),
    ("<!-- docs-test: slow -->\nA paragraph.\n```sh\nls\n```\n", "right before its block"),
])
def test_a_marker_the_runner_cannot_read_fails_loudly(tmp_path, text, message):
    with pytest.raises(MarkerError, match=message):
        page(tmp_path, text)


PRINTED = """\
emulator: base+reversal on udp_loopback:demo-4711 (lockstep)
run complete: 10,012 cycles = 20.0 s of stand time in 14.9 s wall (1.3x real time)

  g main portions     120.37 kgf/(%·s)  [119.80, 121.01]   120.00
  trend Δ               8.31 kgf/s                         8.00
run directory: runs/demo-20261127-113401/
"""


@pytest.mark.parametrize("shown", [
    "  g main portions     121.01 kgf/(%·s)  [120.30, 121.72]   120.00",
    "run complete: 10,000 cycles = 20.0 s of stand time in ...\n...\ntrend Δ 8.00 kgf/s 8.00",
    "run complete: 10,000 cycles ...\n\n  g main portions 121.01 kgf/(%·s) [120.30, 121.72] 120.00",
    "run directory: runs/demo-...",
])
def test_printed_output_matches_shown_lines_in_order_with_numbers_within_the_tolerance(shown):
    assert compare(shown, PRINTED, Tolerance(0.05)) is None


@pytest.mark.parametrize("shown, why", [
    ("  trend Δ  12.0 kgf/s  8.00", "8.31 is off the shown 12 by more than 5 %"),
    ("  g main portions 121.01 kgf/(%·s) [120.30, 121.72] 120.00\nrun complete: 10,000 cycles ...",
     "does not show these lines in order"),
    ("run directory: runs/demo-...\n...\ntrend Δ 8.00 kgf/s 8.00", "nothing printed here"),
    ("  g main portions 121.01 kgf/(%·s) [120.30, 121.72] 120.00\nrun directory: runs/x", "the text differs"),
    ("  g main portions 121.01 kgf/(%·s)", "the text differs"),
])
def test_a_difference_fails_naming_the_line_and_why(shown, why):
    message = compare(shown, PRINTED, Tolerance(0.05))
    assert message is not None and why in message


def test_figures_near_zero_may_differ_by_their_rounding_or_an_absolute_tolerance():
    assert compare("p95 0.07 %, extra cycles 0", "p95 0.09 %, extra cycles 0", Tolerance()) is None
    assert compare("p95 0.07 %", "p95 0.10 %", Tolerance()) is not None
    assert compare("extra cycles 0", "extra cycles 1", Tolerance()) is not None
    assert compare("off -0.01 %", "off +0.05 %", Tolerance(0.05)) is not None
    assert compare("off -0.01 %", "off +0.05 %", Tolerance(0.05, 0.1)) is None


def test_a_page_runs_in_its_own_directory_and_bus_namespace_and_stops_its_background(tmp_path):
    run = PageRun.start("docs/x.md", tmp_path / "x")
    other = PageRun.start("docs/x.md", tmp_path / "y")
    try:
        assert run.env["HYDROSTAND_LOOPBACK_NAMESPACE"] != other.env["HYDROSTAND_LOOPBACK_NAMESPACE"]
        assert (run.directory / "examples" / "rig.toml").exists()
        assert run.run("stand --help >/dev/null && pwd", "x:1").strip() == str(run.directory)
        server = f"{sys.executable} -c \"print('ready', flush=True); import time; time.sleep(60)\""
        assert run.run(f"cd examples && {server} &  # a stand", "x:2") == ""
        proc = run.background[0].proc
        assert proc.poll() is None and "ready" in run.background[0].tail()
        with pytest.raises(CommandFailed, match=r"exited with 3:\nnot found"):
            run.run("echo not found; exit 3", "x:3")
    finally:
        run.stop()
    assert proc.poll() is not None and not run.background
    with pytest.raises(ProcessLookupError):
        os.killpg(proc.pid, 0)


def run(tmp_path, text: str, directory: str = "run") -> list[Outcome]:
    path = tmp_path / "page.md"
    path.write_text(textwrap.dedent(text))
    outcomes: list[Outcome] = []
    run_page(path, "page.md", tmp_path / directory, outcomes)
    return outcomes


def test_a_page_runs_its_blocks_in_order_in_one_directory_with_its_files(tmp_path):
    outcomes = run(tmp_path, """\
        <!-- docs-test: file: hello.py -->
        ```python
        print("hello", 2 * 21)
        ```
        <!-- docs-test: given: rig.toml from examples/rig.toml -->
        ```sh
        python hello.py > said.txt
        grep -c channel rig.toml > /dev/null
        ```
        ```sh
        cat said.txt
        ```
        ```
        hello 42
        ```
        """)
    assert [(o.where, o.status) for o in outcomes] == [("page.md:6", "passed"), ("page.md:10", "passed")]


def test_a_failing_block_stops_the_page_naming_the_command_and_the_blocks_before(tmp_path):
    with pytest.raises(BlockFailed, match=r"(?s)page.md:7: `false` exited with 1.*page.md:1 +passed"):
        run(tmp_path, "```sh\ntrue\n```\n\n```sh\ntrue\nfalse\n```\n```sh\ntouch never\n```\n")
    assert not (tmp_path / "run" / "never").exists()
    with pytest.raises(BlockFailed, match=r"page.md:1: the printed output does not show"):
        run(tmp_path, "```sh\necho 'p95 0.50 %'\n```\n```\np95 0.07 %\n```\n", "run2")


def test_an_xfail_block_that_fails_lets_the_page_go_on_and_one_that_passes_fails_it(tmp_path):
    outcomes = run(tmp_path, """\
        <!-- docs-test: xfail: the estimate raises (bug 7) -->
        ```sh
        exit 2
        ```
        ```sh
        true
        ```
        """)
    assert [o.status for o in outcomes] == ["xfailed", "passed"] and "bug 7" in outcomes[0].why
    with pytest.raises(BlockFailed, match="XPASS.*bug 7.*remove the marker"):
        run(tmp_path, "<!-- docs-test: xfail: bug 7 -->\n```sh\ntrue\n```\n", "run2")


def test_a_block_that_needs_a_program_missing_here_is_skipped_saying_which(tmp_path):
    outcomes = run(tmp_path, """\
        <!-- docs-test: needs: sh no-such-program-4711 -->
        ```sh
        no-such-program-4711 --version
        ```
        <!-- docs-test: needs: sh -->
        ```sh
        true
        ```
        """)
    assert [o.status for o in outcomes] == ["skipped", "passed"]
    assert outcomes[0].why.startswith("no-such-program-4711 not installed")
