"""The wire check in the suite: every capture an end-to-end test leaves is read by tshark.

After each test marked ``e2e`` (its fixtures torn down), the captures it left are found —
``capture.log``, ``capture-<bus>.log`` (the gateway's) and ``candump*.log`` (can-utils', in
user-mode Linux) under the directories made in the session's temporary base while it ran: its
``tmp_path`` and the ones module fixtures made with ``tmp_path_factory`` (looked at again after
later tests, as those may record into them). Each capture keeps what its test provokes
(``@pytest.mark.wire(...)`` on the test or its module:
:class:`~tests.support.wire_check.WireExpectation`). At the end of each test module (the last
test of a module this process runs) one tshark reads all of them
(:func:`tests.support.wire_check.check_captures`; its start-up, ~0.3 s, dominates a test's
few distinct frames), and what a test did not provoke fails that last test's teardown, each
problem on a line naming the capture (its path names the test). The figures go into that
teardown's report (``user_properties``), and the run's totals into the terminal summary.

Where tshark is missing the check is skipped and the summary says why;
``HYDROSTAND_WIRE_CHECK=0`` turns it off (to measure what it costs).
"""
from __future__ import annotations

import os
import resource
import time
from fnmatch import fnmatch
from pathlib import Path

import pytest

from captures import CaptureError

from .wire_check import WireExpectation, check_captures, tshark_missing_reason, wire_problems

PATTERNS = ("capture.log", "capture-*.log", "candump*.log")
_before = pytest.StashKey[set]()


class _State:
    """Per test process: the directories watched, the captures already found, those to check."""

    def __init__(self) -> None:
        self.watched: set[Path] = set()
        self.seen: dict[Path, tuple[int, int]] = {}
        self.pending: list[tuple[Path, WireExpectation, str]] = []     # (capture, expectation, test)


_state = _State()


def _enabled() -> bool:
    return os.environ.get("HYDROSTAND_WIRE_CHECK", "1") != "0"


def _e2e(item) -> bool:
    return item.get_closest_marker("e2e") is not None and _enabled()


def _basetemp(item) -> Path:
    return item.config._tmp_path_factory.getbasetemp()


def _entries(base: Path) -> set[str]:
    try:
        # not pytest's "<name>current" links to a test's directory: each capture is read once
        return {e.name for e in os.scandir(base) if e.is_dir(follow_symlinks=False)}
    except FileNotFoundError:
        return set()


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item) -> None:
    """Before the test's fixtures: what the temporary base holds already."""
    if _e2e(item):
        item.stash[_before] = _entries(_basetemp(item))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_teardown(item, nextitem):
    result = yield
    if _e2e(item) and _before in item.stash:
        expect = WireExpectation.from_marker(item.get_closest_marker("wire"))
        _state.pending += [(path, expect.of(path), item.nodeid) for path in _new_captures(item)]
    if _state.pending and (nextitem is None or nextitem.module is not item.module):
        pending, _state.pending = _state.pending, []
        _check(item, pending)
    return result


def _new_captures(item) -> list[Path]:
    base = _basetemp(item)
    new = {base / name for name in _entries(base) - item.stash[_before]}
    own = item.funcargs.get("tmp_path")
    _state.watched |= {d for d in new if own is None or d != Path(own)}
    found = []
    for top in new | _state.watched:
        for root, _dirs, files in os.walk(top):
            for name in files:
                if any(fnmatch(name, p) for p in PATTERNS):
                    path = Path(root) / name
                    try:
                        st = path.stat()
                    except FileNotFoundError:
                        continue
                    key = (st.st_size, st.st_mtime_ns)
                    if _state.seen.get(path) != key:
                        _state.seen[path] = key
                        found.append(path)
    return sorted(found)


def _check(item, pending: list[tuple[Path, WireExpectation, str]]) -> None:
    """Read ``pending`` captures with tshark (one call per damage handling), fail on what their
    tests did not provoke."""
    skipped = [(p, e.skip, test) for p, e, test in pending if e.skip]
    reason = tshark_missing_reason()
    if reason:
        skipped += [(p, reason, test) for p, e, test in pending if not e.skip]
    for path, why, test in skipped:
        item.user_properties.append(("wire", {"skipped": why, "captures": 1, "test": test}))
    if reason:
        return
    problems = []
    t0, cpu0 = time.perf_counter(), _cpu_s()
    for cut_off in (False, True):
        group = [(p, e, test) for p, e, test in pending if not e.skip and e.cut_off == cut_off]
        if not group:
            continue
        try:
            figures = check_captures([p for p, _, _ in group], on_damage="skip" if cut_off else "stop")
        except CaptureError as exc:
            problems.append(f"a capture cannot be read: {exc}")
            continue
        expect = {str(p): (e, test) for p, e, test in group}
        for f in figures:
            e, test = expect[f.capture]
            problems += [f"{line}   [{test}]" for line in wire_problems([f], e)]
        item.user_properties.append(("wire", {"figures": [{**f.as_dict(), "garbage": expect[f.capture][0].garbage}
                                                          for f in figures]}))
    item.user_properties.append(("wire", {"seconds": time.perf_counter() - t0, "cpu_s": _cpu_s() - cpu0}))
    if problems:
        pytest.fail("the wire, read by tshark's CANopen dissector, shows what these tests do not "
                    "provoke (@pytest.mark.wire says what a test provokes):\n  " + "\n  ".join(problems),
                    pytrace=False)


def _cpu_s() -> float:
    """CPU time of this thread and of the children waited for (tshark), s."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.thread_time() + children.ru_utime + children.ru_stime


def wire_summary(reports) -> list[str]:
    """The run's totals of the wire check, from the teardown reports."""
    checked, skipped = [], []
    seconds = cpu_s = 0.0
    for report in reports:
        if getattr(report, "when", None) != "teardown":
            continue
        for key, value in getattr(report, "user_properties", ()):
            if key != "wire":
                continue
            if "skipped" in value:
                skipped.append((value["test"], value["skipped"]))
            checked += value.get("figures", [])
            seconds += value.get("seconds", 0.0)
            cpu_s += value.get("cpu_s", 0.0)
    if not checked and not skipped:
        return []
    garbage = [f for f in checked if f.get("garbage")]         # a flood of random frames: read, not judged
    checked = [f for f in checked if not f.get("garbage")]
    total = lambda key: sum(f[key] for f in checked)        # noqa: E731
    lines = []
    if checked:
        functions: dict[str, int] = {}
        codes: dict[str, int] = {}
        for f in checked:
            for k, v in f["functions"].items():
                functions[k] = functions.get(k, 0) + v
            for code in f["sdo_abort_codes"]:
                codes[code] = codes.get(code, 0) + 1
        lines += [f"{len(checked)} captures (bus channels) checked, all in {seconds:.1f} s ({cpu_s:.1f} s of CPU): "
                  f"{total('frames'):,} frames, {total('malformed')} malformed, {total('expert_errors')} expert "
                  f"errors, {total('expert_warnings')} warnings",
                  "  by function: " + ", ".join(f"{k} {v:,}" for k, v in sorted(functions.items(), key=lambda kv: -kv[1])),
                  f"  SDO transfers: {total('sdo_begun')} begun ({total('sdo_expedited')} expedited, "
                  f"{total('sdo_segmented')} segmented), {total('sdo_complete')} complete, "
                  f"{sum(codes.values())} aborted, {sum(len(f['sdo_open']) for f in checked)} cut off, "
                  f"{sum(len(f['sdo_faults']) for f in checked)} protocol faults"]
        if codes:
            lines.append("  abort codes: " + ", ".join(f"{c} ×{n}" for c, n in sorted(codes.items())))
    if garbage:
        lines.append(f"{len(garbage)} captures of a bus flooded with random frames (read, not judged): "
                     f"{sum(f['frames'] for f in garbage):,} frames, {sum(f['malformed'] for f in garbage):,} "
                     "malformed")
    if skipped:
        reasons = sorted({why for _, why in skipped})
        lines.append(f"not checked: {len(skipped)} captures of {len({t for t, _ in skipped})} tests: "
                     + "; ".join(reasons))
    return lines
