"""`stand decode` of a candump log imports what reading and decoding the log needs, not the other
formats' stacks: no python-can (``import can`` loads every log format, ``.mf4``'s asammdf and
pandas among them), no cantools (it imports python-can; the stand's DBC comes from its
precompiled codec table, which must be what cantools gives), no BLF reader, no pandas (pyarrow
imports it to ask whether a numpy column is a pandas one). Every format still decodes, its reader
imported when it is opened."""
from __future__ import annotations

import gzip
import json
import logging
import subprocess
import sys

import can
import numpy as np
import pytest

from captures import FrameChunk, FrameDecoder, decode_capture
from captures.dbctable import compile_table, precompiled_codecs
from captures.synthetic import stand_frames, synthetic_run
from captures.writers import to_messages, write_blf, write_candump
from dbc import STAND_CODECS, STAND_DBC

#: what a candump log's decode needs none of (the stacks of the other formats, and what only
#: other commands use)
NOT_FOR_A_CANDUMP_LOG = ["asammdf", "can", "can.io.blf", "can.io.mf4", "canmatrix", "canopen", "cantools",
                         "captures.blf", "captures.pycan", "matplotlib", "pandas", "scipy"]

_DECODE_AND_LIST_MODULES = (
    "import json, sys\n"
    "from stand.cli import main\n"
    "code = main(['decode', sys.argv[1], '-o', sys.argv[2], '--no-progress'])\n"
    "print(json.dumps({'code': code, 'modules': sorted(sys.modules)}))\n")


def test_stand_decode_of_a_candump_log_imports_no_other_formats_stack(tmp_path):
    log = tmp_path / "stand.log"
    write_candump(log, stand_frames(synthetic_run(200, seed=3)))
    res = subprocess.run([sys.executable, "-c", _DECODE_AND_LIST_MODULES, str(log), str(tmp_path / "run")],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["code"] == 0 and (tmp_path / "run" / "signals.parquet").is_file()
    modules = set(out["modules"])
    assert {"captures.candump", "captures.dbcdecode", "pyarrow.parquet"} <= modules  # the probe sees imports
    imported = sorted(m for m in NOT_FOR_A_CANDUMP_LOG if m in modules)
    assert not imported, f"imported to decode a candump log: {imported}"


def write_with_python_can(path, chunks) -> None:
    with can.Logger(str(path)) as logger:
        for chunk in chunks:
            for m in to_messages(chunk):
                logger.on_message_received(m)


@pytest.mark.parametrize("name", ["stand.log.gz", "stand.blf", "stand.asc", "stand.trc", "stand.mf4"])
def test_every_format_decodes_to_the_same_run_as_the_candump_log(tmp_path, name):
    if name.endswith(".mf4"):
        pytest.importorskip("asammdf", reason="install hydrostand[mf4] to read .mf4 captures")
    chunks = list(stand_frames(synthetic_run(300, seed=5)))
    log = tmp_path / "stand.log"
    write_candump(log, chunks)
    path = tmp_path / name
    if name.endswith(".gz"):
        path.write_bytes(gzip.compress(log.read_bytes()))
    elif name.endswith(".blf"):
        write_blf(path, chunks)
    else:
        write_with_python_can(path, chunks)
    ours, reference = decode_capture(path), decode_capture(log)
    assert [r.rows for r in ours.runs_with_rows()] == [r.rows for r in reference.runs_with_rows()] == [300]
    for column in ("u", "y", "y_counts", "cycle", "stale"):
        assert np.array_equal(ours.signals[0][column], reference.signals[0][column]), column


def test_the_stand_dbc_codec_table_is_what_cantools_gives():
    shipped = json.loads(STAND_CODECS.read_text())
    fresh = compile_table(STAND_DBC)
    shipped.pop("cantools"), fresh.pop("cantools")     # the version it was written with: a note
    assert shipped == fresh, f"{STAND_CODECS} is stale: write it again with python -m captures.dbctable"


def stand_traffic() -> FrameChunk:
    return FrameChunk.concat(list(stand_frames(synthetic_run(50, seed=6))))


def test_the_table_serves_the_stand_dbc_and_a_copy_of_it_but_not_an_edited_one(tmp_path):
    copy, edited = tmp_path / "copy.dbc", tmp_path / "edited.dbc"
    text = STAND_DBC.read_text()
    copy.write_text(text)
    assert "(0.010197162129779284,0)" in text
    edited.write_text(text.replace("(0.010197162129779284,0)", "(0.02,0)"))      # Force in other units
    assert precompiled_codecs() is not None and precompiled_codecs(copy) == precompiled_codecs()
    assert precompiled_codecs(edited) is None
    chunk = stand_traffic()
    force = FrameDecoder().decode(chunk)["TPDO1_Dynamometer"]
    force_edited = FrameDecoder(edited).decode(chunk)["TPDO1_Dynamometer"]        # read with cantools
    assert np.array_equal(force_edited.phys["Force"], force.raw["Force"] * 0.02)


def test_the_decoder_from_the_table_decodes_as_the_decoder_from_cantools():
    from captures import load_dbc
    chunk = stand_traffic()
    from_table, from_cantools = FrameDecoder().decode(chunk), FrameDecoder(load_dbc()).decode(chunk)
    assert from_table.keys() == from_cantools.keys() and len(from_table) >= 5
    for name, message in from_table.items():
        assert np.array_equal(message.index, from_cantools[name].index), name
        for signal, values in message.phys.items():
            assert np.array_equal(values, from_cantools[name].phys[signal]), (name, signal)


def test_a_damaged_or_foreign_table_is_not_used(tmp_path, caplog):
    damaged, foreign = tmp_path / "damaged.json", tmp_path / "foreign.json"
    damaged.write_text('{"format": 1, "dbc_sha256": ')
    table = json.loads(STAND_CODECS.read_text())
    foreign.write_text(json.dumps({**table, "format": 99}))
    with caplog.at_level(logging.WARNING, logger="captures.dbctable"):
        assert precompiled_codecs(STAND_DBC, table=damaged) is None
    assert "python -m captures.dbctable" in caplog.text
    assert precompiled_codecs(STAND_DBC, table=foreign) is None
    assert precompiled_codecs(STAND_DBC, table=tmp_path / "missing.json") is None
