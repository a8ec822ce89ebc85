"""From decoded frames to the gateway's rows: one row per control cycle, streamed.

The protocol (see :mod:`gateway.loop`)::

    SDO 0x1006 download (period, µs) to both nodes   ← marks the start of a run
    enabling RPDO (ControlWord 7, command 0)           ← before the first SYNC: not a row
    cycle k:  SYNC → valve TPDO (StatusWord, ValvePosition) + dynamometer TPDO (Force, ForceStatus)
              → RPDO (ControlWord, Command)            ← a row iff its ControlWord is 7 (ACTIVE)
    last SYNC: TPDOs, then safe-state RPDOs (ControlWord 3) ← not a row
    a supervisor trip: the last SYNC's cycle is recorded with the safe command (u = 0), which is
              sent twice and once more twice at the end (≥ 3 safe-state RPDOs after that SYNC)

Row k of a run (the columns of :mod:`gateway.runs`):

* ``y`` = Force of the dynamometer TPDO answering SYNC k (kgf = counts × the DBC factor, the same
  double the gateway uses), ``y_counts`` its raw counts;
* ``u`` = Command of the first RPDO after SYNC k (% = counts × 100/16384, as on the wire);
* ``t`` = k × period in lockstep; in real time the SYNC's slot on the period grid,
  n_k = ⌊(ts_k − ts_0)/period + b⌋ (made strictly increasing), t = n_k × period, so cycles the
  gateway skipped after an overrun leave the same gap as in its own record. The bias b puts the
  slot boundary into the widest phase range no SYNC fell into (SYNCs go out late, never early:
  with little jitter b ≈ 0.1; on a loaded host whose SYNCs are up to 0.9 period late b is ≈ 0.05);
* ``r`` = NaN (the reference never goes on the bus); ``sync_time`` = the SYNC's timestamp.

Which TPDO answers which SYNC: each node answers every SYNC once, so the j-th TPDO of a run
answers its j-th SYNC. The file order alone is not enough: a capture written by a multi-threaded
logger (the gateway's own) may store a received TPDO after the next frame the gateway sent. So
TPDOs are paired by count, and the count is re-synchronised from the file order when the two
disagree for at least :data:`RESYNC_AFTER` TPDOs in a row (a TPDO really lost or duplicated on
the bus), effective from where the disagreement began.

Stale cycles (real time only: the gateway gave up waiting and reused the last reading): the
answering TPDO is stored after the cycle's RPDO *and* stamped later than it. In lockstep the
gateway always waits, so only a missing TPDO makes a cycle stale.

The period: an explicit value, else the 0x1006 download of the run, else the median SYNC
interval. The clock: lockstep if the SYNCs are less than half a period apart (the wall clock
of a lockstep run says nothing about stand time), else real time.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dbc import profile as P
from gateway.runs import COLUMNS as RUN_COLUMNS, SCHEMA

from .dbcdecode import DecodedMessage, FrameDecoder
from .frames import ERROR, EXTENDED, REMOTE, FrameChunk

RESYNC_AFTER = 8          #: TPDOs in a row that must disagree with the count before it is re-synced
MARGIN_SYNCS = 32         #: SYNCs kept back at the end of a chunk until later frames arrive
GRID_SYNCS = 200          #: real time: SYNCs looked at to place the slot boundary (see _grid_bias)
SAFE_REPEATS = 3          #: safe-state RPDOs after a run's last SYNC that mark a recorded trip cycle

SAFE_CONTROL_WORDS = (int(P.CW_HOLD), int(P.CW_DISABLED))

#: the run format's signals, as the gateway records them (one definition: gateway.runs.SCHEMA)
COLUMNS = RUN_COLUMNS
_DTYPES = {f.name: np.dtype(f.type.to_pandas_dtype()).type for f in SCHEMA}


@dataclass(frozen=True)
class StandSignals:
    """Names of the DBC signals that carry the loop (override for another DBC)."""

    force: str = "Force"
    force_status: str = "ForceStatus"      #: optional: kept in the per-SYNC trace if present
    command: str = "Command"
    control_word: str = "ControlWord"
    status_word: str = "StatusWord"
    spool: str = "ValvePosition"
    sync_message: str = "SYNC"
    active_control_word: int = int(P.CW_ACTIVE)


@dataclass
class RunInfo:
    """What the assembler learned about one run in the capture."""

    index: int
    period_s: float | None = None
    period_source: str | None = None      #: "argument" | "SDO 0x1006" | "median SYNC interval"
    period_us_written: list = field(default_factory=list)
    clock: str | None = None              #: "lockstep" | "realtime"
    #: "argument" | "SDO 0x2100" (the gateway read the emulator clock at run start) | "SYNC timing"
    clock_source: str | None = None
    clock_read: list = field(default_factory=list)
    first_sync_ts: float | None = None
    last_sync_ts: float | None = None
    syncs: int = 0
    rows: int = 0
    stale: int = 0
    syncs_without_force: int = 0
    syncs_without_row: int = 0
    tpdo_resyncs: int = 0                 #: count re-synchronisations (lost/duplicated TPDOs)
    tpdos_unpaired: int = 0               #: TPDOs that answer no SYNC of the run
    grid_skips: int = 0                   #: real time: period slots without a SYNC (overruns)
    grid_bias: float | None = None        #: real time: b in n_k = floor((ts_k - ts_0)/T + b)
    trip_cycle: bool = False              #: the run ended with a recorded trip cycle (u = 0)

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def _take(values: np.ndarray, index: np.ndarray, has: np.ndarray, fill):
    """``values[index]`` where ``has``, else ``fill`` (also where there are no values at all)."""
    if not len(values):
        return np.full(len(index), fill, dtype=np.result_type(values.dtype, np.asarray(fill).dtype))
    return np.where(has, values[np.maximum(index, 0)], fill)


def empty_rows() -> dict[str, np.ndarray]:
    return {c: np.empty(0, _DTYPES[c]) for c in COLUMNS}


class _Events:
    """Frames of one kind in file order: ``order`` (global frame number), ``ts``, values."""

    def __init__(self, names: tuple[str, ...]) -> None:
        self.names = names
        self.order = np.empty(0, np.int64)
        self.ts = np.empty(0, np.float64)
        self.v = {n: np.empty(0, np.float64 if n.startswith("f_") else np.int64) for n in names}

    def add(self, order: np.ndarray, ts: np.ndarray, **values) -> None:
        self.order = np.concatenate([self.order, order])
        self.ts = np.concatenate([self.ts, ts])
        for n in self.names:
            self.v[n] = np.concatenate([self.v[n], values[n].astype(self.v[n].dtype)])

    def drop_before(self, count: int) -> None:
        self.order = self.order[count:]
        self.ts = self.ts[count:]
        for n in self.names:
            self.v[n] = self.v[n][count:]

    def __len__(self) -> int:
        return len(self.order)


def resolve_offsets(e: np.ndarray, off0: int, final: bool, k: int = RESYNC_AFTER) -> tuple[np.ndarray, int, int]:
    """Per-TPDO offset between its count and the SYNC it answers.

    ``e[j]`` = (index of the SYNC the j-th TPDO follows in the file) − j. With no loss the
    offset stays ``off0``; a run of at least ``k`` TPDOs all above (below) the current offset is
    a lost (duplicated) TPDO: from the run's start the offset becomes the run's minimum
    (maximum). Shorter excursions are storage-order noise and keep the count.

    Returns (offsets, offset after the last TPDO, index of the first TPDO whose offset may still
    change when more TPDOs arrive — ``len(e)`` if none or ``final``)."""
    n = len(e)
    off = np.full(n, off0, np.int64)
    cur = off0
    start = 0
    changes = 0
    while start < n:
        dev = np.flatnonzero(e[start:] != cur) + start
        if not len(dev):
            break
        sign = np.sign(e[dev] - cur)
        breaks = np.flatnonzero((np.diff(dev) != 1) | (np.diff(sign) != 0)) + 1
        run_starts = np.concatenate([[0], breaks])
        run_ends = np.concatenate([breaks, [len(dev)]])
        lengths = run_ends - run_starts
        long = np.flatnonzero(lengths >= k)
        if not len(long):
            last = len(run_starts) - 1
            if not final and dev[run_ends[last] - 1] == n - 1:
                return off, cur, int(dev[run_starts[last]])
            break
        r = long[0]
        a, b = dev[run_starts[r]], dev[run_ends[r] - 1] + 1
        if not final and b == n and lengths[r] < k:
            return off, cur, int(a)
        cur = int(e[a:b].min() if sign[run_starts[r]] > 0 else e[a:b].max())
        off[a:] = cur
        start = a
        changes += 1
    return off, cur, n


class CycleAssembler:
    """Feed decoded chunks in order; collect rows with :meth:`take_rows` and, at the end,
    :meth:`finish`. Rows come out as ``(run_index, {column: array})``."""

    def __init__(self, decoder: FrameDecoder, signals: StandSignals | None = None,
                 period_s: float | None = None, clock: str | None = None,
                 sync_trace: bool = False) -> None:
        if clock not in (None, "lockstep", "realtime"):
            raise ValueError(f"clock must be 'lockstep', 'realtime' or None (auto), not {clock!r}")
        self.sig = signals or StandSignals()
        self.decoder = decoder
        self.force_msg = decoder.find_signal(self.sig.force)
        self.valve_msg = decoder.find_signal(self.sig.status_word)
        self.command_msg = decoder.find_signal(self.sig.command)
        self.sync_msg = decoder.message(self.sig.sync_message)
        self.has_force_status = any(x.name == self.sig.force_status for x in self.force_msg.signals)
        #: a valve that does not send its spool position (its run's spool column is NaN)
        self.has_spool = any(x.name == self.sig.spool for x in self.valve_msg.signals)
        self.wanted = {
            self.force_msg.name: [self.sig.force] + ([self.sig.force_status] if self.has_force_status else []),
            self.valve_msg.name: [self.sig.status_word] + ([self.sig.spool] if self.has_spool else []),
            self.command_msg.name: [self.sig.control_word, self.sig.command],
            self.sync_msg.name: [],
        }
        if len({self.force_msg.name, self.valve_msg.name, self.command_msg.name, self.sync_msg.name}) < 4:
            raise ValueError("force, valve status, command and SYNC must be four different messages")
        self.force_scale = self.force_msg.signal(self.sig.force)
        self.period_arg = period_s
        self.clock_arg = clock
        self.frames_seen = 0
        self.S = _Events(())
        self.F = _Events(("counts", "f_y", "fstatus"))
        self.V = _Events(("status", "f_spool"))
        self.R = _Events(("cw", "f_u"))
        self.P = _Events(("us",))
        self.C = _Events(("clock",))
        self.sync_g0 = 0                # global index of self.S's first SYNC
        self.runs: list[RunInfo] = []
        self._out: list[tuple[int, dict]] = []
        #: with ``sync_trace``: one entry per SYNC (also those that are not cycles), see :meth:`take_trace`
        self.sync_trace = sync_trace
        self._trace: list[tuple[int, dict]] = []
        self._new_run(0)

    # -- input -----------------------------------------------------------------------------
    def feed(self, chunk: FrameChunk, decoded: dict[str, DecodedMessage]) -> None:
        base = self.frames_seen
        self.frames_seen += len(chunk)
        # SYNC from the raw frames: with its 1-byte counter (the DBC's layout) or without
        # (DLC 0, CiA 301's plain SYNC, which the DBC decoder counts as the wrong length)
        mine = self._channel_mask(chunk)
        sync = np.flatnonzero(self._is_sync(chunk) & mine)
        if len(sync):
            self.S.add(base + sync, chunk.ts[sync])
        if self.force_msg.name in decoded:
            d = decoded[self.force_msg.name]
            status = d.raw[self.sig.force_status] if self.has_force_status else np.zeros(len(d.index), np.int64)
            self.F.add(base + d.index, d.ts, counts=d.raw[self.sig.force], f_y=d.phys[self.sig.force],
                       fstatus=status.astype(np.int64))
        if self.valve_msg.name in decoded:
            d = decoded[self.valve_msg.name]
            self.V.add(base + d.index, d.ts, status=d.raw[self.sig.status_word].astype(np.int64),
                       f_spool=d.phys[self.sig.spool] if self.has_spool else np.full(len(d.index), np.nan))
        if self.command_msg.name in decoded:
            d = decoded[self.command_msg.name]
            self.R.add(base + d.index, d.ts, cw=d.raw[self.sig.control_word].astype(np.int64),
                       f_u=d.phys[self.sig.command])
        self._find_period_writes(chunk, base, mine)
        self._find_clock_reads(chunk, base, mine)
        self._process(final=False)

    def _is_sync(self, chunk: FrameChunk) -> np.ndarray:
        """SYNC frames (data frames with the SYNC's id and at most its counter byte)."""
        return ((chunk.can_id == self.sync_msg.frame_id) & (chunk.dlc <= 1)
                & ((chunk.flags & (EXTENDED | REMOTE | ERROR)) == (EXTENDED if self.sync_msg.extended else 0)))

    def choose_channel(self, chunk: FrameChunk) -> None:
        """Without a channel given, keep the one the stand's first SYNC comes on: a logger
        recording several buses writes them into one capture, and another bus may use the
        same ids (a second stand, another machine's node 2). Call before decoding ``chunk``."""
        if self.decoder.channel is not None or not chunk.channels:
            return
        sync = np.flatnonzero(self._is_sync(chunk))
        if len(sync):
            self.decoder.channel = chunk.channels[int(chunk.channel[sync[0]])]
            self.decoder.stats.channel_chosen = self.decoder.channel

    def _channel_mask(self, chunk: FrameChunk) -> np.ndarray | bool:
        """Frames on the channel the decoder keeps (all, without a channel option)."""
        name = self.decoder.channel
        if name is None or not chunk.channels:
            return True
        if name not in chunk.channels:
            return np.zeros(len(chunk), bool)
        return chunk.channel == chunk.channels.index(name)

    @staticmethod
    def _sdo_expedited(chunk: FrameChunk, cob_lo: int, command: int, index: int, mine
                       ) -> tuple[np.ndarray, np.ndarray] | None:
        """Rows and data of expedited SDO frames on ``cob_lo``..``cob_lo + 0x7E`` (any node) with
        command byte ``command`` (size bits masked) for ``index``:00; None if there are none."""
        sel = ((chunk.can_id >= cob_lo) & (chunk.can_id <= cob_lo + 0x7E) & (chunk.dlc == 8)
               & ((chunk.flags & 0x07) == 0) & mine)
        if not sel.any():
            return None
        rows = np.flatnonzero(sel)
        d = chunk.data[rows]
        hit = (((d[:, 0] & 0xE3) == command) & (d[:, 1] == index & 0xFF) & (d[:, 2] == index >> 8)
               & (d[:, 3] == 0))
        if not hit.any():
            return None
        return rows[hit], d[hit]

    def _find_period_writes(self, chunk: FrameChunk, base: int, mine=True) -> None:
        """SDO expedited downloads of 0x1006:00 to any node (0x601..0x67F)."""
        found = self._sdo_expedited(chunk, 0x601, 0x23, P.COMM_CYCLE_PERIOD, mine)
        if found is None:
            return
        rows, d = found
        unused = ((d[:, 0] >> 2) & 0x3).astype(np.int64)
        raw = d[:, 4:8].astype(np.int64)
        value = raw[:, 0] | raw[:, 1] << 8 | raw[:, 2] << 16 | raw[:, 3] << 24
        value &= (1 << (8 * (4 - unused))) - 1
        self.P.add(base + rows, chunk.ts[rows], us=value)

    def _find_clock_reads(self, chunk: FrameChunk, base: int, mine=True) -> None:
        """SDO expedited upload responses of 0x2100:00 (the emulated valve's clock: 0 real time,
        1 lockstep) from any node (0x581..0x5FF): the gateway reads it at each run start, so a
        capture says how its SYNCs map to stand time even when the wall clock cannot."""
        found = self._sdo_expedited(chunk, 0x581, 0x43, P.EMULATOR_CLOCK, mine)
        if found is not None:
            rows, d = found
            self.C.add(base + rows, chunk.ts[rows], clock=d[:, 4].astype(np.int64))

    # -- output ----------------------------------------------------------------------------
    def take_rows(self) -> list[tuple[int, dict]]:
        out, self._out = self._out, []
        return out

    def take_trace(self) -> list[tuple[int, dict]]:
        """Per-SYNC force trace (``sync_trace=True``): (run, {"y_counts", "force_status",
        "fresh", "is_cycle", "sync_time"}) — every SYNC of the run, including the last one,
        which answers with a force but ends the run."""
        out, self._trace = self._trace, []
        return out

    def finish(self) -> list[tuple[int, dict]]:
        self._process(final=True)
        run = self.runs[-1]
        if run.syncs == 0 and len(self.runs) > 1:
            self.runs.pop()
        return self.take_rows()

    # -- the work --------------------------------------------------------------------------
    def _new_run(self, first_sync_g: int) -> None:
        self.runs.append(RunInfo(len(self.runs)))
        self.run_first_g = first_sync_g    # global index of the run's first SYNC
        self.next_g = first_sync_g         # first SYNC of the run not yet turned into output
        self.force_j = 0                   # TPDOs of the run consumed so far
        self.force_off = 0
        self.valve_j = 0
        self.valve_off = 0
        self.cycle = 0
        self.last = {"y": math.nan, "y_counts": 0, "spool": math.nan, "valve_status": 0}
        self.last_fstatus = 0
        self.last_n = -1
        self.t_origin: float | None = None

    def _seg(self, order: np.ndarray) -> np.ndarray:
        """Global index of the last SYNC before each frame (-1 before any)."""
        return self.sync_g0 + np.searchsorted(self.S.order, order, side="right") - 1

    def _process(self, final: bool) -> None:
        while True:
            boundary = self._next_boundary()
            n_syncs_end = self.sync_g0 + len(self.S)
            if boundary is not None:
                self._emit(boundary, closing=True)
                self._start_next_run(boundary)
                continue
            if final:
                self._emit(n_syncs_end, closing=True)
            else:
                self._emit(n_syncs_end - MARGIN_SYNCS, closing=False)
            return

    def _next_boundary(self) -> int | None:
        """The first SYNC of the next run, if a 0x1006 download after this run's first SYNC
        (and a SYNC after the download) is in the buffer."""
        if len(self.C):  # clock reads before the run's first SYNC belong to the run
            before = np.flatnonzero(self._seg(self.C.order) < self.run_first_g)
            if len(before):
                self.runs[-1].clock_read.extend(int(v) for v in self.C.v["clock"][before])
                self.C.drop_before(int(before[-1]) + 1)
        if not len(self.P):
            return None
        seg = self._seg(self.P.order)
        after = np.flatnonzero(seg >= self.run_first_g)
        run = self.runs[-1]
        # downloads before the run's first SYNC set its period
        before = np.flatnonzero(seg < self.run_first_g)
        if len(before):
            run.period_us_written.extend(int(v) for v in self.P.v["us"][before])
        if not len(after):
            self.P.drop_before(len(self.P))
            return None
        if len(before):
            self.P.drop_before(int(before[-1]) + 1)
            seg = seg[int(before[-1]) + 1:]
        b = int(seg[0]) + 1
        if b >= self.sync_g0 + len(self.S):
            return None                    # no SYNC after the download yet
        return b

    def _start_next_run(self, boundary: int) -> None:
        self._new_run(boundary)

    def _run_clock(self, run: RunInfo, sync_ts: np.ndarray) -> None:
        """Decide period and clock once, from the first SYNCs of the run."""
        if run.period_s is not None:
            return
        if len(sync_ts) < GRID_SYNCS and not self._closing:
            return
        steps = np.diff(sync_ts[:2001])
        steps = steps[steps > 0]
        median = float(np.median(steps)) if len(steps) else None
        if self.period_arg is not None:
            run.period_s, run.period_source = float(self.period_arg), "argument"
        elif run.period_us_written:
            run.period_s, run.period_source = run.period_us_written[-1] / 1e6, "SDO 0x1006"
        elif median:
            # CANopen periods are whole µs (0x1006); float timestamps near 1.7e9 s are only
            # good to ~0.2 µs, so the median is rounded to the µs
            run.period_s = round(median * 1e6) / 1e6 if median >= 1e-4 else median
            run.period_source = "median SYNC interval"
        else:
            run.period_s, run.period_source = math.nan, "unknown (one SYNC)"
        if self.clock_arg is not None:
            run.clock, run.clock_source = self.clock_arg, "argument"
        elif run.clock_read:
            run.clock = "lockstep" if run.clock_read[-1] == 1 else "realtime"
            run.clock_source = "SDO 0x2100"
        elif median is None or not math.isfinite(run.period_s):
            run.clock, run.clock_source = "lockstep", "SYNC timing"
        else:
            run.clock = "lockstep" if median < 0.5 * run.period_s else "realtime"
            run.clock_source = "SYNC timing"
        if run.clock == "realtime":
            run.grid_bias = _grid_bias((sync_ts[:GRID_SYNCS * 10] - sync_ts[0]) / run.period_s)

    def _pair(self, ev: _Events, j0: int, off0: int, end_g: int, final: bool):
        """Pair this run's TPDOs (kind ``ev``) with SYNCs: assigned global SYNC per TPDO."""
        seg = self._seg(ev.order)
        keep = seg >= self.run_first_g
        drop = int(np.argmax(keep)) if keep.any() else len(seg)
        # TPDOs before the run's first SYNC answer no SYNC of it
        if drop:
            self.runs[-1].tpdos_unpaired += drop
            ev.drop_before(drop)
            seg = seg[drop:]
        inrun = np.flatnonzero(seg < end_g)
        seg = seg[inrun]
        j = j0 + np.arange(len(seg))
        e = seg - self.run_first_g - j
        off, off_last, unstable = resolve_offsets(e, off0, final)
        assigned = np.maximum.accumulate(self.run_first_g + j + off) if len(j) else j
        return assigned, off, unstable

    def _emit(self, upto_g: int, closing: bool) -> None:
        """Turn the run's SYNCs below ``upto_g`` into rows (all of them when ``closing``)."""
        self._closing = closing
        run = self.runs[-1]
        lo = self.next_g
        run_syncs_ts = self.S.ts[self.run_first_g - self.sync_g0:] if self.run_first_g >= self.sync_g0 else self.S.ts
        self._run_clock(run, run_syncs_ts)
        if run.period_s is None:
            return                          # not enough SYNCs yet to know the clock
        end_g = upto_g if closing else self.sync_g0 + len(self.S)
        fa, foff, f_unstable = self._pair(self.F, self.force_j, self.force_off, end_g, closing)
        va, voff, v_unstable = self._pair(self.V, self.valve_j, self.valve_off, end_g, closing)
        hi = upto_g
        if not closing:
            if f_unstable < len(fa):
                hi = min(hi, int(fa[f_unstable]))
            if v_unstable < len(va):
                hi = min(hi, int(va[v_unstable]))
        hi = max(hi, lo)
        if hi <= lo and not closing:
            return
        g = np.arange(lo, hi)
        s = g - self.sync_g0
        sync_ts = self.S.ts[s]
        # the command: first RPDO after each SYNC
        r_seg = self._seg(self.R.order)
        r_first = np.flatnonzero(np.r_[True, r_seg[1:] != r_seg[:-1]]) if len(r_seg) else np.empty(0, np.int64)
        r_map = np.full(len(g), -1, np.int64)
        sel = r_first[(r_seg[r_first] >= lo) & (r_seg[r_first] < hi)]
        r_map[r_seg[sel] - lo] = sel
        has_r = r_map >= 0
        cw = _take(self.R.v["cw"], r_map, has_r, -1)
        is_row = has_r & (cw == self.sig.active_control_word)
        if closing and len(g) and has_r[-1] and not is_row[-1]:
            # a trip: the gateway recorded its last cycle with the safe command it sent
            last = r_seg == g[-1]
            safe = last & np.isin(self.R.v["cw"], SAFE_CONTROL_WORDS) & (self.R.v["f_u"] == 0)
            if int(safe.sum()) >= SAFE_REPEATS and safe[r_map[-1]]:
                is_row[-1] = True
                run.trip_cycle = True
        r_order = _take(self.R.order, r_map, has_r, np.iinfo(np.int64).max)
        r_ts = _take(self.R.ts, r_map, has_r, np.inf)
        realtime = run.clock == "realtime"

        def fresh_values(ev: _Events, assigned: np.ndarray):
            idx = np.searchsorted(assigned, g, side="left")
            ok = idx < len(assigned)
            ok[ok] = assigned[idx[ok]] == g[ok]
            idx = np.where(ok, idx, 0)
            fresh = ok.copy()
            if realtime and len(ev):
                fresh &= (ev.order[idx] < r_order) | (ev.ts[idx] <= r_ts)
            return fresh, idx, ok

        f_fresh, f_idx, f_has = fresh_values(self.F, fa)
        v_fresh, v_idx, _ = fresh_values(self.V, va)
        run.syncs_without_force += int((~f_has).sum())

        y = _ffill(np.where(f_fresh, self.F.v["f_y"][f_idx] if len(self.F) else np.nan, np.nan),
                   f_fresh, self.last["y"])
        y_counts = _ffill(np.where(f_fresh, self.F.v["counts"][f_idx] if len(self.F) else 0, 0),
                          f_fresh, self.last["y_counts"])
        spool = _ffill(np.where(v_fresh, self.V.v["f_spool"][v_idx] if len(self.V) else np.nan, np.nan),
                       v_fresh, self.last["spool"])
        status = _ffill(np.where(v_fresh, self.V.v["status"][v_idx] if len(self.V) else 0, 0),
                        v_fresh, self.last["valve_status"])
        if len(g):
            self.last = {"y": y[-1], "y_counts": y_counts[-1], "spool": spool[-1],
                         "valve_status": status[-1]}
        # time
        T = run.period_s
        if len(g) and self.t_origin is None:
            self.t_origin = float(sync_ts[0])
            run.first_sync_ts = self.t_origin
        if len(g):
            run.last_sync_ts = float(sync_ts[-1])
        rows_n = int(is_row.sum())
        cycles = self.cycle + np.arange(rows_n)
        if realtime and len(g):
            # slots of these SYNCs and of the ones held back after them (look-ahead)
            ahead = self.S.ts[lo - self.sync_g0:]
            n = (np.floor((ahead - self.t_origin) / T + run.grid_bias)
                 - math.floor(run.grid_bias)).astype(np.int64)
            k = np.arange(len(n))
            # a SYNC stamped late may look like the next slot's: each SYNC's slot is at most
            # its successor's minus one (backward pass), then strictly after the last emitted one
            n = k + np.minimum.accumulate((n - k)[::-1])[::-1]
            n = (k + np.maximum(np.maximum.accumulate(n - k), self.last_n + 1))[:len(g)]
            prev = self.last_n if self.last_n >= 0 else int(n[0]) - 1
            run.grid_skips += int(n[-1] - prev - len(n))
            self.last_n = int(n[-1])
            t = n[is_row] * T
        else:
            t = cycles * T
        rows = {
            "t": np.asarray(t, np.float64),
            "u": self.R.v["f_u"][r_map[is_row]] if rows_n else np.empty(0),
            "y": y[is_row], "r": np.full(rows_n, np.nan), "cycle": cycles,
            "y_counts": y_counts[is_row].astype(np.int32), "spool": spool[is_row],
            "valve_status": status[is_row].astype(np.uint16), "stale": ~f_fresh[is_row],
            "sync_time": sync_ts[is_row],
        }
        self.cycle += rows_n
        run.syncs += len(g)
        run.rows += rows_n
        run.stale += int((~f_fresh[is_row]).sum())
        run.syncs_without_row += int(len(g) - rows_n)
        if rows_n:
            self._out.append((run.index, rows))
        if self.sync_trace and len(g):
            fstatus = _ffill(np.where(f_fresh, self.F.v["fstatus"][f_idx] if len(self.F) else 0, 0),
                             f_fresh, self.last_fstatus)
            self.last_fstatus = int(fstatus[-1])
            self._trace.append((run.index, {"y_counts": y_counts.astype(np.int32), "force_status": fstatus,
                                            "fresh": f_fresh, "is_cycle": is_row, "sync_time": sync_ts}))
        # consume what was used
        self.next_g = hi
        self.force_j, self.force_off = self._consume(self.F, fa, foff, hi, self.force_j, self.force_off)
        self.valve_j, self.valve_off = self._consume(self.V, va, voff, hi, self.valve_j, self.valve_off)
        r_used = int(np.searchsorted(r_seg, hi, side="left")) if len(r_seg) else 0
        self.R.drop_before(r_used)
        if closing:
            # TPDOs left over from a closed run answer no SYNC of it
            for ev in (self.F, self.V):
                seg = self._seg(ev.order)
                extra = int((seg < hi).sum())
                run.tpdos_unpaired += extra
                ev.drop_before(extra)
        s_used = hi - self.sync_g0
        self.S.drop_before(s_used)
        self.sync_g0 = hi

    def _consume(self, ev: _Events, assigned: np.ndarray, off: np.ndarray, hi: int, j: int, off0: int):
        used = int(np.searchsorted(assigned, hi, side="left"))
        if used:
            changes = int((np.diff(np.r_[off0, off[:used]]) != 0).sum())
            self.runs[-1].tpdo_resyncs += changes
            # several TPDOs assigned to one SYNC: only the first answers it
            dup = int(used - 1 - np.count_nonzero(np.diff(assigned[:used])))   # non-decreasing
            self.runs[-1].tpdos_unpaired += dup
            off0 = int(off[used - 1])
        ev.drop_before(used)
        return j + used, off0


def _grid_bias(x: np.ndarray) -> float:
    """Bias b of the slot rounding n = floor(x + b) for SYNC times ``x`` (in periods since the
    first SYNC): the slot boundary goes near the end of the widest phase gap, just before the
    phases where SYNCs start to arrive (a SYNC is never early, it may be late)."""
    if len(x) < 2:
        return 0.25
    phase = np.sort(np.mod(x, 1.0))
    gaps = np.diff(np.r_[phase, phase[0] + 1.0])
    i = int(np.argmax(gaps))
    end = phase[(i + 1) % len(phase)]            # where the SYNCs start again after the gap
    cut = (end - 0.1 * gaps[i]) % 1.0            # the boundary: a little before them
    return float(1.0 - cut) if cut > 0 else 1.0


def _ffill(values: np.ndarray, fresh: np.ndarray, before) -> np.ndarray:
    """Hold the last fresh value over stale entries (``before`` = value before the first)."""
    if not len(values):
        return values
    idx = np.where(fresh, np.arange(len(values)), -1)
    idx = np.maximum.accumulate(idx)
    out = values[np.maximum(idx, 0)].astype(np.result_type(values, type(before)))
    out[idx < 0] = before
    return out
