"""What an effect knows about telling itself apart: the diagnosis hands it the evidence (what
the data's command can show, the fitted start model, the candidates tried and the best), the
effect answers which explanations these data cannot separate from it (:class:`Ambiguity`), each
with the experiment that would.

The knowledge lives on the effect classes (:attr:`plant.Effect.look_alikes`: the experiment per
look-alike, read by :func:`plant.contract.separating_experiment`;
:attr:`plant.Effect.at_one_amplitude`: the look-alike a single command amplitude cannot tell it
from; :meth:`plant.Effect.ambiguities`: the rules for the data at hand), so a plug-in's is used
exactly as the catalogue's; :mod:`analysis.diagnosis.ambiguity` asks each effect it tried. This
module holds only the data that passes between them: it knows no effect.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

#: what two explanations are told apart by when neither effect names the other
DEFAULT_EXPERIMENT = ("the meander at several amplitudes and periods, plus relay and P-feedback "
                      "runs (richer excitation)")
#: a second explanation that leaves at most this times the error the best leaves is "not
#: separable" from it (comparing what is left, not what is removed: 63 % and 93 % removed leave
#: errors five times apart, which the data do separate)
AMBIGUITY_RATIO = 1.1
#: the base model's parameters as look-alikes, in words
BASE_LOOK_ALIKES = {"gain": "another gain g", "delay": "more delay", "trend": "the trend Δ"}


@dataclass
class Ambiguity:
    """Explanations these data cannot tell apart, and the experiment that would."""

    effects: list[str]            #: what cannot be told apart ("deadzone", "gain", ...)
    reason: str
    experiment: str               #: the experiment that would separate them

    def text(self) -> str:
        if len(self.effects) == 1:
            return f"{self.effects[0]}: {self.reason} To test it: {self.experiment}."
        return f"{' vs '.join(self.effects)}: {self.reason} To separate them: {self.experiment}."


@dataclass(frozen=True)
class Excitation:
    """What the data's command contains, as far as separating effects is concerned."""

    levels: list[float]           #: distinct nonzero |u| levels (empty if continuous)
    continuous: bool              #: the command varies continuously (feedback with smooth r)
    has_steps: bool               #: the command jumps (meander, relay)
    has_zero_hold: bool           #: the command rests at 0 for ≥ 0.5 s somewhere
    single_frequency: bool        #: smooth command dominated by one frequency
    force_span_kgf: float
    both_force_signs: bool
    top_command_pct: float = 0.0  #: the largest |u|

    @property
    def single_amplitude(self) -> bool:
        """Square waves at one |u| only: a slope cannot be told from a gain."""
        return len(self.levels) == 1 and not self.continuous

    @classmethod
    def of(cls, records: Sequence) -> "Excitation":
        """From records (anything with ``u``, ``y`` and ``dt``)."""
        u = np.concatenate([r.u for r in records])
        y = np.concatenate([r.y for r in records])
        nz = np.abs(u[u != 0])
        levels = np.unique(np.round(nz, 2)) if len(nz) else np.array([])
        continuous = len(levels) > 6
        span = float(np.ptp(u)) or 1.0
        steps = any(np.any(np.abs(np.diff(r.u)) > 0.25 * span) for r in records)
        zero = False
        for r in records:
            z = np.concatenate([[0], (r.u == 0).astype(int), [0]])
            edges = np.flatnonzero(np.diff(z))
            runs = edges[1::2] - edges[::2]
            if len(runs) and runs.max() * r.dt >= 0.5:
                zero = True
        single = False
        if continuous and not steps:
            spec = np.abs(np.fft.rfft(u - u.mean())) ** 2
            k = int(np.argmax(spec[1:])) + 1
            single = spec[max(1, k - 3):k + 4].sum() > 0.8 * spec[1:].sum()
        return cls([float(v) for v in levels] if not continuous else [], continuous, steps, zero,
                   single, float(np.ptp(y)),
                   bool(y.min() < -0.1 * np.ptp(y) and y.max() > 0.1 * np.ptp(y)),
                   float(np.abs(u).max()) if len(u) else 0.0)


@dataclass(frozen=True)
class Evidence:
    """What the diagnosis tells each effect it tried."""

    excitation: Excitation
    base: Mapping[str, float]                  #: the start model's fitted values (g, tau, ...)
    tried: frozenset[str]                      #: the candidate effects fitted
    best: str | None = None                    #: the one that earns, if any
    best_params: Mapping[str, float] = field(default_factory=dict)
    #: each candidate's windowed error with re-estimated starts (kgf)
    errors: Mapping[str, float] = field(default_factory=dict)
