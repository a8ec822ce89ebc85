"""Peak/valley compensation for every channel of a rig: one :class:`~loading.compensation.Compensation`
per channel, learned from its own turning points (its peaks and valleys; a load case where the
channel holds or passes through is not one of its turning points), saved in one file with a
table per channel (``[channel.NAME.peak]``, ``[channel.NAME.valley]``)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from core.errors import ParameterError

from .compensation import SCHEMA as ONE_SCHEMA, Compensation

SCHEMA = "hydrostand-rig-compensation/1"


@dataclass
class RigCompensation:
    names: list[str]
    channels: dict[str, Compensation] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for n in self.names:
            self.channels.setdefault(n, Compensation())

    def levels(self, programme) -> list[np.ndarray]:
        """The levels to command for each channel's turning points (a :class:`RigProgramme`)."""
        return [self.channels[n].levels(p.levels_kgf, p.kinds())
                for n, p in zip(programme.names, programme.channels)]

    def learn(self, reports: Sequence, ranges_kgf: Sequence[float]) -> None:
        """Update each channel from its pass's tracking report (in the channels' order)."""
        for n, rep, rng in zip(self.names, reports, ranges_kgf):
            self.channels[n].learn(rep.turning_points, rng)

    def to_toml(self) -> str:
        out = [f"# {SCHEMA}: peak/valley corrections learned by `stand load --rig`, per channel"]
        for n in self.names:
            for kind, lines in self.channels[n].toml_tables():
                out += (["", f"[channel.{n}]"] if kind is None else [f"[channel.{n}.{kind}]"]) + lines
        return "\n".join(out) + "\n"

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_text(self.to_toml())
        return path

    @classmethod
    def load(cls, path: str | Path, names: Sequence[str]) -> "RigCompensation":
        from plant.config import read_toml
        from plant.params import ModelError
        try:
            data = read_toml(path)
        except ModelError as exc:
            raise ParameterError(str(exc)) from None
        tables = data.get("channel")
        if not isinstance(tables, dict):
            raise ParameterError(f"{path}: not a rig compensation file (no [channel.NAME] tables; a "
                                 f"one-channel file ({ONE_SCHEMA}) is for one stand)")
        unknown = [n for n in tables if n not in names]
        if unknown:
            raise ParameterError(f"{path}: [channel.{unknown[0]}] is not a channel of the rig")
        out = cls(list(names))
        for n, t in tables.items():
            out.channels[n] = Compensation.from_mapping(t, f"{path}: [channel.{n}]")
        return out
