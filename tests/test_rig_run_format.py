"""A rig run on disk: every channel's columns, a killed run recovered, one channel read as a
one-channel run; a one-channel run exactly as before."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gateway.errors import DataError
from gateway.recorder import RunRecorder
from gateway.runs import COLUMNS, SCHEMA, channel_capture, load_run

NAMES = ["left", "right"]


def rig_meta() -> dict:
    return {"experiment": {"name": "meander", "params": {"amplitude_pct": 5.0}},
            "clock": "lockstep", "period_s": 0.002, "limits": {"force_limit_kgf": None},
            "rig": {"name": "two", "buses": [{"name": "can0", "spec": "udp_loopback:x",
                                              "capture": "capture-can0.log"}],
                    "channels": [{"name": n, "bus": "can0", "force_limit_kgf": 900.0 + k,
                                  "nodes": {"valve": {"id": 2 * k + 1}, "dynamometer": {"id": 2 * k + 2}}}
                                 for k, n in enumerate(NAMES)],
                    "driven": ["left"]}}


def record(rec: RunRecorder, cycles: int) -> None:
    for k in range(cycles):
        rec.append_cycle(k * 0.002, k, 1e9 + k * 0.002, [5.0, 0.0], [10.0 * k, -3.0 * k],
                         [math.nan, math.nan], [k, -k], [4.9, 0.0], [0x0F, 0x0F], [False, k == 3])


def test_a_rig_run_has_every_channels_columns_and_reads_back_per_channel(tmp_path):
    rec = RunRecorder(tmp_path / "run", rig_meta(), channels=NAMES,
                      files={"signals": "signals.parquet", "captures": {"can0": "capture-can0.log"}})
    record(rec, 10)
    rec.close()
    run = load_run(tmp_path / "run")
    assert run.channels == NAMES
    assert list(run.signals)[:3] == ["t", "cycle", "sync_time"]
    assert {"u.left", "y.right", "stale.right", "valve_status.left"} <= set(run.signals)
    right = load_run(tmp_path / "run", channel="right")
    assert list(right.signals) == list(COLUMNS)
    np.testing.assert_array_equal(right.y, -3.0 * np.arange(10))
    assert right.stale.tolist() == [k == 3 for k in range(10)]
    assert right.meta["channel"] == "right" and right.meta["limits"]["force_limit_kgf"] == 901.0
    assert right.experiment is None and "held a zero command" in right.meta["experiment"]["note"]
    assert load_run(tmp_path / "run").channel("left").experiment == "meander"
    assert channel_capture(tmp_path / "run", "right") == (tmp_path / "run" / "capture-can0.log", (3, 4))


def test_a_killed_rig_run_is_recovered_with_every_channel(tmp_path):
    rec = RunRecorder(tmp_path / "run", rig_meta(), channels=NAMES, flush_s=0.0)
    record(rec, 7)
    rec.sync()                                 # on disk; the process "dies" before close
    run = load_run(tmp_path / "run", channel="left")
    assert run.recovered and len(run) == 7 and run.y[-1] == 60.0


def test_a_channel_that_is_not_there_is_named_with_the_channels(tmp_path):
    rec = RunRecorder(tmp_path / "run", rig_meta(), channels=NAMES)
    record(rec, 2)
    rec.close()
    with pytest.raises(DataError, match="no channel 'middle'; its channels: left, right"):
        load_run(tmp_path / "run", channel="middle")
    with pytest.raises(DataError, match="choose a channel with --channel NAME"):
        channel_capture(tmp_path / "run", None)


def test_a_one_channel_run_is_written_exactly_as_before(tmp_path):
    rec = RunRecorder(tmp_path / "run", {"bus": "udp_loopback:stand0"})
    assert rec.schema == SCHEMA and rec.columns == COLUMNS
    rec.append_cycle(0.0, 0, 1e9, [1.0], [2.0], [math.nan], [3], [0.5], [0x0F], [False])
    rec.append(0.002, 1.5, 2.5, math.nan, 1, 4, 0.5, 0x0F, False, 1e9 + 0.002)
    rec.close()
    meta = json.loads((tmp_path / "run" / "run.json").read_text())
    assert meta["files"] == {"signals": "signals.parquet", "capture": "capture.log"}
    assert "rig" not in meta
    run = load_run(tmp_path / "run")
    assert list(run.signals) == list(COLUMNS) and run.channels == []
    assert run.u.tolist() == [1.0, 1.5] and run.y_counts.tolist() == [3, 4]
    with pytest.raises(DataError, match="one-channel run"):
        load_run(tmp_path / "run", channel="left")
