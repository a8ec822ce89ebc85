"""The polish's Jacobian: the g and Δ columns from the objective's affine form equal the forward
differences they replace; the other columns are scipy's own; models not affine fall back."""
from __future__ import annotations

import numpy as np
import pytest

from analysis.identification import fit as F
from analysis.identification.projection import GainTrendColumns
from analysis.identification.windows import Piece, pieces_from_records, residual
from analysis.records import synthetic as S
from plant import PlantModel


def _pieces(known: bool = False) -> list[Piece]:
    truth = PlantModel.from_spec("base+reversal", {"g": 95.0, "tau": 0.06, "delta": 5.0,
                                                   "reversal.boost": 2.5})
    rec = S.meander(truth, (5.0, 20.0), period_s=2.0, cycles=2, seed=7)
    pieces = pieces_from_records([rec])
    if known:    # a rig channel: a known force rate from the other channels
        p = pieces[0]
        t = np.arange(len(p.u)) * p.dt
        pieces = [Piece(p.u, p.y, p.dt, p.window, p.warmup, p.record, p.start, p.t0,
                        known=40.0 * np.sin(2 * np.pi * 0.3 * t))]
    return pieces


def _jacobians(spec: str, pieces: list[Piece], values: dict):
    """(the polish's Jacobian or None, forward differences of jac="2-point") at ``values``."""
    m = PlantModel.from_spec(spec, values)
    par = F.Parameterization(spec, m.params(), list(m.params()))
    lo, hi = par.bounds()
    last: list = [None, None]

    def fun(x):
        r = residual(par.model(x), pieces)
        last[:] = [x.copy(), r]
        return r

    x = par.to_x(m.params())
    r = fun(x)
    fd = F.approx_derivative(fun, x, method="2-point", rel_step=F.DIFF_STEP, f0=r, bounds=(lo, hi))
    jac = F._jacobian_with_gain_trend(par, pieces, fun, last, (lo, hi))
    return par, (None if jac is None else jac(x)), fd


@pytest.mark.parametrize("spec,known", [("base", False), ("base+reversal", False),
                                        ("base+command_reversal+lag", False),
                                        ("base+reversal", True)])
def test_gain_and_trend_columns_from_the_affine_form_equal_the_finite_differences(spec, known):
    pieces = _pieces(known)
    par, J, fd = _jacobians(spec, pieces, {"g": 88.0, "tau": 0.05, "delta": -3.0})
    assert J is not None, f"{spec} is affine in g and Δ: its columns need no simulation"
    scale = np.abs(fd).max(axis=0)
    for name in ("g", "delta"):
        i = par.free.index(name)
        # forward differences are off by their truncation, ~ half the step (log g: 1e-6·4.5)
        assert np.abs(J[:, i] - fd[:, i]).max() <= 2e-5 * scale[i], name
    others = [i for i, n in enumerate(par.free) if n not in ("g", "delta")]
    assert np.array_equal(J[:, others], fd[:, others])     # scipy's own steps, bit for bit


@pytest.mark.parametrize("spec", ["base+stiffness", "base+reversal+stiction", "base+leakage",
                                  "base+load_pressure"])
def test_a_model_not_affine_in_gain_and_trend_keeps_finite_differences(spec):
    par, J, _ = _jacobians(spec, _pieces(), {"g": 88.0})
    assert J is None
    assert GainTrendColumns.of(spec, _pieces()) is None


def test_the_polish_with_the_affine_columns_ends_where_finite_differences_end(monkeypatch):
    pieces = _pieces()
    spec = "base+reversal"
    par = F.Parameterization(spec, PlantModel.from_spec(spec).params(),
                             list(PlantModel.from_spec(spec).params()))
    start = {**par.values, "g": 80.0, "tau": 0.05, "delta": 0.0, "reversal.boost": 2.0}
    x_new, _ = F._polish(par, pieces, start, None, F.FTOL)
    monkeypatch.setattr(F, "_jacobian_with_gain_trend", lambda *a, **k: None)
    x_fd, _ = F._polish(par, pieces, start, None, F.FTOL)
    assert np.allclose(x_new, x_fd, rtol=1e-6, atol=1e-8)
