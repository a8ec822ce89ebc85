"""The diagnosis's confusion matrix: every catalogue effect alone, and every pair with the
reversal boost and with a valve lag, each simulated by a law written apart from the
catalogue's (tests/support/independent_stand.py), diagnosed by ``stepwise`` and judged.

A *cell* is one set of true effects on one excitation (the paper's four meanders, or
P-feedback runs) with one noise draw. It is *right* when the final model names every true
effect the records show, by its name or a listed equivalent (:data:`NAMES`), or the diagnosis
says precisely which explanations cannot be told apart there (an ambiguity naming the true
effect and what took its place: another effect, or the base model's gain, delay or trend), and
names nothing else. An effect the records do not show (they differ by less than half the
noise without it: a flow limit the command never reaches) is right named or not.

``benchmarks/confusion.py`` runs the whole matrix; ``tests/test_confusion.py`` a few cells.
"""
from __future__ import annotations

import time
import zlib
from dataclasses import asdict, dataclass, field

import numpy as np

from analysis import make_record
from tests.support import independent_stand as sim
from tests.support.records import EQUIVALENT

#: the simulator's law for each catalogue effect: another parameterization or mechanism with
#: the same physics (a play in the rod's travel for the seal's play in force, a sensor lag ahead
#: of the noise, a supply that sags with its own time constant, a drift linear in time, two
#: delays for a delay and its extra one, ...). Not ``dirdelay``: its queue of changes is other
#: physics under a smooth command (a rise waits behind the falls queued before it)
LAW = {"null_drift": "nulldrift", "lag": "lag", "resonance": "res", "slew": "slew",
       "deadzone": "deadzone", "saturation": "saturation", "backlash": "backlash",
       "direction_delay": "dirlatch", "flow_curve": "flownl", "asymmetry": "asymmetry",
       "supply": "supply", "gain_drift": "gaindrift", "reversal": "rev_flow",
       "command_reversal": "rev_cmd", "travel_reversal": "rev_force", "load_pressure": "loadpress",
       "stiffness": "stiffening", "unloading": "softload", "leakage": "leakage",
       "sensor_lag": "sensorlag", "stiction": "lostmotion"}
#: the matrix's values where they are not the simulator's defaults: lags of some tens of ms
VALUES = {"lag": {"T": 0.03}, "sensorlag": {"T": 0.03}}
#: catalogue effect -> the names that are right for it (itself, or what names its law exactly
#: or equivalently: a valve lag and a sensor lag commute on an integrator)
NAMES = {e: EQUIVALENT[law] | {e} for e, law in LAW.items()}
#: the base model's parameters, as an ambiguity names them
BASE = {"gain", "delay", "trend"}
#: the reversal boosts: one per stand (the rod-timed one is the paper's)
REVERSALS = {"reversal", "command_reversal", "travel_reversal"}
#: the noise of each seed (the issue's stands had 2-4 kgf)
NOISE_KGF = (2.0, 4.0, 3.0)

#: the paper's meander: u0 = 5, 10, 15, 20 %, period 4 s, four cycles each (70 s)
MEANDER = [p for p in sim.PLAN if p[1] == "meander"]
#: P feedback (k = 0.005) on sinusoidal references: the paper's slow one, one of its fastest
#: at 3000 kgf, and a faster one (70 s)
PFEEDBACK = [("pfb_f0.1", "pfeedback", dict(kp=0.005, amp=2000.0, freq=0.1, duration=30.0), 0.0),
             ("pfb_f0.4_a3000", "pfeedback", dict(kp=0.005, amp=3000.0, freq=0.4, duration=20.0), 0.0),
             ("pfb_f1.5", "pfeedback", dict(kp=0.005, amp=2000.0, freq=1.5, duration=20.0), 0.0)]
PLANS = {"meander": MEANDER, "pfeedback": PFEEDBACK}
#: the quick mode's short meander: 5 and 20 %, two cycles each (17 s)
SHORT_MEANDER = [("meander_u5", "meander", dict(u0=5.0, cycles=2), 0.0),
                 ("meander_u20", "meander", dict(u0=20.0, cycles=2), 0.0)]


@dataclass(frozen=True)
class Cell:
    """True effects (catalogue names), excitation and noise draw of one case."""

    effects: tuple[str, ...]
    excitation: str               #: "meander" | "pfeedback" | "short_meander"
    seed: int = 0                 #: the draw's index (its noise: :data:`NOISE_KGF`)

    @property
    def label(self) -> str:
        return "+".join(self.effects) if self.effects else "none"

    @property
    def noise_kgf(self) -> float:
        return NOISE_KGF[self.seed % len(NOISE_KGF)]

    def rng_seed(self) -> int:
        """The simulator's seed: the same noise for the same excitation and draw, whatever the
        effects (so a cell without one of its effects sees the same noise)."""
        return 52_000 + zlib.crc32(f"{self.excitation}/{self.seed}".encode()) % 100_000


def plan(cell: Cell) -> list:
    return SHORT_MEANDER if cell.excitation == "short_meander" else PLANS[cell.excitation]


def records(cell: Cell, without: str | None = None) -> list:
    """The cell's records (``without``: one of its effects left out, the same noise)."""
    laws = "+".join(LAW[e] for e in cell.effects if e != without) or "none"
    data = sim.make_dataset(laws, cell.rng_seed(), plan=plan(cell),
                            plant={"sigma": cell.noise_kgf}, values=VALUES)
    return [make_record(t, u, y, r if np.isfinite(r).any() else None, source=name)
            for name, _, t, u, y, r, _ in data]


def shown(cell: Cell, recs: list) -> dict[str, bool]:
    """Whether the records show each true effect: without it they differ by at least half
    the noise (RMS over all samples)."""
    out = {}
    for e in cell.effects:
        other = records(cell, without=e)
        d = np.concatenate([a.y - b.y for a, b in zip(recs, other)])
        out[e] = bool(np.sqrt(np.mean(d ** 2)) >= 0.5 * cell.noise_kgf)
    return out


def matrix(seeds: int = 2, excitations: tuple[str, ...] = ("meander", "pfeedback")) -> list[Cell]:
    """Every catalogue effect alone, and every pair with the reversal boost and with a valve
    lag (not two reversal boosts), on each excitation with ``seeds`` noise draws."""
    sets = [(e,) for e in LAW]
    for partner in ("reversal", "lag"):
        for e in LAW:
            pair = tuple(sorted({partner, e}))
            if len(pair) == 2 and pair not in sets and not set(pair) <= REVERSALS:
                sets.append(pair)
    return [Cell(s, x, k) for s in sets for x in excitations for k in range(seeds)]


@dataclass
class Outcome:
    """What the stepwise diagnosis made of a cell, and the judgement."""

    cell: Cell
    right: bool
    verdict: str
    model: str                    #: the final model's spec
    over_floor: float
    missed: list[str]             #: true effects shown but neither named nor said ambiguous
    spurious: list[str]           #: effects named for no true effect
    ambiguous: list[str]          #: true effects said to be indistinguishable from ...
    not_shown: list[str]          #: true effects the records do not show
    overdamped_resonance: bool    #: the final model has a resonance with ζ ≥ 1
    path: str
    seconds: float
    values: dict = field(default_factory=dict)

    @property
    def taken_for(self) -> str:
        """What a wrong cell was taken for, in a few words."""
        return (f"{self.model} ({self.verdict}, {self.over_floor:.2f}x)"
                + (f", missed {', '.join(self.missed)}" if self.missed else "")
                + (f", spurious {', '.join(self.spurious)}" if self.spurious else ""))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["cell"] = {"effects": list(self.cell.effects), "excitation": self.cell.excitation,
                     "seed": self.cell.seed}
        return d


def judge(cell: Cell, result, show: dict[str, bool], seconds: float = 0.0) -> Outcome:
    """Judge a :class:`~analysis.diagnosis.stepwise.Stepwise` result on ``cell``."""
    named = {e.name for e in result.model.effects}
    said = [set(a.effects) for a in result.ambiguities]
    used: set[str] = set()
    missed, ambiguous = [], []
    for t in cell.effects:
        hit = named & NAMES[t]
        if hit:
            used |= hit
            continue
        # said precisely: an ambiguity between the true effect and what stands in its place
        stand_in = next((s for s in said if s & NAMES[t] and (s - NAMES[t]) & (named | BASE)), None)
        if stand_in is not None:
            used |= stand_in & named
            ambiguous.append(f"{t} ~ {'/'.join(sorted(stand_in - NAMES[t]))}")
        elif show[t]:
            missed.append(t)
    spurious = sorted(named - used)
    params = result.model.params()
    overdamped = ("resonance" in named and params["resonance.damping"] >= 1.0)
    right = not missed and not spurious and result.verdict != "varies_between_records"
    path = " -> ".join([result.steps[0].model] + [f"+{s.added}" for s in result.steps if s.added])
    return Outcome(cell, right, result.verdict, result.model.spec, result.steps[-1].over_floor,
                   missed, spurious, ambiguous, [t for t in cell.effects if not show[t]],
                   overdamped, path, seconds, {k: v for k, v in params.items()})


def run_cell(cell: Cell) -> Outcome:
    """Simulate, diagnose stepwise (one process: the cells are the parallel work) and judge."""
    from analysis import stepwise
    recs = records(cell)
    show = shown(cell, recs)
    t0 = time.process_time()
    result = stepwise(recs, jobs=1)
    return judge(cell, result, show, time.process_time() - t0)
