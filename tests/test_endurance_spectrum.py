"""The block and the flight sequence (endurance.spectrum): flight n's block, position and type
are fixed by the seed and the block (pinned literally here: a change of the algorithm fails),
the same in another process, every block holds its counts exactly, and the order is uniform;
the TWIST-like helper's flight types have the shape it promises."""
from __future__ import annotations

import subprocess
import sys
from collections import Counter

import numpy as np
import pytest

from core.errors import ParameterError
from endurance.spectrum import Block, FlightSequence, twist_like_counts, twist_like_levels

COUNTS = {"A": 1, "B": 3, "C": 8}


def test_a_blocks_order_is_pinned_by_its_seed_and_number():
    b = Block(COUNTS, seed=7)
    assert "".join(b.order(1)) == "BBCCCCCCCACB"
    assert "".join(b.order(2)) == "CBBCCCCCBCCA"
    assert "".join(b.order(1000)) == "CBBBACCCCCCC"
    assert "".join(Block(COUNTS, seed=0).order(1)) == "BACCCCCBCCCB"


def test_the_order_is_the_same_in_another_process():
    code = ("from endurance.spectrum import Block; "
            "print(''.join(Block({'A': 1, 'B': 3, 'C': 8}, seed=7).order(2)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={"PYTHONHASHSEED": "12345", "PATH": ""})
    assert out.stdout.strip() == "".join(Block(COUNTS, seed=7).order(2))


def test_seed_and_block_are_separate_words_of_the_seed():
    assert Block(COUNTS, seed=1).order(2) != Block(COUNTS, seed=2).order(1)
    orders = {Block(COUNTS, seed=3).order(k) for k in range(1, 30)}
    assert len(orders) > 20                     # blocks differ (12!/(3!·8!) = 1980 orders)


def test_every_block_holds_its_counts_exactly_and_flight_numbers_map_to_blocks():
    seq = FlightSequence(Block(COUNTS, seed=5), flights=12 * 40 + 5)
    assert seq.blocks == 41
    slots = seq.slots(1, seq.flights)
    for b in range(1, 41):
        assert Counter(s.flight_type for s in slots if s.block == b) == Counter(COUNTS)
    first, last, next_ = seq.slot(1), seq.slot(12), seq.slot(13)
    assert (first.block, first.position, last.block, last.position) == (1, 1, 1, 12)
    assert (next_.block, next_.position) == (2, 1)
    assert [s.number for s in slots] == list(range(1, seq.flights + 1))
    for n in (0, 1, 7, 12, 13, 100, 485):
        brute = Counter(s.flight_type for s in slots[:n])
        assert seq.counts_through(n) == {t: brute.get(t, 0) for t in COUNTS}


def test_the_order_is_uniform_over_positions():
    b = Block(COUNTS, seed=11)
    where_a = Counter(b.order(k).index("A") for k in range(1, 2401))
    expected = 2400 / 12
    chi2 = sum((where_a.get(p, 0) - expected) ** 2 / expected for p in range(12))
    assert chi2 < 31.3                          # 11 degrees of freedom, p = 0.001


@pytest.mark.parametrize("bad,message", [
    (lambda: Block({}), "at least one flight type"),
    (lambda: Block({"A": 0}), "flight type A: 0 flights"),
    (lambda: Block({"A": 1.5}), "flight type A: 1.5 flights"),
    (lambda: Block({"A": 1}, seed=-1), "seed = -1"),
    (lambda: Block({"A": 1}).order(0), "blocks are numbered from 1"),
    (lambda: FlightSequence(Block({"A": 1}), 10).slot(0), "flights are numbered from 1"),
    (lambda: FlightSequence(Block({"A": 1}), 10).slot(11), "the test has 10 flights"),
])
def test_wrong_numbers_are_refused(bad, message):
    with pytest.raises(ParameterError, match=message):
        bad()


def test_twist_like_flight_types_decrease_in_severity_within_the_limits():
    counts = twist_like_counts(10)
    assert counts["A"] == 1 and list(counts.values()) == sorted(counts.values())
    limits = np.array([9000.0, 9000.0, 4500.0, 4500.0])
    levels = twist_like_levels(limits)
    assert list(levels) == list(counts)
    swing = {t: float(np.max(lv[0]) - np.min(lv[0, 1:-1])) for t, lv in levels.items()}
    assert list(swing.values()) == sorted(swing.values(), reverse=True)
    for t, lv in levels.items():
        assert lv.shape[0] == 4
        assert np.all(np.abs(lv) <= 0.9 * limits[:, None])
        assert np.array_equal(lv[:, 0], lv[:, -1]) and np.all(lv[:, 0] < 0)   # ground to ground
        assert np.all(np.any(np.diff(lv, axis=1) != 0, axis=0))               # each case moves
    # the ratios between the channels change from load case to load case
    a = levels["A"]
    assert np.ptp(a[3, 2:-2] / a[0, 2:-2]) > 0.01
