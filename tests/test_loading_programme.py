"""Loading programmes: the four forms read into the same sampled reference with its turning
points, compensation moves turning points without changing times, and bad programmes are
refused with the file, the line and what to write."""
from __future__ import annotations

import numpy as np
import pytest

from core.errors import DataError, ParameterError
from loading.programme import check_programme, flight_by_flight, from_levels, random_sequence, sine
from loading.programme_files import load_channel_programme

T = 0.002


def test_a_turning_point_csv_becomes_haversines_at_the_peak_rate(tmp_path):
    f = tmp_path / "tp.csv"
    f.write_text("level\n400\n6200\n# a comment\n1000\n5000\n")
    p = load_channel_programme(str(f), T, rate_kgf_s=2500)
    assert np.allclose(p.levels_kgf, [400, 6200, 1000, 5000])
    assert abs(np.max(np.abs(np.diff(p.r_kgf))) / T - 2500) < 5
    assert p.kinds() == ["start", "peak", "valley", "end"]
    # the first half cycle lasts pi*5800/(2*2500) s
    assert abs(p.t_s[p.turning_idx[1]] - np.pi * 5800 / 5000) < T


def test_a_decimal_comma_sequence_and_a_frequency_are_read(tmp_path):
    f = tmp_path / "tp.csv"
    f.write_text("level;\n400,5;\n3000,25;\n1000;\n", encoding="utf-8")
    p = load_channel_programme(str(f), T, frequency_hz=0.5)
    assert np.allclose(p.levels_kgf, [400.5, 3000.25, 1000])
    assert np.allclose(np.diff(p.t_s[p.turning_idx]), 1.0)


def test_a_sine_spec_has_its_peaks_and_valleys_at_mean_plus_minus_amplitude():
    p = load_channel_programme("sine:mean=3000,amplitude=2000,frequency=0.2,cycles=3", T)
    kinds = p.kinds()
    peaks = p.levels_kgf[[k == "peak" for k in kinds]]
    valleys = p.levels_kgf[[k == "valley" for k in kinds]]
    assert len(peaks) == 3 and len(valleys) == 3
    assert np.allclose(peaks, 5000, atol=0.01) and np.allclose(valleys, 1000, atol=0.01)
    assert abs(p.duration_s - 15.0) < T


def test_a_block_programme_joins_its_blocks(tmp_path):
    f = tmp_path / "blocks.toml"
    f.write_text("[[block]]\nmean = 3000\namplitude = 1000\nfrequency = 0.5\ncycles = 2\n"
                 "[[block]]\nmean = 3000\namplitude = 2000\nfrequency = 0.2\ncycles = 1\n")
    p = load_channel_programme(str(f), T)
    assert np.allclose(p.levels_kgf, [3000, 4000, 2000, 4000, 2000, 5000, 1000, 3000])
    assert np.isclose(p.duration_s, 0.5 + 1 + 1 + 1 + 2.5 + 2.5 + 1.25, atol=T)


def test_a_time_history_is_resampled_and_its_reversals_found(tmp_path):
    t = np.linspace(0, 10, 1001)
    r = 3000 + 2000 * np.sin(2 * np.pi * 0.2 * t) + np.random.default_rng(0).normal(0, 2, t.size)
    f = tmp_path / "hist.csv"
    f.write_text("t,r\n" + "\n".join(f"{a:.4f},{b:.3f}" for a, b in zip(t, r)))
    p = load_channel_programme(str(f), T)
    assert len(p.t_s) == 5001 and p.kinds().count("peak") == 2 and p.kinds().count("valley") == 2


def test_with_levels_moves_the_turning_points_and_keeps_the_times():
    p = from_levels([400, 6200, 1000, 5000], T, rate_kgf_s=2500)
    q = p.with_levels(p.levels_kgf + np.array([0, 30, -20, 0]))
    assert np.allclose(q.levels_kgf, [400, 6230, 980, 5000]) and np.array_equal(q.t_s, p.t_s)
    assert np.all(np.diff(q.r_kgf[: p.turning_idx[1] + 1]) >= 0), "a haversine stays monotonic"


def test_with_durations_sets_each_segment_and_keeps_the_turning_points():
    p = from_levels([400, 6200, 1000, 5000], T, rate_kgf_s=2500)
    q = p.with_durations([1.0, 0.5, 0.25])
    assert np.allclose(q.segment_durations_s, [1.0, 0.5, 0.25]) and np.allclose(q.levels_kgf, p.levels_kgf)
    # a haversine made anew: peak rate pi*span/(2*duration), exact
    assert np.max(np.abs(q.rate_kgf_s()[: q.turning_idx[1]])) == pytest.approx(np.pi * 5800 / 2, rel=1e-6)
    s = sine(3000, 2000, 0.2, 2, T)
    f = s.with_durations(s.segment_durations_s * 0.4)     # any other shape is squeezed: a 0.5 Hz sine
    want = 3000 + 2000 * np.sin(2 * np.pi * 0.5 * f.t_s)
    assert np.max(np.abs(f.r_kgf - want)) < 0.05 and np.allclose(f.levels_kgf, s.levels_kgf, atol=0.01)
    assert np.max(np.abs(f.rate_kgf_s())) == pytest.approx(2000 * 2 * np.pi * 0.5, rel=1e-3)
    with pytest.raises(ParameterError, match="3 positive segment durations"):
        p.with_durations([1.0, 0.0, 1.0])


def test_a_flight_by_flight_sequence_alternates_ground_air_ground_and_gusts():
    lv = flight_by_flight(28, seed=1)
    p = from_levels(lv, T, rate_kgf_s=2500)
    assert len(lv) > 1000 and set(p.kinds()[1:-1]) == {"peak", "valley"}
    assert np.sum(lv == 500.0) == 29, "every flight starts and ends on the ground"
    assert 500 <= lv.min() and lv.max() <= 3500 + 2500


def test_random_sequences_alternate_between_peaks_and_valleys():
    lv = random_sequence(101, 400, 6200, seed=4)
    p = from_levels(lv, T, rate_kgf_s=2500)
    assert set(p.kinds()[1:-1]) == {"peak", "valley"} and lv.min() >= 400 and lv.max() <= 6200


@pytest.mark.parametrize("text, match", [
    ("level\n", "empty programme"),
    ("level\n400\nabc\n", r"tp.csv:3: 'abc' is not a number"),
    ("level\n400\n", "at least 2 turning points"),
    ("level\n400\n400\n", "must differ"),
    ("level\n400\nnan\n", "not a finite number"),
    ("x,y,z\n1,2,3\n", "neither 'level'"),
])
def test_a_bad_turning_point_file_says_where_and_what_to_write(tmp_path, text, match):
    f = tmp_path / "tp.csv"
    f.write_text(text)
    with pytest.raises((DataError, ParameterError), match=match):
        load_channel_programme(str(f), T, rate_kgf_s=2500)


def test_bad_specs_and_rates_are_refused():
    with pytest.raises(ParameterError, match="missing cycles"):
        load_channel_programme("sine:mean=3000,amplitude=2000,frequency=0.2", T)
    with pytest.raises(DataError, match="no such file"):
        load_channel_programme("nothere.csv", T, rate_kgf_s=100)
    with pytest.raises(ParameterError, match="positive"):
        from_levels([0, 100], T, rate_kgf_s=-5)
    with pytest.raises(ParameterError, match="--rate"):
        import tempfile, pathlib
        d = pathlib.Path(tempfile.mkdtemp()) / "tp.csv"
        d.write_text("level\n1\n2\n")
        load_channel_programme(str(d), T)


def test_a_level_beyond_the_force_limit_is_refused_naming_the_point():
    p = from_levels([400, 9800, 1000], T, rate_kgf_s=2500)
    with pytest.raises(ParameterError, match=r"turning point 2 \(9800 kgf\).*force limit"):
        check_programme(p, 9500)
