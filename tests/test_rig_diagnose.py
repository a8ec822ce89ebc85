"""Each channel of a rig diagnosed with the coupling in its model (analysis.diagnosis.rig), on
any concurrent.futures executor: in order, a local process pool, a dask cluster on loopback;
the user's plug-ins reach the workers as sources."""
from __future__ import annotations

import numpy as np
import pytest

from analysis.diagnosis.rig import diagnose_rig, same_results
from analysis.executors import InlineExecutor, local_executor, rig_executor
from analysis.rig.estimate import estimate_rig
from analysis.rig.result import starting_models
from analysis.rig.synthetic import per_column_meanders, rig_meander
from core.errors import DataError, ParameterError
from plant import PlantModel, plugins
from plant.catalogue import CATALOGUE
from plant.rig import RigModel
from tests.support.plugins import RIPPLE, isolated_catalogue
from tests.support.rig_models import chain_rig, two_channel_rig

CANDIDATES = ["reversal", "lag"]


@pytest.fixture(scope="module")
def lag_and_reversal():
    """Channel a: a valve lag; channel b: a reversal boost; coupled 30/36 %; both meanders at
    once (periods 4 and 6 s, 36 s)."""
    a = PlantModel.from_spec("base+lag", {"tau": 0.04, "delta": 5.0, "lag.time_constant": 0.03})
    b = PlantModel.from_spec("base+reversal", {"tau": 0.05, "delta": -3.0, "reversal.boost": 2.0})
    rig = two_channel_rig(a, b)
    return rig, rig_meander(rig, [5.0, 5.0], [4.0, 6.0], 36.0, seed=7)


def test_each_channel_is_found_with_its_own_effect_when_the_coupling_is_in_its_model(lag_and_reversal):
    rig, rec = lag_and_reversal
    d = diagnose_rig([rec], rig, effects=CANDIDATES)
    a, b = d.channels
    assert (a.verdict, a.spec) == ("adequate", "base+lag"), a.summary
    assert (b.verdict, b.spec) == ("adequate", "base+reversal"), b.summary
    assert a.params["lag.time_constant"] == pytest.approx(0.03, rel=0.1)
    # one amplitude tells the boost at that amplitude, b·(10 %/|u|)^p, not b and p apart
    at_5 = b.params["reversal.boost"] * 2.0 ** b.params["reversal.exponent"]
    assert at_5 == pytest.approx(2.0 * 2.0 ** 0.7, rel=0.05)
    assert a.params["g"] == pytest.approx(120.0, rel=0.003)
    assert b.params["tau"] == pytest.approx(0.05, abs=0.002)
    # the rig model arrived at: each channel's g on G's diagonal, the coupling as given
    assert d.rig.G[0, 0] == a.params["g"] and d.rig.G[0, 1] == rig.G[0, 1]
    assert [m.spec for m in d.rig.channels] == ["base+lag", "base+reversal"]


@pytest.fixture(scope="module")
def per_column():
    """The 3-channel chain (left and right uncoupled, mid coupled to both), one run per
    column, and the rig model its estimate saves (G and base+reversal starting models)."""
    rig = chain_rig()
    runs = per_column_meanders(rig, 5.0, 4.0, 4, seed=4)
    return rig, runs, starting_models(estimate_rig(runs))


def test_a_per_column_campaign_diagnoses_each_channel_from_the_runs_that_move_its_force(per_column):
    rig, runs, model = per_column
    d = diagnose_rig(runs, model, effects=CANDIDATES)
    for c, truth in zip(d.channels, rig.channels):
        assert (c.verdict, c.spec) == ("adequate", "base+reversal"), (c.name, c.summary)
        assert c.params["g"] == pytest.approx(truth.g, rel=0.001), c.name
        assert c.params["tau"] == pytest.approx(truth.params()["tau"], abs=0.001), c.name
    # left and right are not coupled: each other's column run moves nothing of theirs
    assert len(d.notes) == 2 and all("neither its valve nor the coupling" in n for n in d.notes)
    assert d.notes[0].startswith("left: left out") and "right moving" in d.notes[0]


def test_a_channel_whose_valve_moves_in_no_run_is_not_diagnosed_and_is_said(per_column):
    rig, runs, model = per_column
    # mid's column run moves every force, but only mid's valve
    with pytest.raises(DataError, match="the valves of left, right do not move in"):
        diagnose_rig(runs[1:2], model, ["left", "right"], effects=CANDIDATES)
    d = diagnose_rig(runs[1:2], model, ["left", "mid"], effects=CANDIDATES, build_up=False)
    assert [c.name for c in d.channels] == ["mid"]
    assert d.notes[0].startswith("left: not diagnosed: its valve moves in none of the runs")
    assert d.rig.channels[0].params() == model.channels[0].params()       # left as it was


@pytest.mark.slow
def test_without_the_coupling_the_same_channel_is_not_explained(lag_and_reversal):
    rig, rec = lag_and_reversal
    uncoupled = RigModel(rig.channels, np.diag(np.diag(rig.G)), rig.names)
    b = diagnose_rig([rec], uncoupled, ["b"], effects=CANDIDATES).channels[0]
    assert b.verdict != "adequate" or abs(b.params["g"] - 100.0) > 2.0, b.summary


@pytest.mark.slow
def test_a_local_process_pool_gives_the_results_of_one_process(lag_and_reversal):
    rig, rec = lag_and_reversal
    inline = diagnose_rig([rec], rig, effects=CANDIDATES, build_up=False)
    with local_executor(2) as ex:
        pooled = diagnose_rig([rec], rig, effects=CANDIDATES, build_up=False, executor=ex)
    assert same_results(inline, pooled, rel=0.0)


@pytest.mark.slow
def test_a_dask_cluster_gives_the_local_pools_results_and_loads_the_plugin_in_its_workers(tmp_path):
    """distributed.LocalCluster on loopback (two worker processes, no dashboard): channel a has
    a plug-in effect loaded in this process only; its workers get the plug-in's source."""
    distributed = pytest.importorskip("distributed")
    plugin = tmp_path / "ripple.py"
    plugin.write_text(RIPPLE)
    with isolated_catalogue():
        plugins.load_plugins([str(plugin)])
        a = PlantModel.from_spec("base+ripple", {"tau": 0.04, "delta": 5.0,
                                                 "ripple.amplitude": 30.0, "ripple.frequency": 1.3})
        b = PlantModel.from_spec("base+reversal", {"tau": 0.05, "delta": -3.0,
                                                   "reversal.boost": 2.0})
        rig = two_channel_rig(a, b)
        rec = rig_meander(rig, [5.0, 5.0], [4.0, 6.0], 36.0, seed=3)
        effects = ["reversal", "ripple"]
        with local_executor(2) as ex:
            pooled = diagnose_rig([rec], rig, effects=effects, executor=ex)
        assert [c.spec for c in pooled.channels] == ["base+ripple", "base+reversal"]
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                      host="127.0.0.1", dashboard_address=None) as cluster:
            with rig_executor(scheduler=cluster.scheduler_address) as ex:
                clustered = diagnose_rig([rec], rig, effects=effects, executor=ex)
        assert same_results(pooled, clustered, rel=0.0)
        assert clustered.channels[0].params["ripple.amplitude"] == pytest.approx(30.0, rel=0.02)


def test_a_shipped_plugin_loads_from_its_text_where_the_file_is_not(tmp_path):
    plugin = tmp_path / "ripple.py"
    plugin.write_text(RIPPLE)
    with isolated_catalogue():
        plugins.load_plugins([str(plugin)])
        shipped = plugins.shippable_plugins()
        assert [(s.kind, s.effects) for s in shipped] == [("file", ("ripple",))]
    plugin.unlink()
    with isolated_catalogue():
        assert "ripple" not in CATALOGUE
        assert plugins.load_shipped(shipped) == ["ripple"]
        assert "ripple" in CATALOGUE
        assert plugins.load_shipped(shipped) == ["ripple"]          # once per process
        edited = plugins.ShippedPlugin("file", shipped[0].where,
                                       RIPPLE.replace('"pump ripple"', '"edited"'), ("ripple",))
        plugins.load_shipped([edited])                                 # a newer text replaces it
        assert CATALOGUE["ripple"].summary == "edited"


def test_the_executor_is_inline_for_one_job_and_an_unreachable_scheduler_is_said(monkeypatch):
    assert isinstance(local_executor(1), InlineExecutor)
    with pytest.raises(ParameterError, match="out of range"):
        local_executor(0)
    pytest.importorskip("distributed")
    from analysis import executors
    monkeypatch.setattr(executors, "CONNECT_TIMEOUT_S", 0.5)
    with pytest.raises(ParameterError, match="cannot reach a dask scheduler"):
        with rig_executor(scheduler="tcp://127.0.0.1:9"):
            pass
    with pytest.raises(ParameterError, match="give one"):
        with rig_executor(jobs=2, scheduler="tcp://127.0.0.1:9"):
            pass
