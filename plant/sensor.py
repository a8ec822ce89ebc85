"""The dynamometer as a measuring device: noise, resolution and range."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .params import ModelError, Param

#: noise values drawn at a time
_NOISE_BLOCK = 1024

SENSOR_PARAMS: tuple[Param, ...] = (
    Param("noise_kgf", 2.0, 0.0, 1000.0, "kgf", "standard deviation of white measurement noise"),
    Param("resolution_kgf", 0.5, 0.0, 100.0, "kgf", "quantization step of the reading (0: none)"),
    Param("range_kgf", 10000.0, 1.0, 1e6, "kgf", "measuring range ±F_max; beyond it the reading clips"),
)


@dataclass
class Dynamometer:
    """Turns the true force into a reading: ``clip(round((y + noise)/res)·res, ±range)``."""

    noise_kgf: float = 2.0
    resolution_kgf: float = 0.5
    range_kgf: float = 10000.0
    seed: int | None = None

    def __post_init__(self) -> None:
        for p in SENSOR_PARAMS:
            setattr(self, p.name, p.validate(getattr(self, p.name), "sensor"))
        self._rng = np.random.default_rng(self.seed)
        self._noise = np.empty(0)
        self._next = 0

    def _ensure(self, n: int) -> None:
        """At least ``n`` values of the noise stream ready from ``_next``. Drawn ahead in blocks:
        a block of draws is the same sequence as single draws, so the readings do not depend on
        how they are asked for (one at a time by the emulator, whole records by the analysis)."""
        if self._next + n > len(self._noise):
            fresh = self._rng.normal(0.0, self.noise_kgf, max(n, _NOISE_BLOCK))
            self._noise = np.concatenate([self._noise[self._next:], fresh])
            self._next = 0

    def _draw(self, n: int) -> np.ndarray:
        """The next ``n`` values of the noise stream."""
        self._ensure(n)
        out = self._noise[self._next:self._next + n]
        self._next += n
        return out

    def measure(self, y: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(reading_kgf, over_range)`` for true force(s) ``y``."""
        y = np.asarray(y, float)
        if self.noise_kgf:
            y = y + self._draw(y.size).reshape(y.shape)
        if self.resolution_kgf:
            y = np.round(y / self.resolution_kgf) * self.resolution_kgf
        over = np.abs(y) > self.range_kgf
        return np.clip(y, -self.range_kgf, self.range_kgf), over

    def read(self, y: float) -> tuple[float, bool]:
        """One reading, the same law and noise stream as :meth:`measure` in plain floats (the
        emulator reads once per SYNC; numpy's per-call overhead was most of the cost)."""
        v = float(y)
        if not math.isfinite(v):
            reading, over = self.measure(v)
            return float(reading), bool(over)
        if self.noise_kgf:
            k = self._next
            if k >= len(self._noise):
                self._ensure(1)
                k = self._next
            v += float(self._noise[k])
            self._next = k + 1
        res = self.resolution_kgf
        if res:
            v = round(v / res) * res   # half to even, like np.round
        r = self.range_kgf
        over = v > r or v < -r
        return (min(max(v, -r), r), over)

    @classmethod
    def from_mapping(cls, values: dict, seed: int | None = None) -> "Dynamometer":
        known = {p.name for p in SENSOR_PARAMS}
        unknown = set(values) - known
        if unknown:
            raise ModelError(f"[sensor] has no key(s) {', '.join(sorted(unknown))}; "
                             f"known: {', '.join(sorted(known))}")
        return cls(seed=seed, **values)


class SensorBank:
    """Many dynamometers read together, one reading each per call: a rig's channels at a SYNC
    in lockstep. The law of :meth:`Dynamometer.measure` over arrays, each sensor's own noise
    stream taken from it in blocks, so the readings are bit for bit those of
    :meth:`Dynamometer.read` one sensor at a time (16 channels: ~5 µs a call, lists included,
    instead of ~9).
    Once a bank reads them, the sensors' noise streams are the bank's: a sensor read on its own
    meanwhile would take values the bank has already drawn."""

    def __init__(self, sensors, block: int = _NOISE_BLOCK) -> None:
        self.sensors = list(sensors)
        self._block = int(block)
        self._noisy = np.array([i for i, s in enumerate(self.sensors) if s.noise_kgf], int)
        self._all_noisy = len(self._noisy) == len(self.sensors)
        res = np.array([s.resolution_kgf for s in self.sensors], float)
        self._rounded = res > 0
        self._all_rounded = bool(self._rounded.all())
        self._res = np.where(self._rounded, res, 1.0)
        self._range = np.array([s.range_kgf for s in self.sensors], float)
        self._noise = np.empty((0, len(self._noisy)))
        self._next = 0

    def read(self, forces) -> tuple[np.ndarray, np.ndarray]:
        """``(readings_kgf, over_range)`` for the true forces (one per sensor, in order)."""
        y = np.array(forces, float)
        if len(self._noisy):
            k = self._next
            if k >= len(self._noise):
                self._noise = np.stack([self.sensors[i]._draw(self._block) for i in self._noisy],
                                       axis=1)
                k = 0
            self._next = k + 1
            if self._all_noisy:
                y += self._noise[k]
            else:
                y[self._noisy] += self._noise[k]
        if self._all_rounded:
            y = np.round(y / self._res) * self._res
        elif self._rounded.any():
            y = np.where(self._rounded, np.round(y / self._res) * self._res, y)
        over = np.abs(y) > self._range
        return np.clip(y, -self._range, self._range), over
