"""Benchmarks: speed as ratios against what a user would otherwise use, measured in one run.

Run them with ``scripts/bench`` (``--quick`` for a smoke run under a minute). Each module exposes
``run(quick: bool) -> list[Row]``; :mod:`benchmarks.runner` prints one table. These machines are
shared and noisy: figures live here, never in timed tests.
"""
