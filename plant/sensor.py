"""The dynamometer as a measuring device: noise, resolution and range."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .params import ModelError, Param

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

    def measure(self, y: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(reading_kgf, over_range)`` for true force(s) ``y``."""
        y = np.asarray(y, float)
        if self.noise_kgf:
            y = y + self._rng.normal(0.0, self.noise_kgf, y.shape)
        if self.resolution_kgf:
            y = np.round(y / self.resolution_kgf) * self.resolution_kgf
        over = np.abs(y) > self.range_kgf
        return np.clip(y, -self.range_kgf, self.range_kgf), over

    @classmethod
    def from_mapping(cls, values: dict, seed: int | None = None) -> "Dynamometer":
        known = {p.name for p in SENSOR_PARAMS}
        unknown = set(values) - known
        if unknown:
            raise ModelError(f"[sensor] has no key(s) {', '.join(sorted(unknown))}; "
                             f"known: {', '.join(sorted(known))}")
        return cls(seed=seed, **values)
