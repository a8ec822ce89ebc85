"""core.durable: a record written whole or not at all."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from core.durable import write_json


def test_a_record_is_written_with_numpy_numbers_and_paths_and_no_temporary_file_is_left(tmp_path):
    path = tmp_path / "run.json"
    write_json(path, {"n": np.int64(3), "g": np.float32(0.5), "dir": Path("/x/y"), "ok": True})
    assert json.loads(path.read_text()) == {"n": 3, "g": 0.5, "dir": "/x/y", "ok": True}
    assert [p.name for p in tmp_path.iterdir()] == ["run.json"]


def test_what_json_cannot_hold_is_refused_before_the_old_record_is_touched(tmp_path):
    path = tmp_path / "run.json"
    write_json(path, {"status": "running"})
    with pytest.raises(TypeError, match="not JSON serialisable: object"):
        write_json(path, {"status": "complete", "bad": object()})
    assert json.loads(path.read_text()) == {"status": "running"}
    assert [p.name for p in tmp_path.iterdir()] == ["run.json"]


def test_a_write_that_dies_half_way_leaves_the_old_record_whole(tmp_path, monkeypatch):
    import core.durable as jf
    path = tmp_path / "run.json"
    write_json(path, {"status": "running"})

    def no_disk(fd):
        raise OSError("disk gone")
    monkeypatch.setattr(jf.os, "fsync", no_disk)
    with pytest.raises(OSError, match="disk gone"):
        write_json(path, {"status": "complete"})
    assert json.loads(path.read_text()) == {"status": "running"}
    assert [p.name for p in tmp_path.iterdir()] == ["run.json"]
