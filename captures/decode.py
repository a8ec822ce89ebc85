"""The decode pipeline: capture file → chunks → DBC signals → control-cycle rows → run format.

::

    result = decode_capture("bench.log", out="runs/bench")   # writes runs/bench/{run.json,signals.parquet}
    signals, meta, notes = capture_run("bench.log")          # one run's signals, in memory

Memory is bounded by the chunk size (about 1 MB of capture at a time) plus the Parquet row
groups being written, whatever the length of the capture; ``partition_rows`` splits the output
into part files (``signals.parquet/part-NNNNN.parquet``) for week-long captures, and
``frames_dir`` additionally writes every decoded message as its own Parquet dataset
(``FRAMES/<message>/part-NNNNN.parquet``: ``ts`` + one column per signal).

A capture may hold several runs (a logger left running while the gateway ran several
experiments); each run starts with the 0x1006 period download. :func:`decode_capture` writes one
run directory per run (``OUT`` for one run, ``OUT/run-000``, ``OUT/run-001``, ... for several).
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from core.durable import write_json
from gateway.errors import DataError
from gateway.recorder import prepare_run_dir, versions
from gateway.runs import FORMAT, META_FILE, SCHEMA, SIGNALS_FILE

from .cycles import COLUMNS, CycleAssembler, RunInfo, StandSignals
from .dbcdecode import DecodeStats, FrameDecoder
from .dbctable import DEFAULT_DBC
from .frames import CaptureDamaged, CaptureError, Damage, FrameChunk, ReadStats
from .parquet import PartWriter, frames_schema
from .readers import capture_format, open_capture


@dataclass
class DecodeOptions:
    """How to read a capture.

    ``period_s``: the control period if the capture does not say it (overrides the 0x1006
    download and the median SYNC interval); ``clock``: "lockstep" / "realtime" / None (auto);
    ``channel``: only frames of this channel (several buses in one file; None: the channel the
    stand's first SYNC comes on, :meth:`CycleAssembler.choose_channel`); ``run``: only this run
    (0-based) of a capture holding several; ``on_damage``: "stop" at the first damaged
    line/object (everything before it is decoded) or "skip" it and go on (candump lines,
    BLF containers and objects)."""

    dbc: Any = None
    period_s: float | None = None
    clock: str | None = None
    channel: str | None = None
    run: int | None = None
    on_damage: str = "stop"
    chunk_bytes: int | None = None
    #: a rig's bus: read the channel whose valve and dynamometer have these node ids
    #: (:mod:`captures.nodes`); None: the stand's nodes 1 and 2
    nodes: tuple[int, int] | None = None
    signals: StandSignals = field(default_factory=StandSignals)

    def validate(self) -> None:
        if self.period_s is not None and not (0 < self.period_s < 10):
            raise CaptureError(f"period {self.period_s} s is out of range; give the control period "
                               "in seconds (e.g. 0.002)")
        if self.clock not in (None, "lockstep", "realtime"):
            raise CaptureError(f"clock must be 'lockstep' or 'realtime', not {self.clock!r}")
        if self.on_damage not in ("stop", "skip"):
            raise CaptureError(f"on_damage must be 'stop' or 'skip', not {self.on_damage!r}")
        if self.run is not None and self.run < 0:
            raise CaptureError(f"run {self.run}: runs are numbered from 0")
        if self.nodes is not None:
            from .nodes import node_table
            try:
                node_table(*self.nodes)
            except (TypeError, ValueError) as exc:
                raise CaptureError(f"nodes {self.nodes!r}: {exc}") from None


@dataclass
class DecodeResult:
    """What a decode produced and saw."""

    path: Path
    format: str
    options: DecodeOptions
    runs: list[RunInfo]
    frames: DecodeStats
    read: ReadStats
    elapsed_s: float
    force_scale: float
    signals: dict[int, dict[str, np.ndarray]] = field(default_factory=dict)
    #: with ``trace=True``: per-SYNC force trace of each run (see CycleAssembler.take_trace)
    traces: dict[int, dict[str, np.ndarray]] = field(default_factory=dict)
    outputs: list[Path] = field(default_factory=list)
    frames_dir: Path | None = None

    @property
    def damage(self) -> Damage | None:
        return self.read.damage

    @property
    def frames_per_s(self) -> float:
        return self.frames.frames / self.elapsed_s if self.elapsed_s > 0 else float("nan")

    def runs_with_rows(self) -> list[RunInfo]:
        return [r for r in self.runs if r.rows]

    def notes(self, run: RunInfo | None = None) -> list[str]:
        """Human-readable findings (damage, skipped frames, stale cycles)."""
        f, out = self.frames, []
        if self.options.nodes is not None:
            valve, dyn = self.options.nodes
            out.append(f"read the channel of valve node {valve} and dynamometer node {dyn}; the "
                       "other nodes' frames are counted as unknown ids")
        if self.damage is not None:
            out.append(f"capture damaged at {self.damage}; everything before it was decoded")
        if self.read.damaged:
            what = "region(s) (containers or objects)" if self.format == "blf" else "line(s)"
            out.append(f"{self.read.damaged} damaged {what} skipped (first at "
                       f"{self.read.first_damage.position}: {self.read.first_damage.reason})")
        if f.unknown:
            ids = ", ".join(list(f.unknown_ids)[:8])
            out.append(f"{f.unknown} frame(s) with ids not in the DBC skipped ({ids})")
        if f.wrong_dlc:
            out.append("frames with the wrong length for their message, not decoded: "
                       + ", ".join(f"{k} ×{v}" for k, v in f.wrong_dlc.items()))
        if f.out_of_order:
            out.append(f"{f.out_of_order} timestamp(s) went backwards (up to {f.max_backstep_s * 1e3:.3g} ms); "
                       "frames were taken in file order")
        if f.error_frames:
            out.append(f"{f.error_frames} CAN error frame(s)")
        if f.other_channel:
            others = ", ".join(f.other_channels)
            if f.channel_chosen is not None:
                out.append(f"frames on several channels: the stand's loop read from "
                           f"{f.channel_chosen} (its first SYNC), {f.other_channel} frame(s) of "
                           f"{others} skipped; to read another, decode it with stand decode --channel NAME")
            else:
                out.append(f"{f.other_channel} frame(s) of other channels ({others}) skipped")
        for r in ([run] if run is not None else self.runs):
            if r.stale:
                out.append(f"run {r.index}: {r.stale} stale cycle(s) (force TPDO late or missing; "
                           "the last reading is held)")
            if r.tpdo_resyncs:
                out.append(f"run {r.index}: {r.tpdo_resyncs} lost or duplicated TPDO(s) on the bus")
        return out

    def meta(self, run: RunInfo) -> dict[str, Any]:
        """``run.json`` of one decoded run (the gateway's format, plus where it came from)."""
        return {
            "format": FORMAT,
            "status": "damaged" if self.damage is not None else "complete",
            "end_reason": "capture_damaged" if self.damage is not None else None,
            "source": "capture",
            "capture": {"path": str(self.path.resolve()), "format": self.format,
                        "bytes": _size(self.path), "dbc": str(self.options.dbc or DEFAULT_DBC),
                        "run": run.index, "runs_in_capture": len(self.runs_with_rows()),
                        **({} if self.options.nodes is None else
                           {"nodes": {"valve": self.options.nodes[0],
                                      "dynamometer": self.options.nodes[1]}})},
            "experiment": None,
            "clock": run.clock,
            "period_s": run.period_s,
            "period_source": run.period_source,
            "clock_source": run.clock_source,
            "force_scale_kgf_per_count": self.force_scale,
            "started": _iso(run.first_sync_ts),
            "ended": _iso(run.last_sync_ts),
            "rows": run.rows,
            "decode": {"run": run.as_dict(), "frames": self.frames.as_dict(), "reader": self.read.as_dict(),
                       "elapsed_s": self.elapsed_s, "frames_per_s": self.frames_per_s,
                       "notes": self.notes(run)},
            "versions": versions(),
            "command": sys.argv,
            "files": {"signals": SIGNALS_FILE},
        }

    def summary(self) -> str:
        f = self.frames
        lines = [f"{self.path}: {f.frames:,} frames ({self.format}) in {self.elapsed_s:.2f} s "
                 f"({self.frames_per_s:,.0f} frames/s); {f.decoded:,} decoded, {f.unknown:,} unknown id, "
                 f"{sum(f.wrong_dlc.values()):,} wrong length"]
        for r in self.runs_with_rows():
            lines.append(f"  run {r.index}: {r.rows:,} cycles, period {r.period_s * 1e3:.6g} ms "
                         f"({r.period_source}), {r.clock}, {r.stale} stale")
        return "\n".join(lines)


def _size(path: Path) -> int | None:
    try:
        return path.stat().st_size
    except OSError:
        return None


def _iso(ts: float | None) -> str | None:
    if ts is None or not (1e8 < ts < 1e10):
        return None
    return _dt.datetime.fromtimestamp(ts, _dt.timezone.utc).isoformat(timespec="milliseconds")


def iter_frames(path: str | Path, chunk_bytes: int | None = None, on_damage: str = "stop"):
    """The capture's frames as :class:`FrameChunk` s (raises :class:`CaptureDamaged` after the
    last good chunk if the file is damaged)."""
    reader = open_capture(path, chunk_bytes, on_damage)
    yield from reader
    if reader.stats.damage is not None:
        raise CaptureDamaged(reader.stats.damage)


def decode_frames(path: str | Path, dbc=None, chunk_bytes: int | None = None,
                  on_damage: str = "stop") -> Iterator[tuple[FrameChunk, dict]]:
    """Every known message of every chunk, decoded with the DBC:
    ``(chunk, {message: DecodedMessage})``. The vectorized decoder on its own."""
    decoder = FrameDecoder(dbc)
    reader = open_capture(path, chunk_bytes, on_damage)
    for chunk in reader:
        yield chunk, decoder.decode(chunk)
    if reader.stats.damage is not None:
        raise CaptureDamaged(reader.stats.damage)


class _RunOutputs:
    """Streams each run's rows into a staging directory; finalised into run directories."""

    def __init__(self, out: Path, partition_rows: int | None, only_run: int | None) -> None:
        self.out = out
        self.partition_rows = partition_rows
        self.only_run = only_run
        self.writers: dict[int, PartWriter] = {}
        self.stage = out / f".decoding-{os.getpid()}"

    def write(self, run: int, rows: dict) -> None:
        if self.only_run is not None and run != self.only_run:
            return
        w = self.writers.get(run)
        if w is None:
            d = self.stage / f"run-{run:03d}"
            d.mkdir(parents=True, exist_ok=True)
            w = self.writers[run] = PartWriter(d / SIGNALS_FILE, SCHEMA, self.partition_rows)
        w.write(rows)

    def finish(self, result: DecodeResult) -> list[Path]:
        for w in self.writers.values():
            w.close()
        runs = [r for r in result.runs_with_rows() if r.index in self.writers]
        paths = []
        for r in runs:
            target = self.out if len(runs) == 1 else self.out / f"run-{r.index:03d}"
            target.mkdir(parents=True, exist_ok=True)
            os.replace(self.stage / f"run-{r.index:03d}" / SIGNALS_FILE, target / SIGNALS_FILE)
            write_json(target / META_FILE, result.meta(r))
            paths.append(target)
        shutil.rmtree(self.stage, ignore_errors=True)
        return paths

    def abort(self) -> None:
        for w in self.writers.values():
            try:
                w.close()
            except Exception:
                pass
        shutil.rmtree(self.stage, ignore_errors=True)


class _FramesOutput:
    """Every decoded message as its own Parquet dataset under ``root``."""

    def __init__(self, root: Path, partition_rows: int | None) -> None:
        self.root = root
        self.partition_rows = partition_rows
        self.writers: dict[str, PartWriter] = {}

    def write(self, decoded: dict) -> None:
        for name, dm in decoded.items():
            names = list(dm.phys)
            w = self.writers.get(name)
            if w is None:
                target = self.root / name
                target.mkdir(parents=True, exist_ok=True)
                w = self.writers[name] = PartWriter(target if self.partition_rows else target / "part-00000.parquet",
                                                    frames_schema(names, dm.phys), self.partition_rows)
            w.write({"ts": dm.ts, **{n: dm.phys[n] for n in names}})

    def finish(self) -> None:
        for w in self.writers.values():
            w.close()


class _NoCycles:
    """Stands in for the cycle assembler when the DBC does not describe the stand's loop."""

    wanted: dict = {}
    runs: list = []

    def choose_channel(self, chunk) -> None:
        pass

    def feed(self, chunk, decoded) -> None:
        pass

    def take_rows(self) -> list:
        return []

    def take_trace(self) -> list:
        return []

    def finish(self) -> list:
        return []


def run_dbc(capture: Path, nodes: tuple[int, int] | None = None) -> Path | None:
    """The DBC a run directory keeps beside its capture for devices other than the emulated
    pair (run.json ``files.dbc``: one file, or a rig's file per channel, found by its node
    ids ``nodes``); None: the stand's DBC."""
    meta_path = capture.parent / META_FILE
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError):
        return None
    files = meta.get("files") or {}
    dbc = files.get("dbc")
    if isinstance(dbc, str):
        return capture.parent / dbc
    if isinstance(dbc, dict):
        for ch in (meta.get("rig") or {}).get("channels", []):
            ids = ((ch.get("nodes") or {}).get("valve", {}).get("id"),
                   (ch.get("nodes") or {}).get("dynamometer", {}).get("id"))
            if (nodes is None or tuple(nodes) == ids) and ch.get("name") in dbc:
                return capture.parent / dbc[ch["name"]]
    return None


def decode_capture(path: str | Path, out: str | Path | None = None, *, collect: bool = True,
                   partition_rows: int | None = None, frames_dir: str | Path | None = None,
                   progress: bool = False, trace: bool = False, options: DecodeOptions | None = None,
                   **option_kwargs) -> DecodeResult:
    """Decode a capture into control-cycle rows (the gateway's run format).

    Parameters
    ----------
    out : directory to write the run(s) into (one run directory per run in the capture)
    collect : keep the rows in memory (``result.signals[run]``); turn off for huge captures
    partition_rows : split the Parquet output into part files of at most this many rows
    frames_dir : also write every decoded message as a Parquet dataset here
    trace : also keep the per-SYNC force trace of every run (``result.traces[run]``)
    options / option_kwargs : :class:`DecodeOptions` (dbc, period_s, clock, channel, run, ...)
    """
    opts = options or DecodeOptions(**option_kwargs)
    opts.validate()
    path = Path(path)
    if opts.dbc is None:
        opts.dbc = run_dbc(path, opts.nodes)
    reader = open_capture(path, opts.chunk_bytes, opts.on_damage)
    fmt = capture_format(path)
    decoder = FrameDecoder(opts.dbc, channel=opts.channel)
    try:
        assembler = CycleAssembler(decoder, opts.signals, opts.period_s, opts.clock, sync_trace=trace)
    except (ValueError, DataError) as exc:
        if out is not None or frames_dir is None or trace:
            raise CaptureError(f"the DBC does not describe the stand's loop ({exc}); give the "
                               "stand's DBC, or only decode the messages (frames_dir / --frames)") from None
        assembler = None            # another bus: every message decoded, no control cycles
    force_scale = float(assembler.force_scale.scale) if assembler is not None else float("nan")
    collected: dict[int, list[dict]] = {}
    traced: dict[int, list[dict]] = {}
    outputs = _RunOutputs(prepare_run_dir(out), partition_rows, opts.run) if out is not None else None
    frames_out = _FramesOutput(Path(frames_dir), partition_rows) if frames_dir is not None else None
    wanted = None if frames_out is not None else assembler.wanted
    if assembler is None:
        assembler = _NoCycles()
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=_size(path), unit="B", unit_scale=True, desc=f"decode {path.name}", leave=False,
                   disable=None)

    def deliver(pieces):
        for run, part in assembler.take_trace():
            if opts.run is None or run == opts.run:
                traced.setdefault(run, []).append(part)
        for run, rows in pieces:
            if collect and (opts.run is None or run == opts.run):
                collected.setdefault(run, []).append(rows)
            if outputs is not None:
                outputs.write(run, rows)

    table = None
    if opts.nodes is not None:
        from .nodes import node_table, remap_nodes
        table = node_table(*opts.nodes)
    t0 = time.perf_counter()
    try:
        done = 0
        for chunk in reader:
            if table is not None:
                remap_nodes(chunk, table)
            assembler.choose_channel(chunk)
            decoded = decoder.decode(chunk, wanted)
            if frames_out is not None:
                frames_out.write(decoded)
            assembler.feed(chunk, {k: v for k, v in decoded.items() if k in assembler.wanted})
            deliver(assembler.take_rows())
            if bar is not None:
                bar.update(reader.stats.bytes_read - done)
                done = reader.stats.bytes_read
        deliver(assembler.finish())
    except BaseException:
        if outputs is not None:
            outputs.abort()
        raise
    finally:
        if bar is not None:
            bar.close()
    elapsed = time.perf_counter() - t0
    if frames_out is not None:
        frames_out.finish()
    result = DecodeResult(path, fmt, opts, assembler.runs, decoder.stats, reader.stats, elapsed,
                          force_scale, frames_dir=Path(frames_dir) if frames_dir else None)
    result.signals = {run: {c: np.concatenate([p[c] for p in parts]) for c in COLUMNS}
                      for run, parts in collected.items()}
    result.traces = {run: {c: np.concatenate([p[c] for p in parts]) for c in parts[0]}
                     for run, parts in traced.items()}
    if outputs is not None:
        result.outputs = outputs.finish(result)
    return result


def capture_run(path: str | Path, strict: bool = False, **options) -> tuple[dict, dict, list[str]]:
    """One run of a capture as its signals (t, u, y, r = NaN, ...), its metadata and the notes
    on what decoding met (what :func:`analysis.load_capture` makes a record of).

    A capture holding several runs needs ``run=i``. A damaged capture gives what was decoded
    before the damage, with a note naming the position (``strict=True``: raise
    :class:`CaptureDamaged` instead)."""
    result = decode_capture(path, **options)
    runs = result.runs_with_rows()
    if result.damage is not None and strict:
        raise CaptureDamaged(result.damage, partial=result)
    if not runs:
        where = f" before the damage at {result.damage.position}" if result.damage else ""
        raise DataError(f"{path}: no control cycles found{where} (no SYNC followed by an RPDO with "
                        f"ControlWord {result.options.signals.active_control_word}); "
                        f"{result.frames.frames:,} frames read, by message: {result.frames.per_message}")
    if result.options.run is None and len(runs) > 1:
        listing = "; ".join(f"run {r.index}: {r.rows} cycles from {_iso(r.first_sync_ts) or r.first_sync_ts}"
                            for r in runs)
        raise DataError(f"{path} holds {len(runs)} runs ({listing}); choose one with run=N "
                        "(stand decode --run N)")
    if result.options.run is not None:
        runs = [r for r in runs if r.index == result.options.run]
        if not runs:
            raise DataError(f"{path}: there is no run {result.options.run}; the capture holds runs "
                            f"{', '.join(str(r.index) for r in result.runs_with_rows())}")
    run = runs[0]
    return result.signals[run.index], result.meta(run), result.notes(run)
