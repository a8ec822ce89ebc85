"""Capture → run format: files on disk, partitioned Parquet, the analysis reading captures
directly, several runs, damaged captures, bounded memory, and the ``stand decode`` command."""
from __future__ import annotations

import json
import subprocess
import sys
import tracemalloc

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pytest

from analysis import estimate_meander, load, load_capture
from captures import CaptureDamaged, FrameChunk, decode_capture
from captures.synthetic import FORCE_SCALE, stand_frames, synthetic_run
from captures.writers import write_blf, write_candump
from gateway import load_run
from gateway.errors import DataError
from gateway.runs import COLUMNS, FORMAT, TRUTH_FILE


def capture(tmp_path, cycles=3000, name="c.log", seed=1, model="base+reversal", **kw):
    run = synthetic_run(cycles, seed=seed, model=model, **kw)
    path = tmp_path / name
    (write_blf if name.endswith(".blf") else write_candump)(path, stand_frames(run))
    return run, path


def test_decode_writes_the_gateways_run_format(tmp_path):
    run, path = capture(tmp_path)
    result = decode_capture(path, out=tmp_path / "run")
    assert result.outputs == [tmp_path / "run"]
    rec = load_run(tmp_path / "run")
    assert tuple(rec.signals) == COLUMNS
    assert np.array_equal(rec.y_counts, run.y_counts[:-1]) and np.array_equal(rec.u, run.u)
    assert np.array_equal(rec.t, run.t) and np.array_equal(rec.y, run.y)
    for name in COLUMNS:
        assert np.array_equal(rec.signals[name], result.signals[0][name], equal_nan=True), name
    meta = rec.meta
    assert meta["format"] == FORMAT and meta["status"] == "complete" and meta["source"] == "capture"
    assert meta["period_s"] == 0.002 and meta["period_source"] == "SDO 0x1006" and meta["clock"] == "realtime"
    assert meta["rows"] == run.cycles and meta["decode"]["frames"]["frames"] == result.frames.frames
    assert meta["started"].startswith("2023-11-14T22:13:20")
    assert not (tmp_path / "run" / TRUTH_FILE).exists(), "a capture has no truth"


def test_candump_and_blf_of_the_same_traffic_decode_identically(tmp_path):
    run = synthetic_run(2000, seed=3)
    write_candump(tmp_path / "a.log", stand_frames(run))
    write_blf(tmp_path / "a.blf", stand_frames(run))
    a = decode_capture(tmp_path / "a.log").signals[0]
    b = decode_capture(tmp_path / "a.blf").signals[0]
    for name in COLUMNS:
        assert np.array_equal(a[name], b[name], equal_nan=True), name


def test_partitioned_parquet_is_one_table_for_pyarrow_dataset(tmp_path):
    run, path = capture(tmp_path, 5000)
    decode_capture(path, out=tmp_path / "run", partition_rows=1200, frames_dir=tmp_path / "frames",
                   chunk_bytes=20_000)
    parts = sorted((tmp_path / "run" / "signals.parquet").glob("part-*.parquet"))
    assert len(parts) == 5
    table = ds.dataset(tmp_path / "run" / "signals.parquet", format="parquet").to_table()
    assert table.num_rows == run.cycles
    assert np.array_equal(table.column("y_counts").to_numpy(), run.y_counts[:-1])
    assert np.array_equal(load_run(tmp_path / "run").u, run.u)
    force = ds.dataset(tmp_path / "frames" / "TPDO1_Dynamometer", format="parquet").to_table()
    assert force.num_rows == run.cycles + 1
    assert np.array_equal(force.column("Force").to_numpy(), run.y_counts * FORCE_SCALE)
    assert set(force.column_names) == {"ts", "Force", "ForceStatus"}


def test_parquet_columns_are_the_arrays_pa_array_makes():
    """Columns reach pyarrow as numpy buffers (pa.array would import pandas to inspect them)."""
    from captures.parquet import arrow_column
    rng = np.random.default_rng(1)
    cases = [(rng.normal(size=1001), pa.float64()),
             (rng.integers(-2**40, 2**40, 1001), pa.int64()),
             (rng.integers(-2**31, 2**31, 1001).astype(np.int32), pa.int32()),
             (rng.integers(0, 2**16, 1001).astype(np.uint16), pa.uint16()),
             (rng.random(1001) < 0.3, pa.bool_()),                       # 1001 bits: a partial byte
             (np.arange(3000, dtype=np.int64)[::3], pa.int64()),         # a strided view
             (np.arange(10, dtype=np.int64), pa.int32())]                # another dtype: cast by pa.array
    for values, type in cases:
        column = arrow_column(values, type)
        assert column.type == type and column.null_count == 0
        assert column.equals(pa.array(values, type=type)), type
    with pytest.raises(pa.ArrowInvalid):                                 # and as safely as pa.array
        arrow_column(np.array([0.5]), pa.int64())


def test_every_analysis_reads_a_capture_directly(tmp_path):
    run, path = capture(tmp_path, 6000, model="base", amplitude_pct=5, meander_period_s=2.0)
    rec = load(path)
    assert rec.source == str(path) and rec.experiment is None
    assert np.array_equal(rec.y, run.y) and np.array_equal(rec.u, run.u) and np.all(np.isnan(rec.r))
    assert rec.meta["decode"]["run"]["rows"] == 6000
    est = estimate_meander(rec)
    assert est.g == pytest.approx(120.0, rel=0.03)


def test_several_runs_need_a_choice(tmp_path):
    a = FrameChunk.concat(list(stand_frames(synthetic_run(500, seed=1))))
    b = FrameChunk.concat(list(stand_frames(synthetic_run(800, seed=2), start_s=1_700_000_100.0)))
    path = tmp_path / "two.log"
    write_candump(path, [a, b])
    with pytest.raises(DataError, match="holds 2 runs .*run 0: 500 cycles.*run 1: 800 cycles"):
        load_capture(path)
    assert len(load_capture(path, run=1)) == 800
    result = decode_capture(path, out=tmp_path / "out")
    assert [p.name for p in result.outputs] == ["run-000", "run-001"]
    assert len(load_run(tmp_path / "out" / "run-001")) == 800
    assert load_run(tmp_path / "out" / "run-000").meta["capture"]["runs_in_capture"] == 2


def test_damaged_capture_keeps_what_came_before_and_says_where(tmp_path):
    run, path = capture(tmp_path, 3000)
    lines = path.read_bytes().split(b"\n")
    lines[6000] = b"(1700000012.001000) can0 182#ZZ\x00\x01"
    path.write_bytes(b"\n".join(lines))
    rec = load_capture(path)
    assert 1000 < len(rec) < 3000
    assert np.array_equal(rec.y, run.y[:len(rec)])
    assert any("line 6001" in n and "everything before it was decoded" in n for n in rec.notes)
    with pytest.raises(CaptureDamaged, match="line 6001") as err:
        load_capture(path, strict=True)
    assert err.value.partial.runs[0].rows == len(rec)
    decode_capture(path, out=tmp_path / "run")
    meta = load_run(tmp_path / "run").meta
    assert meta["status"] == "damaged" and meta["decode"]["reader"]["damage"]["line"] == 6001


def test_a_busy_bus_decodes_to_the_stands_run(tmp_path):
    """A capture as a logger on a shared bus writes it: the stand's traffic among another node's
    (its TPDOs, heartbeat, EMCY, SDO, NMT), error frames whose class bits read as the stand's
    ids (0x20000080: SYNC's 0x080), remote requests for the stand's ids, an extended id ending
    in 0x080, and a second bus (can1) with the force TPDO's id. Before, can1's 0x182 frames were
    taken for the dynamometer's: 333 'lost or duplicated' TPDOs, glitches of 2e7 kgf."""
    run, clean = capture(tmp_path, 3000, seed=4)
    rng = np.random.default_rng(0)
    extra = []
    for k, t in enumerate(np.sort(rng.uniform(1_700_000_000.0, 1_700_000_006.0, 2000))):
        stamp = f"({t:.6f})"
        extra.append(f"{stamp} " + [
            f"can0 {rng.choice(['185', '285', '705', '085', '585'])}#{rng.bytes(8).hex().upper()}",
            f"can0 {rng.choice(['20000080', '20000182', '20000004', '20000201'])}#{rng.bytes(8).hex().upper()}",
            f"can0 {rng.choice(['182', '181', '080', '201'])}#R{rng.choice(['', '5', '8'])}",
            f"can1 182#{rng.bytes(5).hex().upper()}",
            f"can0 00000080#{rng.bytes(2).hex().upper()}",
            f"can0 {rng.choice(['000#0105', '605#4000100000000000'])}"][k % 6])
    lines = clean.read_text().splitlines() + extra
    busy = tmp_path / "busy.log"
    busy.write_text("\n".join(sorted(lines, key=lambda ln: float(ln[1:ln.index(")")]))) + "\n")
    a, b = decode_capture(clean).signals[0], decode_capture(busy).signals[0]
    for name in COLUMNS:
        assert np.array_equal(a[name], b[name], equal_nan=True), name
    rec = load(busy)
    assert np.array_equal(rec.y, run.y) and np.array_equal(rec.u, run.u)
    said = " | ".join(rec.notes)
    assert "334 CAN error frame(s)" in said and "ids not in the DBC skipped" in said
    assert "the stand's loop read from can0 (its first SYNC), 333 frame(s) of can1 skipped" in said
    assert not any("glitch" in n or "lost or duplicated" in n for n in rec.notes), rec.notes
    with pytest.raises(DataError, match="no control cycles found"):
        load_capture(busy, channel="can1")


def _peak_bytes(path, **kw) -> int:
    tracemalloc.start()
    try:
        decode_capture(path, collect=False, chunk_bytes=64 * 1024, **kw)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_memory_does_not_grow_with_the_capture(tmp_path):
    """Streaming: the peak of Python/numpy allocations is set by the chunk size, not the file."""
    _, small = capture(tmp_path, 20_000, name="small.log")
    _, large = capture(tmp_path, 80_000, name="large.log")
    assert large.stat().st_size > 3.9 * small.stat().st_size
    p_small = _peak_bytes(small, out=tmp_path / "s", partition_rows=10_000)
    p_large = _peak_bytes(large, out=tmp_path / "l", partition_rows=10_000)
    assert p_large < 1.3 * p_small + 1_000_000, (p_small, p_large)
    assert p_large < large.stat().st_size / 2


def stand_cli(*args):
    res = subprocess.run([sys.executable, "-m", "stand", *args], capture_output=True, text=True, timeout=120)
    assert "Traceback" not in res.stderr + res.stdout, res.stderr
    return res


def test_stand_decode_command(tmp_path):
    run, path = capture(tmp_path, 1500)
    res = stand_cli("decode", str(path), "-o", str(tmp_path / "run"))
    assert res.returncode == 0, res.stderr
    assert "1,500 cycles, period 2 ms (SDO 0x1006), realtime, 0 stale" in res.stdout
    assert np.array_equal(load_run(tmp_path / "run").y_counts, run.y_counts[:-1])
    # the same run again: runs are never overwritten
    res = stand_cli("decode", str(path), "-o", str(tmp_path / "run"))
    assert res.returncode == 2 and "already holds a run" in res.stderr
    # damaged: what came before is written, the error names the line, exit 1
    lines = path.read_bytes().split(b"\n")
    lines[2000] = b"garbage"
    path.write_bytes(b"\n".join(lines))
    res = stand_cli("decode", str(path), "-o", str(tmp_path / "partial"))
    assert res.returncode == 1 and "line 2001" in res.stderr and "everything before it was decoded" in res.stderr
    assert json.loads((tmp_path / "partial" / "run.json").read_text())["status"] == "damaged"


def test_stand_decode_refuses_a_capture_without_cycles(tmp_path):
    path = tmp_path / "heartbeats.log"
    path.write_text("".join(f"(1700000000.{i:06d}) can0 701#05\n" for i in range(50)))
    res = stand_cli("decode", str(path), "-o", str(tmp_path / "run"))
    assert res.returncode == 2 and "no control cycles found" in res.stderr
    assert not (tmp_path / "run").exists()
    res = stand_cli("decode", str(path), "--period-ms", "-1")
    assert res.returncode == 2 and "--period-ms" in res.stderr


def test_another_dbc_decodes_every_message_to_parquet(tmp_path):
    """The decoder is DBC-driven: a bus the stand's DBC does not describe still decodes."""
    run, path = capture(tmp_path, 400)
    dbc = tmp_path / "other.dbc"
    dbc.write_text('VERSION ""\nNS_ :\nBS_:\nBU_: X\n'
                   'BO_ 386 Load: 5 X\n SG_ F : 0|32@1- (0.1,0) [0|0] "N" X\n SG_ S : 32|8@1+ (1,0) [0|0] "" X\n'
                   'BO_ 128 Tick: 1 X\n SG_ N : 0|8@1+ (1,0) [0|0] "" X\n')
    result = decode_capture(path, frames_dir=tmp_path / "frames", dbc=dbc)
    assert result.runs_with_rows() == []
    load_n = ds.dataset(tmp_path / "frames" / "Load", format="parquet").to_table()
    assert np.array_equal(load_n.column("F").to_numpy(), run.y_counts * 0.1)
    assert result.frames.unknown == result.frames.frames - 2 * (run.cycles + 1)
    with pytest.raises(DataError, match="does not describe the stand's loop"):
        decode_capture(path, out=tmp_path / "run", dbc=dbc)
    res = stand_cli("decode", str(path), "--dbc", str(dbc), "--frames", str(tmp_path / "f2"))
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "f2" / "Tick").is_dir()
