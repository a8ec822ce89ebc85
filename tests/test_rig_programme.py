"""Multi-channel programmes (loading.programme, loading.programme_files): load cases where every channel arrives at
the same moment, per-channel sequences on one clock, and every mistake named before anything
moves."""
from __future__ import annotations

import math

import numpy as np
import pytest

from core.errors import DataError, ParameterError
from loading.programme import from_load_cases, random_load_cases
from loading.programme_files import load_programme, write_load_cases

T = 0.002
NAMES = ["root", "inner", "outer", "tip"]


def write(tmp_path, text, name="cases.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_every_channel_reaches_each_load_case_together_at_the_rate_of_the_one_that_moves_most(tmp_path):
    p = write(tmp_path, "case,tip,root,inner,outer\n"
                        "1,300,500,500,300\n2,1500,4000,2500,300\n3,800,1000,2600,2000\n")
    prog = load_programme(str(p), NAMES, T, rate_kgf_s=2500)
    assert prog.load_cases and prog.names == NAMES and prog.case_labels == ["1", "2", "3"]
    idx = prog.turning_idx
    for ch in prog.channels:
        assert np.array_equal(ch.turning_idx, idx)
    assert prog.levels_kgf.tolist() == [[500, 4000, 1000], [500, 2500, 2600], [300, 300, 2000], [300, 1500, 800]]
    # segment 1: root moves 3500 kgf, the most: pi*3500/(2*2500) s; segment 2: root 3000
    assert np.diff(idx) * T == pytest.approx([math.pi * 3500 / 5000, math.pi * 3000 / 5000], abs=T)
    assert np.max(np.abs(prog.channel("root").rate_kgf_s())) == pytest.approx(2500, rel=1e-3)
    assert np.max(np.abs(prog.channel("inner").rate_kgf_s()[:idx[1]])) == pytest.approx(2500 * 2000 / 3500, rel=1e-3)
    # outer holds its level over the first segment (a repeated level is a hold)
    outer = prog.channel("outer").r_kgf[:idx[1] + 1]
    assert np.all(outer == 300)


def test_a_frequency_gives_every_segment_half_a_period():
    prog = from_load_cases([[0, 1000, 200], [0, -500, 100]], ["a", "b"], T, frequency_hz=0.5)
    assert np.diff(prog.turning_idx).tolist() == [500, 500]


@pytest.mark.parametrize("text, match", [
    ("case,root,inner,outer\n1,1,2,3\n2,4,5,6\n", "no column for channel\\(s\\) tip"),
    ("case,root,inner,outer,tip,wing\n1,1,2,3,4,5\n2,2,3,4,5,6\n", "'wing' is not a channel"),
    ("root,inner,outer,tip,tip\n1,2,3,4,5\n2,3,4,5,6\n", "'tip' appears twice"),
    ("1,2,3,4\n5,6,7,8\n", "needs a header naming the channels"),
    ("case,root,inner,outer,tip\n1,1,2,3,4\n2,1,2,3,4\n", "load cases 1 and 2 are the same"),
    ("case,root,inner,outer,tip\n1,1,2,3,4\n", "at least 2 load cases"),
    ("case,root,inner,outer,tip\n1,1,2,x,4\n2,2,3,4,5\n", "cases.csv:2: 'x' is not a number"),
])
def test_a_bad_load_case_file_is_refused_naming_the_file_the_line_or_the_column(tmp_path, text, match):
    with pytest.raises((DataError, ParameterError), match=match):
        load_programme(str(write(tmp_path, text)), NAMES, T, rate_kgf_s=2500)


def test_load_cases_need_a_rate_or_a_frequency(tmp_path):
    p = write(tmp_path, "case,root,inner,outer,tip\n1,1,2,3,4\n2,2,3,4,5\n")
    with pytest.raises(ParameterError, match="--rate"):
        load_programme(str(p), NAMES, T)


def test_channel_names_match_regardless_of_case(tmp_path):
    p = write(tmp_path, "CASE,Left,right\n1,100,200\n2,900,300\n")
    prog = load_programme(str(p), ["left", "Right"], T, rate_kgf_s=1000)
    assert prog.levels_kgf.tolist() == [[100, 900], [200, 300]]


def test_per_channel_sequences_run_on_one_clock_the_shorter_holding_its_last_level(tmp_path):
    write(tmp_path, "level\n0\n2000\n500\n", "a.csv")
    (tmp_path / "prog.toml").write_text('[channel.a]\nprogramme = "a.csv"\nrate = 1000\n'
                                        '[channel.b]\nprogramme = "sine:mean=1000,amplitude=200,frequency=1,cycles=2"\n')
    prog = load_programme(str(tmp_path / "prog.toml"), ["a", "b"], T)
    assert not prog.load_cases and prog.names == ["a", "b"]
    a, b = prog.channels
    assert len(a.t_s) == len(b.t_s)
    # a: pi*2000/2000 + pi*1500/2000 = 5.50 s, b: 2 s, padded by holding its last level
    assert prog.duration_s == pytest.approx(math.pi * 3500 / 2000, abs=T)
    assert b.r_kgf[-1] == pytest.approx(1000) and b.turning_idx[-1] == len(b.t_s) - 1
    with pytest.raises(ParameterError, match="no load cases"):
        prog.turning_idx


def test_a_per_channel_file_names_the_channel_whose_programme_is_wrong(tmp_path):
    (tmp_path / "prog.toml").write_text('[channel.a]\nprogramme = "missing.csv"\n[channel.b]\nprogramme = "x.csv"\n')
    with pytest.raises(DataError, match=r"\[channel.a\]: programme .*missing.csv"):
        load_programme(str(tmp_path / "prog.toml"), ["a", "b"], T, rate_kgf_s=1000)
    (tmp_path / "p2.toml").write_text('[channel.a]\nprogramme = "sine:mean=0,amplitude=1,frequency=1,cycles=1"\n')
    with pytest.raises(DataError, match=r"no \[channel.b\]"):
        load_programme(str(tmp_path / "p2.toml"), ["a", "b"], T)


def test_a_level_beyond_a_channels_force_limit_is_refused_naming_the_channel():
    prog = from_load_cases([[0, 5000, 100], [0, 4600, 100]], ["wing", "tip"], T, rate_kgf_s=2500)
    prog.check([9000, 5000])
    with pytest.raises(ParameterError, match="channel tip: .*turning point 2 \\(4600 kgf\\)"):
        prog.check([9000, 4500])


def test_random_load_cases_alternate_on_every_channel_and_their_ratios_change(tmp_path):
    L = random_load_cases(20, [(500, 6000), (300, 3000), (300, 3000)], seed=3, antiphase=[False, False, True])
    assert L.shape == (3, 20)
    steps = np.sign(np.diff(L, axis=1))
    assert np.all(steps[0] == steps[1]) and np.all(steps[2] == -steps[0])
    ratios = L[1] / L[0]
    assert np.ptp(ratios) > 0.5
    p = write_load_cases(tmp_path / "lc.csv", L, ["a", "b", "c"])
    back = load_programme(str(p), ["a", "b", "c"], T, rate_kgf_s=2500)
    assert np.allclose(back.levels_kgf, L, atol=0.05)
