"""Synthetic stand traffic with known answers, for tests and benchmarks.

:func:`synthetic_run` simulates an open-loop meander on the shared plant model
(:class:`plant.model.PlantModel`, paper eq. 1: dy/dt = g·u(t−τ) + Δ) with the dynamometer's noise and
resolution, and :func:`stand_frames` turns it into the frames the gateway and the two CANopen
nodes put on the bus (see :mod:`gateway.loop`)::

    NMT start ×2, SDO 0x1006 download + answer ×2 (period, µs), enabling RPDO (ControlWord 7, 0)
    cycle k:  SYNC(counter) → TPDO1 valve 0x181 → TPDO1 dynamometer 0x182 → RPDO1 0x201 (CW 7, u_k)
    last SYNC of the run: TPDOs only;   then safe-state RPDOs (ControlWord 3, 0) ×2
    heartbeats 0x701/0x702 every ``heartbeat_every`` cycles

Timestamps are whole microseconds (so a candump log represents them exactly).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from dbc import profile as P
from plant.model import PlantModel
from plant.sensor import Dynamometer

from .frames import TX, FrameChunk

FORCE_SCALE = P.force_scale_kgf(P.UNIT_N_DEFAULT, 1)     #: kgf per count (0.1 N)


@dataclass
class SyntheticRun:
    """Per-cycle truth of a synthetic run (what the gateway would record)."""

    period_s: float
    u_counts: np.ndarray      #: int16 command counts sent in cycle k
    y_counts: np.ndarray      #: int32 force counts read at SYNC k (k = 0..cycles: one more than rows)
    spool_counts: np.ndarray  #: int16 valve actual value at SYNC k (k = 0..cycles)

    @property
    def cycles(self) -> int:
        return len(self.u_counts)

    @property
    def u(self) -> np.ndarray:
        return self.u_counts * P.PERCENT_PER_COUNT

    @property
    def y(self) -> np.ndarray:
        return self.y_counts[:-1] * FORCE_SCALE

    @property
    def t(self) -> np.ndarray:
        return np.arange(self.cycles) * self.period_s


def synthetic_run(cycles: int, period_s: float = 0.002, model: str = "base+reversal",
                  params: dict | None = None, amplitude_pct: float = 5.0,
                  meander_period_s: float = 1.0, y0_kgf: float = 500.0, seed: int = 0) -> SyntheticRun:
    """An open-loop meander of ``cycles`` control cycles through the plant model and the sensor."""
    plant = PlantModel.from_spec(model, params or {"g": 120.0, "tau": 0.05, "delta": 8.0})
    t = np.arange(cycles + 1) * period_s
    u_pct = np.where((t[:-1] // (meander_period_s / 2)) % 2 == 0, amplitude_pct, -amplitude_pct)
    u_counts = np.round(u_pct * P.COUNTS_PER_PERCENT).astype(np.int16)
    u_wire = u_counts * P.PERCENT_PER_COUNT
    y_true = plant.simulate(np.append(u_wire, u_wire[-1]), period_s, y0=y0_kgf)
    reading, _ = Dynamometer(seed=seed).measure(y_true)
    y_counts = np.round(reading / FORCE_SCALE).astype(np.int32)
    spool = np.concatenate([[0], u_counts]).astype(np.int16)
    return SyntheticRun(period_s, u_counts, y_counts, spool)


def _le(values: np.ndarray, nbytes: int) -> np.ndarray:
    v = values.astype(np.int64).astype(np.uint64)
    return np.stack([(v >> np.uint64(8 * i)) & np.uint64(0xFF) for i in range(nbytes)], axis=1).astype(np.uint8)


def stand_frames(run: SyntheticRun, start_s: float = 1_700_000_000.0, channel: str = "can0",
                 heartbeat_every: int = 50, lockstep: bool = False,
                 block_cycles: int = 200_000) -> Iterator[FrameChunk]:
    """The run's bus traffic as chunks of at most ``block_cycles`` cycles (bounded memory).

    Real time: SYNC k at ``start_s + k·period``; lockstep: SYNCs 300 µs apart (the wall clock
    says nothing about stand time, only the 0x1006 download does)."""
    start_us = int(round(start_s * 1e6))
    period_us = int(round(run.period_s * 1e6))
    step_us = 300 if lockstep else period_us
    pre = _preamble(period_us)
    yield _chunk([(start_us + i, *f) for i, f in enumerate(pre)], channel)
    base = start_us + 1000
    n_syncs = run.cycles + 1
    for k0 in range(0, n_syncs, block_cycles):
        k = np.arange(k0, min(n_syncs, k0 + block_cycles))
        yield _cycles_chunk(run, k, base + k * step_us, heartbeat_every, channel, step_us / 2000)
    end_us = base + n_syncs * step_us
    safe = [(end_us + i, 0x201, True, bytes([int(P.CW_HOLD), 0, 0, 0])) for i in range(2)]
    yield _chunk(safe, channel)


def _preamble(period_us: int) -> list[tuple]:
    frames = [(0x000, True, bytes([1, P.VALVE_NODE_ID])), (0x000, True, bytes([1, P.DYNAMOMETER_NODE_ID]))]
    for node in (P.VALVE_NODE_ID, P.DYNAMOMETER_NODE_ID):
        frames.append((0x600 + node, True, bytes([0x23, 0x06, 0x10, 0x00]) + period_us.to_bytes(4, "little")))
        frames.append((0x580 + node, False, bytes([0x60, 0x06, 0x10, 0x00, 0, 0, 0, 0])))
    frames.append((0x201, True, bytes([int(P.CW_ACTIVE), 0, 0, 0])))
    return frames


def _chunk(frames: list[tuple], channel: str) -> FrameChunk:
    n = len(frames)
    data = np.zeros((n, 8), np.uint8)
    for i, f in enumerate(frames):
        data[i, :len(f[3])] = np.frombuffer(f[3], np.uint8)
    return FrameChunk(np.array([f[0] for f in frames], np.int64) / 1e6,
                      np.array([f[1] for f in frames], np.uint32),
                      np.array([TX if f[2] else 0 for f in frames], np.uint8),
                      np.array([len(f[3]) for f in frames], np.uint8), data,
                      np.zeros(n, np.int16), [channel])


def _cycles_chunk(run: SyntheticRun, k: np.ndarray, sync_us: np.ndarray, heartbeat_every: int,
                  channel: str, squeeze: float = 1.0) -> FrameChunk:
    n = len(k)
    row = k < run.cycles
    counter = (k % P.SYNC_COUNTER_OVERFLOW + 1).astype(np.uint8)
    status = np.full(n, int(P.ValveState.ACTIVE), np.int64)
    # slot: 0 SYNC, 1 valve TPDO, 2 force TPDO, 3 RPDO, 4/5 heartbeats
    parts = []

    def add(sel, slot, cob, tx, offset_us, payload):
        m = int(sel.sum()) if sel.dtype == bool else len(sel)
        data = np.zeros((m, 8), np.uint8)
        data[:, :payload.shape[1]] = payload
        parts.append((k[sel] * 8 + slot, sync_us[sel] + int(offset_us * min(squeeze, 1.0)), np.full(m, cob, np.uint32),
                      np.full(m, TX if tx else 0, np.uint8), np.full(m, payload.shape[1], np.uint8), data))

    every = np.ones(n, bool)
    add(every, 0, 0x080, True, 0, counter[:, None])
    add(every, 1, 0x181, False, 150, np.hstack([_le(status, 2), _le(run.spool_counts[k], 2)]))
    add(every, 2, 0x182, False, 200, np.hstack([_le(run.y_counts[k], 4), np.zeros((n, 1), np.uint8)]))
    kr = k[row]
    add(row, 3, 0x201, True, 300, np.hstack([_le(np.full(len(kr), int(P.CW_ACTIVE)), 2),
                                             _le(run.u_counts[kr], 2)]))
    if heartbeat_every:
        hb = (k % heartbeat_every == heartbeat_every - 1)
        add(hb, 4, 0x701, False, 400, np.full((int(hb.sum()), 1), 0x05, np.uint8))
        add(hb, 5, 0x702, False, 450, np.full((int(hb.sum()), 1), 0x05, np.uint8))
    key = np.concatenate([p[0] for p in parts])
    order = np.argsort(key, kind="stable")
    cat = [np.concatenate([p[i] for p in parts])[order] for i in range(1, 6)]
    ts_us, cob, flags, dlc, data = cat
    return FrameChunk(ts_us / 1e6, cob, flags, dlc, data, np.zeros(len(cob), np.int16), [channel])
