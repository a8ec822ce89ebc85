"""The benchmark command still works (``scripts/bench --quick``): a smoke run that catches a
broken benchmark. It judges nothing about speed: these machines are shared and noisy."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.runner import discover

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.e2e


def test_every_benchmark_runs_in_quick_mode_and_prints_its_rows():
    res = subprocess.run([sys.executable, "-m", "benchmarks.runner", "--quick"], cwd=ROOT,
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    table = res.stdout
    assert "FAILED" not in table
    for name in discover():
        assert f"running {name}" in res.stderr
    for figure in ("cycles/s", "x real time", "frames/s", "round trips/s", "% bus load",
                   "stand diagnose", "SYNC jitter", "host floor", "where the time goes"):
        assert figure in table, figure
