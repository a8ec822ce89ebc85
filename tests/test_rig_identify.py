"""The rig's G, τ and Δ from meanders (analysis.rig): per column and all at once, with the
truth of a synthetic rig inside the intervals, and the runs that cannot tell columns apart
refused with the reason."""
from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.rig.estimate import estimate_rig
from analysis.rig.load import load_rig_inputs
from analysis.rig.periods import (planned_inflation, separating_periods, shares_harmonics,
                                  sharing_pairs)
from analysis.rig.record import make_rig_record
from analysis.rig.result import physical_note, starting_models
from analysis.rig.synthetic import per_column_meanders, rig_meander, rig_truth, write_rig_run
from core.errors import DataError, ParameterError
from rig.config import load_rig_file
from tests.support.rig import EXAMPLE_RIG
from tests.support.rig_models import CHANNELS3, chain_rig, within


@pytest.fixture(scope="module")
def rig():
    return chain_rig()


@pytest.fixture(scope="module")
def columns(rig):
    """The per-column campaign: each channel a ±5 % meander of 4 s, 5 periods, the others at 0."""
    return per_column_meanders(rig, 5.0, 4.0, 5, seed=1)


@pytest.fixture(scope="module")
def simultaneous(rig):
    """All three at once, periods 8, 10, 12 s (separating_periods(3)), 96 s."""
    return rig_meander(rig, [5.0] * 3, separating_periods(3, 8.0), 96.0, seed=2)


def test_per_column_meanders_recover_G_within_its_intervals(rig, columns):
    est = estimate_rig(columns)
    assert est.design == "per-column"
    err = np.abs(est.G - rig.G) / np.diag(rig.G)[None, :]
    assert err.max() < 0.002, est.G            # 0.2 % of the diagonal
    assert within(est, rig.G).sum() >= 8, (est.G, est.G_ci)       # 9 entries at 95 %
    assert within(est, rig.G, widen=1.5).all()
    assert np.allclose(est.delta_kgf_s, [d for _, d, _ in CHANNELS3], atol=0.2)


def test_a_simultaneous_run_with_separating_periods_recovers_G_within_its_intervals(rig, simultaneous):
    est = estimate_rig([simultaneous])
    assert est.design == "simultaneous"
    err = np.abs(est.G - rig.G) / np.diag(rig.G)[None, :]
    assert err.max() < 0.001, est.G
    assert within(est, rig.G).sum() >= 7, (est.G, est.G_ci)       # 9 entries at 95 %
    assert within(est, rig.G, widen=1.5).all()
    assert max(est.inflation) < 1.3            # the periods keep the columns apart (1.15 here)


def test_each_channels_delay_and_transitional_window_come_from_its_own_reversals(rig, simultaneous):
    est = estimate_rig([simultaneous])
    for j, (tau, _, _) in enumerate(CHANNELS3):
        assert abs(est.tau_s[j] - tau) <= 0.0011, est.tau_s
        lo, hi = est.tau_ci_s[j]
        assert lo - 1e-9 <= tau <= hi + 0.0011
    # an exponential boost of 0.15 s adds 90 % of its force within ln(10)·0.15 = 0.345 s
    assert np.allclose(est.transitional_s, 0.345, atol=0.03) and all(est.transitional_detected)


def test_the_starting_models_carry_each_channels_reversal_boost(rig, simultaneous):
    start = starting_models(estimate_rig([simultaneous]))
    for m, (tau, _, boost) in zip(start.channels, CHANNELS3):
        assert m.spec == "base+reversal"
        assert m.params()["reversal.boost"] == pytest.approx(boost, rel=0.08)
        assert m.params()["reversal.decay"] == pytest.approx(0.15, rel=0.08)
    assert np.array_equal(start.G, estimate_rig([simultaneous]).G)


def test_a_simultaneous_run_with_equal_periods_is_refused_naming_the_channels(rig):
    rec = rig_meander(rig, [5.0] * 3, [8.0, 8.0, 12.0], 48.0, seed=3)
    with pytest.raises(DataError) as err:
        estimate_rig([rec])
    msg = str(err.value)
    assert "cannot tell column" in msg and "left" in msg and "mid" in msg
    assert "correlation +1.000" in msg and "period" in msg and "column by column" in msg


def test_a_channel_that_never_moves_leaves_its_column_unknown_and_says_so(rig, columns):
    est = estimate_rig(columns[:2])
    assert np.all(np.isnan(est.G[:, 2])) and np.all(np.isfinite(est.G[:, :2]))
    assert any("right moved in no run" in n for n in est.notes)
    assert not est.physical.checked and "right" in est.physical.text
    assert est.to_dict()["G"][0][2] is None


def test_a_run_that_starts_with_the_valves_held_the_other_way_guards_the_reversal_at_its_start(rig):
    """After a trip the valves were held (the rod moving the other way): each meander reverses
    the rod at its first sample, and the boost after it is no steady stretch. Unguarded, the
    start's long first stretch (a quarter period, weighted by its length cubed) put G 14 % off
    here (60 % through the emulator at 3 s periods)."""
    held = per_column_meanders(rig, 5.0, 4.0, 3, seed=5, u_before_pct=-1.0, y0_kgf=1500.0)
    est = estimate_rig(held)
    err = np.abs(est.G - rig.G) / np.diag(rig.G)[None, :]
    assert err.max() < 0.002, est.G
    assert within(est, rig.G, widen=1.5).all(), (est.G, est.G_ci)


def test_meanders_too_short_for_the_guard_after_their_reversals_are_refused_saying_what_to_do(rig):
    """At 2.5 s a half period (1.25 s) is shorter than the guard after a reversal (4 × the 0.3 s
    transitional window) and a stretch: no steady stretch moves a column of a coupled row."""
    short = per_column_meanders(rig, 5.0, 2.5, 3, seed=5, u_before_pct=-1.0)
    with pytest.raises(DataError, match=r"no steady stretch where channel \w+'s valve moves") as err:
        estimate_rig(short)
    assert "reverses every 1.25 s" in str(err.value)
    assert "--meander-period-s" in str(err.value) and "--guard-ms" in str(err.value)


def test_a_closed_loop_command_is_refused(rig):
    n = 5000
    rng = np.random.default_rng(0)
    u = rng.normal(0, 3, (3, n))
    rec = make_rig_record(np.arange(n) * 0.002, u, np.cumsum(u, axis=1), rig.names)
    with pytest.raises(DataError, match="needs open-loop meanders"):
        estimate_rig([rec])


def test_the_physical_check_of_an_estimate_is_noted_with_its_figures(rig, simultaneous):
    est = estimate_rig([simultaneous])
    assert est.physical.physical, est.physical.text
    assert ("right", "left") in est.physical.zeroed and ("left", "right") in est.physical.zeroed
    assert "asymmetry" in est.physical.text and "smallest eigenvalue" in est.physical.text
    # a G that couples one way only (20 against 0 ± 0.1) is noted as not physical, not refused
    G = rig.G.copy()
    G[0, 2] = 20.0
    ci = np.stack([G - 0.1, G + 0.1], axis=-1)
    note = physical_note(G, ci, rig.names)
    assert note.checked and not note.physical and "couples one way far more" in note.reason


def _ci(G, half):
    return np.stack([G - half, G + half], axis=-1)


def test_an_entry_whose_interval_holds_zero_is_judged_with_its_pair():
    """A short campaign: G[inner,tip] = 0 ± 0.006 beside G[tip,inner] = 0.0164 ± 0.006 (true 0
    both): taking the first as zero and not the second called the rig not physical (a
    structure that couples one way only). Within the intervals the pair couples weakly both
    ways; a pair whose intervals both hold zero is taken as zero on both sides."""
    rig = load_rig_file(EXAMPLE_RIG)
    G, half = rig.G.copy(), np.full((4, 4), 0.006)
    G[1, 3], G[3, 1] = 0.0, 0.0164
    note = physical_note(G, _ci(G, half), rig.names)
    assert note.physical, note.text
    assert ("inner", "tip") not in note.zeroed and ("tip", "inner") not in note.zeroed
    assert {("root", "outer"), ("outer", "root"), ("root", "tip"), ("tip", "root")} == set(note.zeroed)
    # signs within the intervals: -0.004 ± 0.006 may be as positive as its pair
    G[1, 3] = -0.004
    assert physical_note(G, _ci(G, half), rig.names).physical
    # ... but a pair of opposite signs beyond their intervals cannot be
    G[1, 3] = -0.02
    note = physical_note(G, _ci(G, half), rig.names)
    assert not note.physical and "opposite signs even within their intervals" in note.reason


def test_a_loop_of_channels_is_judged_within_the_intervals():
    """Three channels all coupled: the products of the entries one way round and the other
    (20·20·40 against 10·10·20) differ by 8×: not physical with tight intervals, physical when
    the intervals hold a symmetric G."""
    G = np.array([[100.0, 20.0, 10.0], [20.0, 100.0, 20.0], [40.0, 10.0, 100.0]])
    names = ["a", "b", "c"]
    tight = physical_note(G, _ci(G, 0.1), names)
    assert not tight.physical and "loop of channels" in tight.reason
    assert tight.asymmetry > tight.asymmetry_allowed
    loose = physical_note(G, _ci(G, 20.0), names)
    assert loose.physical, loose.text


def test_separating_periods_are_pairwise_orthogonal_within_a_factor_of_two():
    assert separating_periods(4, 8.0) == [8.0, 10.0, 12.0, 15.0]
    for n in (2, 3, 5, 8):
        p = separating_periods(n, 8.0)
        assert len(set(p)) == n and min(p) >= 8.0 and max(p) < 16.0
        assert sharing_pairs(p) == []
        assert max(planned_inflation(p, 8 * max(p))) < 1.06
    with pytest.raises(ParameterError, match="at least 131"):
        separating_periods(16, 8.0)


def test_periods_that_share_odd_harmonics_are_named_and_equal_ones_collinear():
    assert shares_harmonics(8.0, 24.0) and shares_harmonics(6.0, 10.0)
    assert not shares_harmonics(8.0, 12.0) and not shares_harmonics(8.0, 9.0)
    assert sharing_pairs([4.0, 4.0, 6.0, 12.0]) == [(0, 1), (0, 3), (1, 3)]
    vif = planned_inflation([8.0, 8.0, 10.0], 80.0)
    assert math.isinf(vif[0]) and math.isinf(vif[1]) and vif[2] < 1.1
    assert planned_inflation([8.0, 24.0], 120.0)[0] == pytest.approx(1.125, abs=0.01)


def test_rig_runs_on_disk_a_campaign_directory_and_a_table_read_as_the_arrays(rig, columns, tmp_path):
    for rec in columns:
        write_rig_run(rec, tmp_path / "campaign" / rec.source.split(": ")[1].split()[0],
                      rig_truth(rig))
    loaded = load_rig_inputs([tmp_path / "campaign"])
    assert [r.names for r in loaded] == [rig.names] * 3
    assert np.array_equal(estimate_rig(loaded).G, estimate_rig(columns).G)
    table = tmp_path / "rig.csv"
    rec = columns[1]
    cols = ["t"] + [f"{c}.{n}" for n in rec.names for c in ("u", "y")]
    data = np.column_stack([rec.t] + [row for i in range(rec.n) for row in (rec.u[i], rec.y[i])])
    np.savetxt(table, data, delimiter=",", header=",".join(cols), comments="")
    assert np.allclose(load_rig_inputs([table])[0].y, rec.y)


def test_runs_of_another_rig_or_not_of_a_rig_are_refused(rig, columns, tmp_path):
    write_rig_run(columns[0], tmp_path / "a")
    other = make_rig_record(columns[1].t, columns[1].u[:2], columns[1].y[:2], ["left", "mid"])
    write_rig_run(other, tmp_path / "b")
    with pytest.raises(DataError, match="give runs of one rig"):
        load_rig_inputs([tmp_path / "a", tmp_path / "b"])
    (tmp_path / "c").mkdir()
    with pytest.raises(DataError, match="no rig runs in it"):
        load_rig_inputs([tmp_path / "c"])
