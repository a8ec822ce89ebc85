r"""A rig's controller, designed from its model: decoupling feedforward and feedback, with the
margins of all loops together.

The rig's plant (:mod:`plant.rig`) is ``dy/dt = G·w(t − τ) + Δ``, ``w_j`` channel j's flow
after its own valve and flow effects. The controller, per cycle (:mod:`loading.rig_controller`),

.. math::  u = \operatorname{clip}\big(u^{ff} + S\,M\,K_p\,e + i,\ \pm u_{max}\big),\qquad
           i \leftarrow i + S\,M\,K_i\,e,

* **feedforward** through the model's inverse (:mod:`loading.rig_feedforward`): the planned
  force rates of every channel give the flows ``w = G^{-1}(\dot r − Δ − F(r))``, each channel's
  flow and valve effects are inverted as for one channel, each command is sent its own ``τ``
  ahead;
* **feedback**: one PI per channel, ``K_p = \operatorname{diag}(K_{p,i})``,
  ``K_i = K_p·T/T_i``, each designed for its own channel by the one-channel design
  (:func:`loading.design.design`: SIMC, gain margin ≥ 2 at the channel's boosted gain, phase
  margin ≥ 45°), their outputs through ``M = \hat G^{-1}\operatorname{diag}(\hat g)``
  (**decoupled**, the default) or ``M = I`` (**independent**: today's one-channel controller on
  every channel, the baseline); ``S`` the per-valve share of the feedback where the model's gain
  exceeds the design's (as for one channel).

**Why decoupled.** With ``M = I`` each loop meets the structure's coupling as a gain: the loop
of the load pattern ``v`` (an eigenvector of ``G·diag(1/g)``) has its gain times that eigenvalue,
0.51-1.49 on the example rig (neighbours 30 %), so the one-channel design's margins do not hold
together: at the boosted gains the phase margin falls from 45° to 30° and the gain margin from
2.2 to 1.6 (characteristic loci, :mod:`loading.rig_margins`). With ``M = \hat G^{-1}diag(\hat
g)`` the loop is ``G·diag(ρP̂)·\hat G^{-1}·diag(\hat g C)``: for ``\hat G = G`` and equal delays
exactly ``diag(g_i ρ_i P̂_i C_i)``, so each loop sees its own g and the one-channel margins carry
over (44.8° and 2.15 on the example rig, whose delays differ by up to 15 ms). The feedforward
through ``G^{-1}`` does the tracking; the feedback handles what the model does not know, and it
does so without fighting the neighbours.

**The multi-loop margins** are the characteristic loci's (generalized Nyquist,
:mod:`loading.rig_margins`) at: the nominal gains; every channel at its largest gain factor
``ρ_j`` (a load case reverses every channel at once); each channel alone at ``ρ_j`` (the others
nominal); and each of these with the plant's coupling ``1 ± ε`` times the model's
(:data:`COUPLING_ERROR`, the model-error factor on G). The decoupled design asks of every case
what the one-channel design asks (gain margin ≥ 2 where boosted, phase margin ≥ 45°); where the
delays' mismatch or the coupling's error costs margin, every loop's closed-loop time constant
is lengthened by one common factor κ ≥ 1 (bisected) until they hold. No κ up to
:data:`DETUNING_MAX` holds them: **refused**, with the figure (which case, which margin). The
independent baseline is today's design on each channel, unchanged; it is refused when the loops
together are unstable at any case (at a boosted one: they self-oscillate after reversals), and
stated with a note when they hold less than the targets. Stability is decided by the closed
loop's eigenvalues for every case (python-control), the margins by the loci.

A rig controller file (TOML, :data:`SCHEMA`) holds it all: the loop, the model's G, per channel
the PI and its model, and the margins it was designed with.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from core.errors import ParameterError
from plant import PlantModel
from plant.params import ModelError
from plant.rig import RigModel

from .design import (COMMAND_LIMIT_PCT, GAIN_MARGIN_MIN, PHASE_MARGIN_MIN_DEG, ControllerDesign,
                     check_model, design, margins)
from .rig_margins import POINTS, LoopMargins, RigLoop

SCHEMA = "hydrostand-rig-controller/1"
#: the plant's coupling may be this much off the model's (each off-diagonal entry of G)
COUPLING_ERROR = 0.2
#: the longest closed-loop time constants tried, as a multiple of each channel's own design's
DETUNING_MAX = 8.0
DETUNING_BISECTIONS = 8
#: frequency points of the loci while searching κ (the stated margins use more)
SEARCH_POINTS = 1000
FEEDBACKS = ("decoupled", "independent")
FEEDFORWARDS = ("rig", "channel")


@dataclass
class RigControllerDesign:
    """A rig controller file's content (module docstring)."""

    names: list[str]
    G: np.ndarray                           #: the model's gain matrix, kgf/(%·s)
    channels: list[ControllerDesign]        #: per channel: its model, PI and one-loop margins
    period_s: float
    command_limit_pct: float = COMMAND_LIMIT_PCT
    feedback: str = "decoupled"             #: "decoupled" (M = Ĝ⁻¹·diag(ĝ)) or "independent" (M = I)
    feedforward: str = "rig"                #: "rig" (through G⁻¹) or "channel" (each its own g)
    detuning: float = 1.0                   #: κ: every λ over its one-channel design's
    coupling_error: float = COUPLING_ERROR
    margins: list[LoopMargins] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def n(self) -> int:
        return len(self.names)

    @property
    def model(self) -> RigModel:
        return RigModel([c.model for c in self.channels], self.G, self.names)

    @property
    def boosts(self) -> np.ndarray:
        return np.array([c.boost for c in self.channels])

    @property
    def decoupled(self) -> bool:
        return self.feedback == "decoupled"

    @property
    def M(self) -> np.ndarray:
        """The feedback's mixing matrix (module docstring)."""
        return self.loop().M

    def loop(self) -> RigLoop:
        return RigLoop(self.G, np.array([c.model.tau for c in self.channels]),
                       np.array([c.kp_pct_per_kgf for c in self.channels]),
                       np.array([c.ti_s for c in self.channels]), self.period_s, self.decoupled)

    def worst(self, boosted: bool | None = None) -> LoopMargins | None:
        """The case with the smallest phase margin (among the boosted or nominal ones)."""
        cases = [m for m in self.margins if boosted is None or _boosted(m) == boosted]
        return min(cases, key=lambda m: (m.phase_margin_deg, m.gain_margin), default=None)

    def text(self) -> str:
        lines = [f"rig controller for {self.n} channels at T = {self.period_s * 1e3:g} ms: feedforward "
                 + ("through G⁻¹ (the rig's model)" if self.feedforward == "rig" else "each channel's own g")
                 + ", feedback " + ("decoupled (PI outputs through Ĝ⁻¹·diag(ĝ))" if self.decoupled
                                    else "independent (one PI per channel)")
                 + (f", λ × {self.detuning:.2f} of the one-channel designs" if self.detuning > 1 else ""),
                 "G, kgf/(%·s):"]
        width = max(len(n) for n in self.names)
        lines.append(" " * (width + 2) + "".join(f"{n:>9}" for n in self.names))
        for name, row in zip(self.names, self.G):
            lines.append(f"  {name:<{width}}" + "".join(f"{v:9.2f}" for v in row))
        lines.append("channels:")
        for name, c in zip(self.names, self.channels):
            lines.append(f"  {name:<{width}}  {c.model_spec}, g {c.model.g:.2f}, τ {c.model.tau * 1e3:.1f} ms, "
                         f"largest gain factor {c.boost:.2f}: Kp {c.kp_pct_per_kgf:.5f} %/kgf, "
                         f"Ti {c.ti_s:.3f} s (λ {c.lambda_s:.3f} s)")
        lines.append("loops together (characteristic loci; coupling ± "
                     f"{100 * self.coupling_error:.0f} % = the plant's off-diagonal G off the model's):")
        for label, boosted in (("nominal", False), ("boosted", True)):
            w = self.worst(boosted)
            if w is not None:
                lines.append(f"  {label:<8} worst case: {w.text()}")
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"schema": SCHEMA, "channels": self.names, "G": self.G.tolist(), "period_s": self.period_s,
                "command_limit_pct": self.command_limit_pct, "feedback": self.feedback,
                "feedforward": self.feedforward, "detuning": self.detuning,
                "coupling_error": self.coupling_error,
                "channel": {n: {"model": c.model_spec, "params": c.model_params,
                                "kp_pct_per_kgf": c.kp_pct_per_kgf, "ti_s": c.ti_s, "lambda_s": c.lambda_s,
                                "boost": c.boost} for n, c in zip(self.names, self.channels)},
                "margins": [m.to_dict() for m in self.margins], "notes": self.notes}

    def to_toml(self, path: str | Path | None = None) -> str:
        """The rig controller file; ``path``: where it will be written (plug-in files are
        named relative to it)."""
        import json
        from plant.config import plugin_sources
        here = Path(path).parent if path is not None else None
        sources: list[str] = []
        for c in self.channels:
            sources += [s for s in plugin_sources(c.model, here) if s not in sources]
        out = [f"# {SCHEMA}: a rig's force controller designed by `stand design` (edit with care:",
               "# the margins below were computed for these values and are not re-checked on load)",
               "channels = [" + ", ".join(json.dumps(n) for n in self.names) + "]"]
        if sources:
            out.append("plugins = [" + ", ".join(json.dumps(s) for s in sources) + "]")
        out += ["", "[loop]", f"period_s = {_num(self.period_s)}",
                f"command_limit_pct = {_num(self.command_limit_pct)}",
                f'feedback = "{self.feedback}"', f'feedforward = "{self.feedforward}"',
                "", "[structure]", "# kgf/(%·s); row i: channel i's force, column j: channel j's valve",
                "G = ["]
        out += ["    [" + ", ".join(_num(v) for v in row) + "]," for row in self.G]
        out += ["]", "", "[design]", f"detuning = {_num(self.detuning)}",
                f"coupling_error = {_num(self.coupling_error)}"]
        for m in self.margins:
            out += ["", "[[design.margins]]", f"label = {json.dumps(m.label)}",
                    "factors = [" + ", ".join(_num(f) for f in m.factors) + "]",
                    f"coupling_error = {_num(m.coupling_error)}", f"gain_margin = {_num(m.gain_margin)}",
                    f"phase_margin_deg = {_num(m.phase_margin_deg)}", f"crossover_hz = {_num(m.crossover_hz)}",
                    f"peak_sensitivity = {_num(m.peak_sensitivity)}"]
        for name, c in zip(self.names, self.channels):
            out += ["", f"[channel.{name}]", f"kp_pct_per_kgf = {_num(c.kp_pct_per_kgf)}",
                    f"ti_s = {_num(c.ti_s)}", f"lambda_s = {_num(c.lambda_s)}", f"boost = {_num(c.boost)}",
                    f"[channel.{name}.model]", f'spec = "{c.model_spec}"']
            out += [f'"{k}" = {_num(v)}' for k, v in c.model_params.items()]
        return "\n".join(out) + "\n"


def _num(v: float) -> str:
    v = float(v)
    if math.isnan(v):
        return "nan"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return repr(v)


def _boosted(m: LoopMargins) -> bool:
    return any(f > 1.0 + 1e-12 for f in m.factors)


# -- the design ---------------------------------------------------------------------------------------
def margin_cases(boosts: Sequence[float], names: Sequence[str],
                 coupling_error: float) -> list[tuple[str, list[float], float]]:
    """The (label, gain factors, coupling error) the margins are computed at (module
    docstring): nominal, all boosted, each alone boosted; each at the model's coupling and at
    ``1 ± coupling_error`` times it."""
    n = len(boosts)
    sets = [("nominal", [1.0] * n), ("boosted", [float(b) for b in boosts])]
    if n > 1:
        for j, name in enumerate(names):
            if boosts[j] > 1.0 + 1e-12:
                sets.append((f"boosted: {name}", [float(b) if k == j else 1.0 for k, b in enumerate(boosts)]))
    errors = [0.0] + ([coupling_error, -coupling_error] if coupling_error > 0 and n > 1 else [])
    return [(label, f, e) for e in errors for label, f in sets]


def _meets(m: LoopMargins) -> bool:
    """The one-channel design's targets (:mod:`loading.design`), asked of the loops together."""
    return m.gain_margin >= GAIN_MARGIN_MIN and m.phase_margin_deg >= PHASE_MARGIN_MIN_DEG


def _detuned(c: ControllerDesign, kappa: float, with_margins: bool = True) -> ControllerDesign:
    """The one-channel design with its λ times κ (SIMC: Kp = 1/(g(λ + θ)), Ti = 4(λ + θ));
    ``with_margins``: its own loop's margins recomputed (not while searching κ)."""
    if kappa == 1.0:
        return c
    model = c.model
    theta = model.tau + c.period_s / 2
    lam = c.lambda_s * kappa
    kp, ti = 1.0 / (model.g * (lam + theta)), 4.0 * (lam + theta)
    if not with_margins:
        return replace(c, kp_pct_per_kgf=kp, ti_s=ti, lambda_s=lam)
    return replace(c, kp_pct_per_kgf=kp, ti_s=ti, lambda_s=lam,
                   nominal=margins(kp, ti, model.g, model.tau, c.period_s, check=False),
                   boosted=margins(kp, ti, model.g * c.boost, model.tau, c.period_s, check=False))


def _loop(names, G, channels, period_s, decoupled) -> RigLoop:
    return RigLoop(G, np.array([c.model.tau for c in channels]),
                   np.array([c.kp_pct_per_kgf for c in channels]),
                   np.array([c.ti_s for c in channels]), period_s, decoupled)


def _case_margins(loop: RigLoop, cases, points: int, check: bool = False) -> list[LoopMargins]:
    """The margins of every case; ``check``: the closed loop's eigenvalues too (stable or not)."""
    return [loop.margins(f, label, e, points=points, check=check) for label, f, e in cases]


def _refuse_unstable(m: LoopMargins, loop: RigLoop, G: np.ndarray, spectrum: np.ndarray) -> None:
    """Refuse a decoupled design whose loops are unstable at the case ``m``, with the figure."""
    mix = np.sort(np.linalg.eigvals(loop.plant_G(m.coupling_error) @ np.linalg.inv(G)).real)
    raise ParameterError(
        f"the coupling is too strong for decoupled PI feedback: at {m.label}"
        + (f" with the coupling {100 * m.coupling_error:+.0f} % off the model's" if m.coupling_error else "")
        + f" the loops together are unstable (closed-loop eigenvalues beyond the unit circle): the "
        f"plant's G times the model's inverse has eigenvalues from {mix[0]:.3g} to {mix[-1]:.3g} "
        f"(1 when the model is right); G·diag(1/g) has eigenvalues from {spectrum[0]:.3g} to "
        f"{spectrum[-1]:.3g}. Identify G better (a smaller --coupling-error) or check the rig model")


def check_rig_model(model: RigModel, where: str = "rig model") -> None:
    """Refuse a rig model a controller cannot be designed from: non-finite or non-positive
    values, a singular G."""
    G = model.G
    if not np.all(np.isfinite(G)):
        raise ParameterError(f"{where}: G has a value that is not a finite number")
    for name, m in zip(model.names, model.channels):
        check_model(m, f"{where}: channel {name}")
    cond = np.linalg.cond(G)
    if not math.isfinite(cond) or cond > 1e8:
        raise ParameterError(f"{where}: G is singular (condition number {cond:.3g}): some load "
                             "pattern cannot be made by any valve commands; check the rig model")


def design_rig(model: RigModel, period_s: float = 0.002, command_limit_pct: float = COMMAND_LIMIT_PCT,
               feedback: str = "decoupled", feedforward: str | None = None,
               coupling_error: float = COUPLING_ERROR) -> RigControllerDesign:
    """The rig's controller (module docstring). ``feedback``: ``decoupled`` or ``independent``;
    ``feedforward``: ``rig`` (through G⁻¹) or ``channel`` (each channel's own g; default: ``rig``
    with decoupled feedback, ``channel`` with independent, today's controller per channel).
    Raises :class:`~core.errors.ParameterError` with the figure when the coupling is too strong
    for the feedback."""
    if feedback not in FEEDBACKS:
        raise ParameterError(f"feedback {feedback!r}: it is one of {', '.join(FEEDBACKS)}")
    feedforward = feedforward or ("rig" if feedback == "decoupled" else "channel")
    if feedforward not in FEEDFORWARDS:
        raise ParameterError(f"feedforward {feedforward!r}: it is one of {', '.join(FEEDFORWARDS)}")
    if not (0.0 <= coupling_error < 1.0):
        raise ParameterError(f"coupling error {coupling_error}: it must be from 0 to 1 (a share)")
    check_rig_model(model)
    G = np.array(model.G, float)
    names = list(model.names)
    one = []
    for name, m in zip(names, model.channels):
        try:
            one.append(design(m, period_s, command_limit_pct, check=False))
        except ParameterError as exc:
            raise ParameterError(f"channel {name}: {exc}") from None
    boosts = [c.boost for c in one]
    cases = margin_cases(boosts, names, coupling_error)
    notes = [f"{name}: {n}" for name, c in zip(names, one) for n in c.notes]
    decoupled = feedback == "decoupled"
    spectrum = np.sort(np.linalg.eigvals(G / np.diag(G)[None, :]).real)
    kappa = 1.0
    if decoupled:
        order = list(cases)

        def worst_at(k: float) -> LoopMargins | None:
            """The first case whose margins miss the targets at κ = k (None: all hold); the
            case that failed last is tried first."""
            loop = _loop(names, G, [_detuned(c, k, False) for c in one], period_s, True)
            for i, (label, f, e) in enumerate(order):
                m = loop.margins(f, label, e, points=SEARCH_POINTS, sensitivity=False)
                if not _meets(m):
                    order.insert(0, order.pop(i))
                    return m
            return None
        failing = worst_at(1.0)
        if failing is not None:
            at_max = worst_at(DETUNING_MAX)
            if at_max is not None:
                loop = _loop(names, G, [_detuned(c, DETUNING_MAX, False) for c in one], period_s, True)
                if not loop.margins(at_max.factors, at_max.label, at_max.coupling_error, SEARCH_POINTS,
                                    check=True, sensitivity=False).stable:
                    _refuse_unstable(at_max, loop, G, spectrum)
                raise ParameterError(
                    f"the coupling is too strong for decoupled PI feedback: at {at_max.label}"
                    + (f" with the coupling {100 * at_max.coupling_error:+.0f} % off the model's"
                       if at_max.coupling_error else "")
                    + f" the loops together keep a gain margin of {at_max.gain_margin:.2f} and a phase "
                    f"margin of {at_max.phase_margin_deg:.1f}° (targets {GAIN_MARGIN_MIN:g} and "
                    f"{PHASE_MARGIN_MIN_DEG:g}°) even {DETUNING_MAX:g}× slower than each channel's own "
                    f"design; G·diag(1/g) has eigenvalues from {spectrum[0]:.3g} to {spectrum[-1]:.3g}. "
                    "Identify G better (a smaller --coupling-error) or check the rig model")
        if failing is not None:
            lo, hi = 1.0, DETUNING_MAX
            for _ in range(DETUNING_BISECTIONS):
                mid = math.sqrt(lo * hi)
                lo, hi = (lo, mid) if worst_at(mid) is None else (mid, hi)
            kappa = hi
            notes.append(f"every λ × {kappa:.3f}: at κ = 1 {failing.label}"
                         + (f" (coupling {100 * failing.coupling_error:+.0f} %)" if failing.coupling_error else "")
                         + f" kept phase margin {failing.phase_margin_deg:.1f}°, gain margin "
                           f"{failing.gain_margin:.2f} (the channels' delays differ, or the coupling's error)")
    channels = [_detuned(c, kappa) for c in one]
    loop = _loop(names, G, channels, period_s, decoupled)
    stated = _case_margins(loop, cases, POINTS, check=True)
    unstable = [m for m in stated if m.stable is False]
    if decoupled and unstable:
        _refuse_unstable(unstable[0], loop, G, spectrum)
    if not decoupled:
        bad = [m for m in stated if m.stable is False or m.gain_margin < 1.0 or m.phase_margin_deg <= 0]
        nominal_bad = [m for m in bad if not _boosted(m)]
        if bad:
            m = nominal_bad[0] if nominal_bad else bad[0]
            raise ParameterError(
                f"the coupling is too strong for independent PI loops: at {m.label}"
                + (f" with the coupling {100 * m.coupling_error:+.0f} % off the model's" if m.coupling_error else "")
                + (" the loops together are unstable (closed-loop eigenvalues beyond the unit circle"
                   + (": they self-oscillate after reversals)" if _boosted(m) else ")")
                   if m.stable is False else
                   f" the loops together have a gain margin of {m.gain_margin:.2f} and a phase margin "
                   f"of {m.phase_margin_deg:.1f}°" + (" (they self-oscillate after reversals)" if _boosted(m) else ""))
                + ";"
                f" G·diag(1/g) has eigenvalues from {spectrum[0]:.3g} to {spectrum[-1]:.3g}: decouple "
                "(stand design without --independent)")
        short = [m for m in stated if not _meets(m)]
        if short:
            w = min(short, key=lambda m: m.phase_margin_deg)
            notes.append(f"the independent loops together hold less than the one-channel targets: {w.label}"
                         + (f" (coupling {100 * w.coupling_error:+.0f} %)" if w.coupling_error else "")
                         + f" gain margin {w.gain_margin:.2f}, phase margin {w.phase_margin_deg:.1f}° "
                         f"(G·diag(1/g) has eigenvalues {spectrum[0]:.3g} to {spectrum[-1]:.3g}: the "
                         "coupling changes each load pattern's loop gain)")
    return RigControllerDesign(names, G, channels, period_s, command_limit_pct, feedback, feedforward,
                               kappa, coupling_error, stated, notes)


# -- files -------------------------------------------------------------------------------------------
def read_rig_model(path: str | Path) -> tuple[RigModel, str]:
    """The rig model a design starts from, and where it came from: a rig model file
    (``stand estimate --save`` / ``stand diagnose --rig-model ... --save``: ``channels``,
    ``[structure] G``, a ``[channel.NAME]`` model each), or a rig file whose channels have
    plants (the emulator's truth: ``examples/rig.toml``). The one place that reads either."""
    from plant.config import read_toml
    path = Path(path)
    try:
        data = read_toml(path)
    except ModelError as exc:
        raise ParameterError(str(exc)) from None
    if isinstance(data.get("channel"), list):            # a rig file: [[channel]] tables
        from rig.config import RigError, load_rig_file
        try:
            rig = load_rig_file(path)
        except RigError as exc:
            raise ParameterError(str(exc)) from None
        lacking = [c.name for c in rig.channels if c.plant is None]
        if lacking:
            raise ParameterError(f"{path}: a rig file without plants for {', '.join(lacking)}; "
                                 "design from a rig model file (stand estimate RUNS --save, stand "
                                 "diagnose --rig-model ... --save) or a rig file with a plant per channel")
        return (RigModel([c.plant.model for c in rig.channels], rig.G, rig.names),
                f"{path.name} (the rig file's plants: the emulator's truth)")
    try:
        from plant.rig_config import load_rig_model
    except ImportError:
        raise ParameterError(f"{path}: not a rig file ([[channel]] tables with plants); rig model "
                             "files come with the rig identification") from None
    try:
        return load_rig_model(path), f"{path.name} (rig model file)"
    except ModelError as exc:
        raise ParameterError(str(exc)) from None


def is_rig_file(path: str | Path) -> bool:
    """True if ``path`` is a rig model file, a rig file or a rig controller file (TOML with
    ``channels`` or ``[[channel]]``), False for a one-channel model or controller file."""
    from plant.config import read_toml
    p = Path(path)
    if not p.is_file() or p.suffix.lower() != ".toml":
        return False
    try:
        data = read_toml(p)
    except ModelError:
        return False
    return "channels" in data or isinstance(data.get("channel"), list)


def load_rig_controller(path: str | Path, period_s: float | None = None,
                        names: Sequence[str] | None = None) -> RigControllerDesign:
    """A rig controller file, validated: every value finite, every model complete, G square and
    its diagonal each channel's g, the period the loop's (if given), the channels the rig's (if
    given: in any order, put in the rig's)."""
    from plant.config import load_named_plugins, read_toml
    path = Path(path)
    try:
        data = read_toml(path)
    except ModelError as exc:
        raise ParameterError(str(exc)) from None
    if "channels" not in data:
        raise ParameterError(f"{path}: not a rig controller file (no channels = [...]); a "
                             "one-channel controller drives one stand: design the rig's with "
                             "`stand design RIG-MODEL.toml -o FILE`")
    try:
        load_named_plugins(data, str(path), path.parent)
        file_names = [str(n) for n in data["channels"]]
        loop = data["loop"]
        G = np.array(data["structure"]["G"], float)
        des = data.get("design", {})
        chans = []
        for n in file_names:
            t = data["channel"][n]
            mdl = dict(t["model"])
            spec = str(mdl.pop("spec"))
            chans.append(ControllerDesign(
                period_s=float(loop["period_s"]), model_spec=spec,
                model_params={k: float(v) for k, v in mdl.items()},
                kp_pct_per_kgf=float(t["kp_pct_per_kgf"]), ti_s=float(t["ti_s"]),
                command_limit_pct=float(loop.get("command_limit_pct", COMMAND_LIMIT_PCT)),
                boost=float(t.get("boost", 1.0)), lambda_s=float(t.get("lambda_s", math.nan))))
        stated = [LoopMargins(str(m["label"]), [float(f) for f in m["factors"]], float(m["coupling_error"]),
                              float(m["gain_margin"]), float(m["phase_margin_deg"]), float(m["crossover_hz"]),
                              float(m["peak_sensitivity"])) for m in des.get("margins", [])]
        c = RigControllerDesign(file_names, G, chans, float(loop["period_s"]),
                                float(loop.get("command_limit_pct", COMMAND_LIMIT_PCT)),
                                str(loop.get("feedback", "decoupled")), str(loop.get("feedforward", "rig")),
                                float(des.get("detuning", 1.0)), float(des.get("coupling_error", COUPLING_ERROR)),
                                stated)
    except KeyError as exc:
        raise ParameterError(f"{path}: no {exc.args[0]!r}; a rig controller file has channels, [loop] "
                             "period_s, [structure] G and a [channel.NAME] table per channel with "
                             "kp_pct_per_kgf, ti_s and [channel.NAME.model] (write one with `stand "
                             "design RIG-MODEL.toml -o FILE`)") from None
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{path}: a value is not a number ({exc})") from None
    except ModelError as exc:
        raise ParameterError(f"{path}: {exc}") from None
    n = len(file_names)
    if G.shape != (n, n) or not np.all(np.isfinite(G)):
        raise ParameterError(f"{path}: [structure] G must be {n} rows of {n} finite numbers")
    if c.feedback not in FEEDBACKS or c.feedforward not in FEEDFORWARDS:
        raise ParameterError(f"{path}: [loop] feedback is one of {', '.join(FEEDBACKS)} and feedforward "
                             f"one of {', '.join(FEEDFORWARDS)}")
    for name, ch in zip(file_names, c.channels):
        where = f"{path}: [channel.{name}]"
        try:
            needed = set(PlantModel.from_spec(ch.model_spec).params())
        except ModelError as exc:
            raise ParameterError(f"{where}: {exc}") from None
        missing = sorted(needed - set(ch.model_params))
        if missing:
            raise ParameterError(f"{where}.model lacks {', '.join(missing)} of {ch.model_spec}")
        for key, v in (("kp_pct_per_kgf", ch.kp_pct_per_kgf), ("ti_s", ch.ti_s)):
            if not (v > 0 and (math.isfinite(v) or key == "ti_s" and v == math.inf)):
                raise ParameterError(f"{where}: {key} = {v} must be a positive number")
        try:
            check_model(ch.model, where)
        except ModelError as exc:
            raise ParameterError(f"{where}: {exc}") from None
        if not math.isclose(ch.model.g, G[file_names.index(name)][file_names.index(name)], rel_tol=1e-9):
            raise ParameterError(f"{where}: its model's g = {ch.model.g:g} is not G's diagonal "
                                 f"{G[file_names.index(name)][file_names.index(name)]:g}")
    if not (c.period_s > 0 and 0 < c.command_limit_pct <= 100):
        raise ParameterError(f"{path}: period_s must be positive and command_limit_pct from 0 to 100")
    if period_s is not None and abs(c.period_s - period_s) > 1e-9:
        raise ParameterError(f"{path} was designed for a period of {c.period_s * 1e3:g} ms but the loop "
                             f"runs at {period_s * 1e3:g} ms; design it again with "
                             f"`stand design RIG-MODEL --period-ms {period_s * 1e3:g}`")
    if names is not None:
        names = list(names)
        if sorted(names) != sorted(file_names):
            raise ParameterError(f"{path} is for the channels {', '.join(file_names)}; the rig has "
                                 f"{', '.join(names)}")
        order = [file_names.index(nm) for nm in names]
        c = replace(c, names=names, G=G[np.ix_(order, order)], channels=[c.channels[i] for i in order])
    return c
