"""The valve-limited minimum time of a programme: every segment a haversine at the largest rate
the model says the valve delivers within the feedforward's share of the command limit, each way
and at each force; `stand load --plan` prints it beside the programme's time without touching
the stand."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from core.errors import ParameterError
from loading.minimum_time import FEEDFORWARD_SHARE, programme_timing, valve_limit
from loading.programme import from_levels
from plant import PlantModel
from stand.cli import main as stand

T = 0.002
LEVELS = [500.0, 5500.0, 1500.0, 3000.0, 2800.0]


def test_on_the_base_model_each_segment_takes_pi_span_over_twice_the_valve_rate():
    model = PlantModel.from_spec("base", {"g": 120.0, "tau": 0.05, "delta": 8.0})
    p = from_levels(LEVELS, T, rate_kgf_s=2500)
    timing = programme_timing(p, model, 100.0)
    up, down = 120.0 * FEEDFORWARD_SHARE * 100 + 8.0, 120.0 * FEEDFORWARD_SHARE * 100 - 8.0
    spans = np.diff(LEVELS)
    want = [math.pi * abs(s) / (2 * (up if s > 0 else down)) for s in spans]
    assert np.allclose(timing.minimum_s, want, rtol=1e-6)
    assert timing.minimum_time_s == pytest.approx(sum(want), rel=1e-6)
    assert timing.programme_time_s == pytest.approx(p.duration_s)
    # 2500 kgf/s against 10 800: the programme is 4.3 times slower than the valve allows
    assert timing.ratio == pytest.approx(p.duration_s / sum(want))
    assert 4.2 < timing.ratio < 4.4


def test_an_asymmetric_valve_a_flow_limit_and_a_sagging_supply_each_set_their_own_limit():
    values = {"g": 80.0, "tau": 0.07, "delta": 0.0}
    asym = valve_limit(PlantModel.from_spec("base+asymmetry", {**values, "asymmetry.ratio": 0.1}),
                       100.0, np.array([3000.0]))
    assert asym.up_kgf_s[0] == pytest.approx(80 * 90 * 1.1) and asym.down_kgf_s[0] == pytest.approx(80 * 90 * 0.9)
    flow = valve_limit(PlantModel.from_spec("base+saturation", {**values, "saturation.limit": 40.0}),
                       100.0, np.array([3000.0]))
    assert flow.up_kgf_s[0] == pytest.approx(80 * 40) and flow.down_kgf_s[0] == pytest.approx(80 * 40)
    # a settled sag k·|q|/100 lowers the gain to sqrt(1 - k·q/100): q·sqrt(1 - q/100) peaks at 66.7 %
    sag = valve_limit(PlantModel.from_spec("base+supply", {**values, "supply.sag": 1.0}),
                      100.0, np.array([3000.0]))
    best = 200 / 3
    assert sag.up_kgf_s[0] == pytest.approx(80 * best * math.sqrt(1 - best / 100), rel=2e-3)
    # a reversal boost lasts a moment: it does not raise the limit
    boost = valve_limit(PlantModel.from_spec("base+reversal", values), 100.0, np.array([3000.0]))
    assert boost.up_kgf_s[0] == pytest.approx(80 * 90, rel=1e-6)


def test_a_leak_that_outruns_the_valve_is_refused_naming_the_segment():
    model = PlantModel.from_spec("base+leakage", {"g": 10.0, "tau": 0.05, "leakage.rate": 0.5})
    p = from_levels([500.0, 1500.0, 2500.0], T, rate_kgf_s=500)      # 0.5·1800 kgf/s > 900 kgf/s
    with pytest.raises(ParameterError, match="cannot move the force from 1500 to 2500 kgf .segment 2."):
        programme_timing(p, model, 100.0)


def test_stand_load_plan_prints_both_times_and_needs_no_stand(tmp_path, capsys):
    ctl = tmp_path / "c.toml"
    assert stand(["design", "base+reversal", "-o", str(ctl)]) == 0
    seq = tmp_path / "tp.csv"
    seq.write_text("level\n" + "\n".join(f"{v:g}" for v in LEVELS) + "\n")
    capsys.readouterr()
    assert stand(["load", str(seq), "--rate", "2500", "--controller", str(ctl), "--plan",
                  "--bus", "udp_loopback:nobody-listens"]) == 0
    out = capsys.readouterr().out
    assert "at the requested rate:" in out and "valve-limited minimum:" in out and "4.3" in out
    assert stand(["load", str(seq), "--rate", "2500", "--controller", str(ctl), "--plan", "--json",
                  "--command-limit", "50"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["command_limit_pct"] == 50 and s["largest_rate_up_kgf_s"] == pytest.approx(120 * 45)
    assert s["minimum_time_s"] * s["ratio"] == pytest.approx(s["programme_time_s"])
    assert not list(tmp_path.glob("pass-*"))
    rc = stand(["load", str(seq), "--rate", "2500", "--controller", str(ctl)])
    err = capsys.readouterr().err
    assert rc == 2 and "give --out DIR" in err and "Traceback" not in err
