"""The diagnosis's confusion matrix (tests/support/confusion.py), a representative few of its
cells: the issue's two pairs that ended unexplained (a sensor lag with the reversal boost, a
play in the rod's travel with a valve lag), a resonance that rings beside the boost, a single
effect at the larger noise, and a lag on P feedback (named, or said apart from a delay). The
whole matrix is a benchmark (``scripts/bench confusion``; docs/benchmarks.md)."""
from __future__ import annotations

import pytest

from analysis import stepwise
from tests.support.confusion import NAMES, Cell, judge, matrix, records, shown

CELLS = [Cell(("reversal", "sensor_lag"), "meander"), Cell(("lag", "stiction"), "meander"),
         Cell(("resonance", "reversal"), "meander"), Cell(("deadzone",), "meander", 1),
         Cell(("lag",), "pfeedback")]


@pytest.mark.slow
@pytest.mark.parametrize("cell", CELLS, ids=lambda c: f"{c.label}-{c.excitation}-{c.seed}")
def test_a_cell_of_the_matrix_is_named_right(cell):
    recs = records(cell)
    r = stepwise(recs, jobs=1)
    o = judge(cell, r, shown(cell, recs))
    assert o.right, (o.taken_for, r.summary)
    assert not o.overdamped_resonance, r.summary
    named = {e.name for e in r.model.effects}
    if cell.excitation == "meander":      # steps show every effect here: each one is named
        assert all(named & NAMES[t] for t in cell.effects), r.summary
    if "resonance" in cell.effects:       # on its own evidence, and the step says why
        step = next(s for s in r.steps if s.added == "resonance")
        assert "preferred over +" in step.line and "it rings" in step.line, step.line
        assert "+lag (" in step.line and "+sensor_lag (" in step.line, step.line
        assert r.model.params()["resonance.damping"] == pytest.approx(0.2, rel=0.1)
    if cell == Cell(("lag",), "pfeedback"):  # three reference frequencies: the lag itself, or
        # said apart from a delay (at one frequency a lag shifts like a delay)
        lag = "lag" in named and r.model.params()["lag.time_constant"] == pytest.approx(0.03, rel=0.1)
        assert lag or any(set(a.effects) == {"lag", "delay"} for a in r.ambiguities), r.summary


def test_the_matrix_holds_every_effect_alone_and_each_pair_with_the_boost_and_the_lag():
    cells = matrix(seeds=2)
    sets = {c.effects for c in cells}
    assert len(sets) == 21 + 18 + 19 and len(cells) == 4 * len(sets)
    assert ("reversal", "sensor_lag") in sets and ("lag", "stiction") in sets
    assert not any(set(s) >= {"reversal", "travel_reversal"} for s in sets)   # one boost a stand


def test_a_cell_is_judged_by_names_equivalents_and_what_is_said_apart():
    from types import SimpleNamespace as NS

    from plant import PlantModel
    from plant.evidence import Ambiguity

    def result(spec, ambiguities=(), verdict="adequate"):
        m = PlantModel.from_spec(spec)
        return NS(model=m, ambiguities=list(ambiguities), verdict=verdict,
                  steps=[NS(model="base", added=None, over_floor=1.0)])

    cell = Cell(("lag", "reversal"), "pfeedback")
    both = {"lag": True, "reversal": True}
    assert judge(cell, result("base+reversal+sensor_lag"), both).right       # an equivalent
    o = judge(cell, result("base+reversal"), both)
    assert not o.right and o.missed == ["lag"]
    said = Ambiguity(["lag", "delay"], "", "")
    assert judge(cell, result("base+reversal", [said]), both).right          # said apart
    o = judge(cell, result("base+reversal+lag+leakage"), both)
    assert not o.right and o.spurious == ["leakage"]
    # an effect the records do not show is right named or not
    assert judge(Cell(("slew",), "pfeedback"), result("base"), {"slew": False}).right
