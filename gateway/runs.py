"""The run directory: what every recorded run looks like on disk, and how to read it back.

::

    RUN/
      run.json          metadata: experiment and parameters, bus, node ids and identities,
                        period, clock, versions, start/end, why it ended, counters.
                        A run that did not complete has ``status`` "stopped" (the
                        supervisor or the experiment stopped it) or "aborted" (error,
                        Ctrl-C/SIGTERM), ``end_reason``/``end_message``, and for a
                        supervisor stop ``safety`` (reason, action, onset/detected/
                        safe_state wall times, reaction_s, bound_s, unload);
                        ``events`` lists indicate-only limit crossings; ``stats`` counts
                        stale/late cycles and ignored frames (docs/safety.md)
      signals.parquet   one row per control cycle (columns below)
      signals.arrows    the same while the run is going (Arrow IPC stream, flushed at least
                        every 0.5 s); a run cut short by a crash keeps only this file, and
                        :func:`load_run` recovers every complete chunk from it
      capture.log       raw bus capture (candump -L format, python-can logger); it begins with
                        the start-up (boot, identity, configuration: its first
                        ``startup.frames`` frames, run.json)
      stand.dbc         only for devices other than the emulated pair: the stand's DBC for
                        them as configured (the capture is decoded with it)
      truth.json        only for emulated runs: the emulator's true parameters. Written by the
                        tool that started the emulator; the analysis never reads it.

Signals (one row per cycle; SI-ish units in the names' docs):

=============  ========  =====================================================================
t              float64   s since the run's first SYNC (lockstep: cycle × period exactly)
u              float64   valve command sent after this cycle's force reading, % (as on the
                         wire: 0x6300:01 counts / 163.84)
y              float64   force read at this cycle's SYNC, kgf
r              float64   reference force, kgf (NaN for open-loop experiments)
cycle          int64     cycle number from 0
y_counts       int32     the amplifier's raw process value (its counts; a REAL32 value in its
                         unit's last decimal digit)
spool          float64   the valve's reported actual value at this SYNC, % (NaN: not sent)
valve_status   uint16    the valve's status word at this SYNC
stale          bool      no fresh force PDO this cycle (y repeats the last reading)
sync_time      float64   wall-clock time the SYNC was sent (s since the epoch)
=============  ========  =====================================================================

**A rig run** (many channels, :mod:`rig`) keeps ``t``, ``cycle`` and ``sync_time`` (the first
bus's SYNC; every bus's SYNC goes out right after it with the same counter) and the channel
columns once per channel, named ``<column>.<channel>`` (``u.root_left``, ``y.root_left``, ...);
one capture per bus, ``capture-<bus>.log``; run.json has a ``rig`` section (name, period, G if
known, buses with their capture and budget, channels with bus, node ids, identities, range,
force limit and whether the experiment drove them). ``load_run(path, channel=NAME)`` gives one
channel as a one-channel run (the columns above, the metadata of that channel), which is what
the analysis reads (``--channel NAME``).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.ipc
import pyarrow.parquet as pq

from .errors import DataError

FORMAT = "hydrostand-run/1"
META_FILE = "run.json"
SIGNALS_FILE = "signals.parquet"
STREAM_FILE = "signals.arrows"
CAPTURE_FILE = "capture.log"
DBC_FILE = "stand.dbc"
TRUTH_FILE = "truth.json"

SCHEMA = pa.schema([
    ("t", pa.float64()), ("u", pa.float64()), ("y", pa.float64()), ("r", pa.float64()),
    ("cycle", pa.int64()), ("y_counts", pa.int32()), ("spool", pa.float64()),
    ("valve_status", pa.uint16()), ("stale", pa.bool_()), ("sync_time", pa.float64()),
])
COLUMNS = tuple(SCHEMA.names)
#: the columns a rig run has once per channel (``<name>.<channel>``), and once per run
CHANNEL_COLUMNS = ("u", "y", "r", "y_counts", "spool", "valve_status", "stale")
RIG_RUN_COLUMNS = ("t", "cycle", "sync_time")


def capture_file(bus: str) -> str:
    """A rig run's capture of one bus."""
    return f"capture-{bus}.log"


def rig_schema(channels: list[str]) -> pa.Schema:
    """The signals of a rig run: ``t, cycle, sync_time``, then each channel's columns."""
    types = {f.name: f.type for f in SCHEMA}
    fields = [(name, types[name]) for name in RIG_RUN_COLUMNS]
    fields += [(f"{col}.{ch}", types[col]) for col in CHANNEL_COLUMNS for ch in channels]
    return pa.schema(fields)


@dataclass
class Run:
    """A recorded run: signals as numpy arrays plus its metadata."""

    path: Path
    meta: dict[str, Any]
    signals: dict[str, np.ndarray]
    recovered: bool = False          #: True if read from the crash-safe stream (no clean close)
    notes: list[str] = field(default_factory=list)

    def __getattr__(self, name: str) -> np.ndarray:
        signals = self.__dict__.get("signals")
        if signals is not None and name in signals:
            return signals[name]
        raise AttributeError(name)

    def __len__(self) -> int:
        return len(self.signals["t"])

    @property
    def experiment(self) -> str | None:
        return (self.meta.get("experiment") or {}).get("name")

    @property
    def channels(self) -> list[str]:
        """A rig run's channels (empty for a one-channel run)."""
        return rig_channels(self.meta)

    def channel(self, name: str) -> "Run":
        """One channel of a rig run as a one-channel run (see the module docstring)."""
        return channel_view(self, name)


def rig_channels(meta: dict[str, Any]) -> list[str]:
    return [c["name"] for c in (meta.get("rig") or {}).get("channels", [])]


def channel_view(run: Run, name: str) -> Run:
    """Channel ``name`` of the rig run ``run``: the one-channel columns and metadata (its bus,
    nodes, limits; the experiment only if it drove this channel)."""
    rig = run.meta.get("rig")
    if not rig:
        raise DataError(f"{run.path} is a one-channel run, not a rig run: it has no channel "
                        f"{name!r} (leave --channel out)")
    entry = next((c for c in rig.get("channels", []) if c["name"] == name), None)
    if entry is None:
        raise DataError(f"{run.path}: rig {rig.get('name')!r} has no channel {name!r}; its "
                        f"channels: {', '.join(rig_channels(run.meta))}")
    sig = run.signals
    signals = {}
    for col in COLUMNS:
        key = col if col in RIG_RUN_COLUMNS else f"{col}.{name}"
        if key in sig:
            signals[col] = sig[key]
    meta = {k: v for k, v in run.meta.items() if k not in ("rig", "files")}
    bus = next((b for b in rig.get("buses", []) if b["name"] == entry["bus"]), {})
    meta.update(channel=name, bus=bus.get("spec"), nodes=entry.get("nodes"),
                files={"signals": SIGNALS_FILE, "capture": bus.get("capture")},
                rig_run={"name": rig.get("name"), "channels": rig_channels(run.meta),
                         "driven": rig.get("driven", []), "bus": entry["bus"]})
    limits = dict(meta.get("limits") or {})
    limits["force_limit_kgf"] = entry.get("force_limit_kgf")
    meta["limits"] = limits
    if name not in rig.get("driven", []):
        meta["experiment"] = {"name": None, "params": {},
                              "note": f"channel {name} held a zero command while "
                                      f"{', '.join(rig.get('driven', []))} ran "
                                      f"{(run.meta.get('experiment') or {}).get('name')}"}
    return Run(path=run.path, meta=meta, signals=signals, recovered=run.recovered,
               notes=list(run.notes))


def is_run_dir(path: str | Path) -> bool:
    path = Path(path)
    return path.is_dir() and (path / META_FILE).exists()


def read_stream(path: Path) -> tuple[pa.Table, str | None]:
    """All complete record batches of a (possibly truncated) Arrow IPC stream."""
    batches = []
    problem = None
    schema = SCHEMA
    try:
        with pa.OSFile(str(path), "rb") as fh:
            reader = pa.ipc.open_stream(fh)
            schema = reader.schema
            while True:
                try:
                    batches.append(reader.read_next_batch())
                except StopIteration:
                    break
    except (pa.ArrowInvalid, OSError) as exc:
        problem = f"stream ends in an incomplete chunk after {sum(len(b) for b in batches)} rows ({exc})"
    return pa.Table.from_batches(batches, schema=schema), problem


def load_run(path: str | Path, channel: str | None = None) -> Run:
    """Read a run directory (also one whose recorder was killed: see :data:`STREAM_FILE`);
    ``channel``: one channel of a rig run, as a one-channel run (:func:`channel_view`)."""
    path = Path(path)
    meta_path = path / META_FILE
    if not meta_path.exists():
        raise DataError(f"{path} is not a run directory (no {META_FILE})")
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise DataError(f"{meta_path}: unreadable metadata: {exc}") from None
    notes: list[str] = []
    recovered = False
    if (path / SIGNALS_FILE).exists():
        try:
            table = pq.read_table(path / SIGNALS_FILE)
        except (pa.ArrowInvalid, OSError) as exc:
            raise DataError(f"{path / SIGNALS_FILE}: unreadable: {exc}") from None
    elif (path / STREAM_FILE).exists():
        table, problem = read_stream(path / STREAM_FILE)
        recovered = True
        notes.append(f"recovered {table.num_rows} rows from {STREAM_FILE}: the recorder did not "
                     "close the run cleanly")
        if problem:
            notes.append(problem)
    else:
        raise DataError(f"{path} has no signals ({SIGNALS_FILE} or {STREAM_FILE})")
    signals = {name: table.column(name).to_numpy(zero_copy_only=False) for name in table.column_names}
    run = Run(path=path, meta=meta, signals=signals, recovered=recovered, notes=notes)
    return run if channel is None else channel_view(run, channel)


def read_truth(path: str | Path) -> dict[str, Any] | None:
    """The emulator's truth for a run (for reports that show it beside the estimates)."""
    truth = Path(path) / TRUTH_FILE
    if not truth.exists():
        return None
    return json.loads(truth.read_text())


def channel_capture(path: str | Path, channel: str | None) -> tuple[Path, tuple[int, int]]:
    """A rig run's channel: the capture of its bus and its (valve, dynamometer) node ids, which
    :func:`captures.decode.decode_capture` reads with ``nodes=``. Without ``channel``, a clear
    error listing the channels."""
    path = Path(path)
    try:
        meta = json.loads((path / META_FILE).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise DataError(f"{path}: not a readable run directory ({exc})") from None
    rig = meta.get("rig")
    if not rig:
        raise DataError(f"{path} is a one-channel run: its capture is {path / CAPTURE_FILE}")
    names = rig_channels(meta)
    if channel is None:
        raise DataError(f"{path} is a run of the rig {rig.get('name')!r}: choose a channel with "
                        f"--channel NAME ({', '.join(names)})")
    entry = next((c for c in rig["channels"] if c["name"] == channel), None)
    if entry is None:
        raise DataError(f"{path}: rig {rig.get('name')!r} has no channel {channel!r}; its "
                        f"channels: {', '.join(names)}")
    bus = next(b for b in rig["buses"] if b["name"] == entry["bus"])
    nodes = entry["nodes"]
    return path / bus["capture"], (int(nodes["valve"]["id"]), int(nodes["dynamometer"]["id"]))
