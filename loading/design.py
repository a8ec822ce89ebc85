r"""A station's force controller, designed from its identified model: feedforward through the
model's inverse and a PI per channel, with the margins of the loops together.

**One channel** (:func:`design_channel`): for the paper's model the loop at the control period
``T`` is exactly, in discrete time (zero-order hold, no Padé approximation, :mod:`loading.margins`),

.. math::  P(z) = g\,T\,\frac{(1 - f)\,z + f}{z^{m+1}\,(z - 1)},\qquad
           C(z) = K_p\left(1 + \frac{T}{T_i}\,\frac{z}{z - 1}\right),

the PI from the SIMC family for an integrating process with dead time θ = τ + T/2:
``K_p = 1/(g·(λ + θ))``, ``T_i = 4·(λ + θ)``. The closed-loop time constant λ is the smallest (by
bisection) for which the loop keeps a **gain margin ≥ 2 at the largest gain the model predicts**
(``g·ρ``: the reversal boost right after a rod reversal, ``ρ = 1 + b`` at ``|q| = u_ref``, times
``1 + |a|`` of an asymmetry) and a **phase margin ≥ 45°** at both the nominal and the boosted
gain. The gain margin is how far the plant's gain may rise before the loop oscillates, so this
is what keeps the paper's self-oscillation after reversals away. The tracking itself comes from
the feedforward (:mod:`loading.feedforward`); the feedback handles what the model does not know.

margins of all loops together.

**A station of N channels** (:func:`design`; a one-channel stand is N = 1, a rig's plant is
:mod:`plant.rig`'s ``dy/dt = G·w(t − τ) + Δ``, ``w_j`` channel j's flow after its own valve and
flow effects). The controller, per cycle (:mod:`loading.controller`),

.. math::  u = \operatorname{clip}\big(u^{ff} + S\,M\,K_p\,e + i,\ \pm u_{max}\big),\qquad
           i \leftarrow i + S\,M\,K_i\,e,

* **feedforward** through the model's inverse (:mod:`loading.feedforward`): the planned
  force rates of every channel give the flows ``w = G^{-1}(\dot r − Δ − F(r))``, each channel's
  flow and valve effects are inverted as for one channel, each command is sent its own ``τ``
  ahead;
* **feedback**: one PI per channel, ``K_p = \operatorname{diag}(K_{p,i})``,
  ``K_i = K_p·T/T_i``, each designed for its own channel by the one-channel design
  (:func:`design_channel`: SIMC, gain margin ≥ 2 at the channel's boosted gain, phase
  margin ≥ 45°), their outputs through ``M = \hat G^{-1}\operatorname{diag}(\hat g)``
  (**decoupled**, the default) or ``M = I`` (**independent**: today's one-channel controller on
  every channel, the baseline); ``S`` the per-valve share of the feedback where the model's gain
  exceeds the design's (as for one channel).

**Why decoupled.** With ``M = I`` each loop meets the structure's coupling as a gain: the loop
of the load pattern ``v`` (an eigenvector of ``G·diag(1/g)``) has its gain times that eigenvalue,
0.51-1.49 on the example rig (neighbours 30 %), so the one-channel design's margins do not hold
together: at the boosted gains the phase margin falls from 45° to 30° and the gain margin from
2.2 to 1.6 (characteristic loci, (:mod:`loading.margins`)). With ``M = \hat G^{-1}diag(\hat
g)`` the loop is ``G·diag(ρP̂)·\hat G^{-1}·diag(\hat g C)``: for ``\hat G = G`` and equal delays
exactly ``diag(g_i ρ_i P̂_i C_i)``, so each loop sees its own g and the one-channel margins carry
over (44.8° and 2.15 on the example rig, whose delays differ by up to 15 ms). The feedforward
through ``G^{-1}`` does the tracking; the feedback handles what the model does not know, and it
does so without fighting the neighbours.

**The multi-loop margins** are the characteristic loci's (generalized Nyquist,
(:mod:`loading.margins`)) at: the nominal gains; every channel at its largest gain factor
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

**At N = 1** the decoupled design is the one-channel design: M = 1, the loop is the channel's
own, its PI and its margins at the nominal and the boosted gain are :func:`design_channel`'s
(the characteristic loci of one loop are its Nyquist curve), and its feedforward is the
channel's own model's (the same flows as through G⁻¹; a rig's feedforward through G⁻¹ plans no
flow below the valve's resolution and holds each valve's sign throughout, for a valve whose
force its neighbours make, which one channel has not).

The controller files (:mod:`loading.controller_files`) hold it all: a one-channel stand's
(:data:`SCHEMA`) the loop, the PI and the model; a rig's (:data:`STATION_SCHEMA`) the loop, the
model's G, per channel the PI and its model, and the margins it was designed with.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from typing import Sequence

from core.errors import ParameterError
from plant import PlantModel
from plant.rig import RigModel

from .margins import POINTS, LoopMargins, Margins, StationLoop, margins
from .programme import STAND

#: required margins
GAIN_MARGIN_MIN = 2.0
PHASE_MARGIN_MIN_DEG = 45.0
#: the closed-loop time constants searched, as multiples of the dead time θ, and the steps
LAMBDA_RANGE = (0.25, 40.0)
LAMBDA_BISECTIONS = 14
#: the loop's command limit (%) unless given
COMMAND_LIMIT_PCT = 100.0
#: a one-channel stand's controller file
SCHEMA = "hydrostand-controller/1"
#: a rig's controller file
STATION_SCHEMA = "hydrostand-rig-controller/1"
#: the plant's coupling may be this much off the model's (each off-diagonal entry of G)
COUPLING_ERROR = 0.2
#: the longest closed-loop time constants tried, as a multiple of each channel's own design's
DETUNING_MAX = 8.0
DETUNING_BISECTIONS = 8
#: frequency points of the loci while searching κ (the stated margins use more)
SEARCH_POINTS = 1000
FEEDBACKS = ("decoupled", "independent")
#: "rig": through G⁻¹; "channel": each channel from its own model (one channel's plan, coupling
#: left to the feedback); "none": feedback alone (a P controller for comparisons)
FEEDFORWARDS = ("rig", "channel", "none")


@dataclass
class ChannelDesign:
    """One channel's controller: its model, the loop period, the PI gains and its own loop's
    margins (a one-channel stand's controller file)."""

    period_s: float
    model_spec: str
    model_params: dict
    kp_pct_per_kgf: float
    ti_s: float
    command_limit_pct: float = COMMAND_LIMIT_PCT
    boost: float = 1.0                   #: ρ, the largest gain factor the model predicts
    #: False: feedback alone (a P or PI without the model's inverse, for comparisons)
    feedforward: bool = True
    lambda_s: float = math.nan
    nominal: Margins | None = None
    boosted: Margins | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def model(self) -> PlantModel:
        return PlantModel.from_spec(self.model_spec, self.model_params)

    def text(self) -> str:
        lines = [f"controller for {self.model_spec} at T = {self.period_s * 1e3:g} ms "
                 f"(g = {self.model_params['g']:.2f} kgf/(%·s), τ = {self.model_params['tau'] * 1e3:.1f} ms, "
                 f"largest gain factor {self.boost:.2f})",
                 f"feedback: PI, Kp = {self.kp_pct_per_kgf:.5f} %/kgf, Ti = {self.ti_s:.3f} s "
                 f"(λ = {self.lambda_s:.3f} s), command limit ±{self.command_limit_pct:g} %"]
        if self.nominal:
            lines.append(self.nominal.text("nominal"))
        if self.boosted:
            lines.append(self.boosted.text("boosted"))
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["schema"] = SCHEMA
        return d

    def to_toml(self, path: str | Path | None = None) -> str:
        """The controller file; ``path``: where it will be written (the model's plug-in files
        are named relative to it)."""
        from plant.config import plugin_sources

        def num(v: float) -> str:
            return repr(float(v))
        out = [f"# {SCHEMA}: a force controller designed by `stand design` (edit with care: the",
               "# margins below were computed for these values and are not re-checked on load)",
               "[loop]", f"period_s = {num(self.period_s)}", f"command_limit_pct = {num(self.command_limit_pct)}",
               f"feedforward = {'true' if self.feedforward else 'false'}",
               "", "[feedback]", f"kp_pct_per_kgf = {num(self.kp_pct_per_kgf)}", f"ti_s = {num(self.ti_s)}",
               "", "[model]", f'spec = "{self.model_spec}"']
        sources = plugin_sources(self.model, Path(path).parent if path is not None else None)
        if sources:
            out.append("plugins = [" + ", ".join(json.dumps(s) for s in sources) + "]")
        out += [f'"{k}" = {num(v)}' for k, v in self.model_params.items()]
        out += ["", "[design]", f"boost = {num(self.boost)}", f"lambda_s = {num(self.lambda_s)}"]
        for label, m in (("nominal", self.nominal), ("boosted", self.boosted)):
            if m is not None:
                out += ["", f"[design.{label}]"] + [f"{k} = {num(v)}" for k, v in asdict(m).items()]
        return "\n".join(out) + "\n"


def proportional(kp_pct_per_kgf: float, model: PlantModel, period_s: float = 0.002) -> "ControllerDesign":
    """A one-channel stand's P controller without feedforward (the paper's ``u = k·(r − y)``),
    for comparisons."""
    rho, notes = largest_gain_factor(model)
    return ControllerDesign.of(ChannelDesign(
        period_s, model.spec, model.params(), kp_pct_per_kgf, math.inf, boost=rho, feedforward=False,
        nominal=margins(kp_pct_per_kgf, math.inf, model.g, model.tau, period_s),
        boosted=margins(kp_pct_per_kgf, math.inf, model.g * rho, model.tau, period_s), notes=notes))


def largest_gain_factor(model: PlantModel) -> tuple[float, list[str]]:
    """ρ: how much larger than g the plant's gain gets, the product of its effects'
    :meth:`~plant.Effect.largest_gain_factor` (a plug-in's too), with a note for each."""
    rho = 1.0
    notes = []
    for e in model.effects:
        factor = e.largest_gain_factor()
        if factor > 1.0 + 1e-9:
            rho *= factor
            notes.append(f"{e.name}: gain up to {factor:.2f}× ({e.summary})")
    return rho, notes


def check_model(model: PlantModel, where: str = "model") -> None:
    for k, v in model.params().items():
        if not math.isfinite(v):
            raise ParameterError(f"{where}: parameter {k} = {v} is not a finite number")
    if model.g <= 0:
        raise ParameterError(f"{where}: g = {model.g} must be positive")


def design_channel(model: PlantModel, period_s: float = 0.002,
                   command_limit_pct: float = COMMAND_LIMIT_PCT, check: bool = True) -> ChannelDesign:
    """One channel's PI: the fastest of the SIMC family that keeps GM >= 2 at the boosted gain
    and PM >= 45° at the nominal and the boosted gain (see the module docstring). ``check``: the
    stated margins cross-checked by python-control (a rig's design checks its loops together
    instead)."""
    check_model(model)
    if not (0.0005 <= period_s <= 0.1):
        raise ParameterError(f"period = {period_s * 1e3:g} ms: it must be from 0.5 to 100 ms")
    g, tau = model.g, model.tau
    rho, notes = largest_gain_factor(model)
    theta = tau + period_s / 2
    def gains(lam: float) -> tuple[float, float]:
        return 1.0 / (g * (lam + theta)), 4.0 * (lam + theta)

    def meets(lam: float) -> bool:
        kp, ti = gains(lam)
        nominal = margins(kp, ti, g, tau, period_s, check=False)
        boosted = margins(kp, ti, g * rho, tau, period_s, check=False)
        return (min(nominal.gain_margin, boosted.gain_margin) >= GAIN_MARGIN_MIN
                and min(nominal.phase_margin_deg, boosted.phase_margin_deg) >= PHASE_MARGIN_MIN_DEG)

    # the margins grow with λ: bisect for the smallest λ that meets them
    lo, hi = LAMBDA_RANGE[0] * theta, LAMBDA_RANGE[1] * theta
    if not meets(hi):
        raise ParameterError(f"no PI of the SIMC family keeps a gain margin of {GAIN_MARGIN_MIN} at "
                             f"{rho:.1f}× the gain; check the model's boost")
    if meets(lo):
        hi = lo
    for _ in range(LAMBDA_BISECTIONS):
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if meets(mid) else (mid, hi)
    chosen = (hi, *gains(hi))
    lam, kp, ti = chosen
    return ChannelDesign(
        period_s=period_s, model_spec=model.spec, model_params=model.params(), kp_pct_per_kgf=kp,
        ti_s=ti, command_limit_pct=command_limit_pct, boost=rho, lambda_s=lam,
        nominal=margins(kp, ti, g, tau, period_s, check), boosted=margins(kp, ti, g * rho, tau, period_s, check),
        notes=notes)


@dataclass
class ControllerDesign:
    """A station's controller (module docstring): per channel its :class:`ChannelDesign`, the
    model's G, the feedback's mixing and the feedforward's mode, and the margins of the loops
    together."""

    names: list[str]
    G: np.ndarray                           #: the model's gain matrix, kgf/(%·s)
    channels: list[ChannelDesign]           #: per channel: its model, PI and one-loop margins
    period_s: float
    command_limit_pct: float = COMMAND_LIMIT_PCT
    feedback: str = "decoupled"             #: "decoupled" (M = Ĝ⁻¹·diag(ĝ)) or "independent" (M = I)
    feedforward: str = "rig"                #: "rig" (through G⁻¹), "channel" (each its own g) or "none"
    detuning: float = 1.0                   #: κ: every λ over its one-channel design's
    coupling_error: float = COUPLING_ERROR
    margins: list[LoopMargins] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @classmethod
    def of(cls, channel: ChannelDesign, name: str = STAND) -> "ControllerDesign":
        """One channel's controller as a station's of one channel (module docstring: N = 1):
        its model's g is G, M = 1, its feedforward its own model's (none for feedback alone)."""
        return cls([name], np.array([[channel.model.g]]), [channel], channel.period_s,
                   channel.command_limit_pct, "decoupled", "channel" if channel.feedforward else "none",
                   notes=list(channel.notes))

    @property
    def stand(self) -> bool:
        """A one-channel stand's controller (its file is the one-channel form)."""
        return self.names == [STAND]

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

    def hold_flows(self) -> np.ndarray:
        """The flows that hold every force against the trends, as the feedforward makes them:
        through G⁻¹ ``−G⁻¹Δ``, each channel's own ``−Δ_i/g_i``, none without a feedforward."""
        trends = np.array([c.model.delta for c in self.channels])
        if self.feedforward == "rig":
            return -np.linalg.solve(self.G, trends)
        if self.feedforward == "channel":
            return -trends / np.array([c.model.g for c in self.channels])
        return np.zeros(self.n)

    def loop(self) -> StationLoop:
        return StationLoop(self.G, np.array([c.model.tau for c in self.channels]),
                           np.array([c.kp_pct_per_kgf for c in self.channels]),
                           np.array([c.ti_s for c in self.channels]), self.period_s, self.decoupled)

    def worst(self, boosted: bool | None = None) -> LoopMargins | None:
        """The case with the smallest phase margin (among the boosted or nominal ones)."""
        cases = [m for m in self.margins if boosted is None or _boosted(m) == boosted]
        return min(cases, key=lambda m: (m.phase_margin_deg, m.gain_margin), default=None)

    def text(self) -> str:
        """What ``stand design`` prints: a one-channel stand's as one loop, a rig's with its G,
        its channels and the loops together."""
        if self.stand:
            return self.channels[0].text()
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
        if self.stand:
            return self.channels[0].to_dict()
        return {"schema": STATION_SCHEMA, "channels": self.names, "G": self.G.tolist(), "period_s": self.period_s,
                "command_limit_pct": self.command_limit_pct, "feedback": self.feedback,
                "feedforward": self.feedforward, "detuning": self.detuning,
                "coupling_error": self.coupling_error,
                "channel": {n: {"model": c.model_spec, "params": c.model_params,
                                "kp_pct_per_kgf": c.kp_pct_per_kgf, "ti_s": c.ti_s, "lambda_s": c.lambda_s,
                                "boost": c.boost} for n, c in zip(self.names, self.channels)},
                "margins": [m.to_dict() for m in self.margins], "notes": self.notes}

    def to_toml(self, path: str | Path | None = None) -> str:
        """The controller file (a one-channel stand's or a rig's, module docstring); ``path``:
        where it will be written (plug-in files are named relative to it)."""
        from plant.config import plugin_sources
        if self.stand:
            return self.channels[0].to_toml(path)
        here = Path(path).parent if path is not None else None
        sources: list[str] = []
        for c in self.channels:
            sources += [s for s in plugin_sources(c.model, here) if s not in sources]
        out = [f"# {STATION_SCHEMA}: a rig's force controller designed by `stand design` (edit with care:",
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


def _detuned(c: ChannelDesign, kappa: float, with_margins: bool = True) -> ChannelDesign:
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


def _loop(names, G, channels, period_s, decoupled) -> StationLoop:
    return StationLoop(G, np.array([c.model.tau for c in channels]),
                   np.array([c.kp_pct_per_kgf for c in channels]),
                   np.array([c.ti_s for c in channels]), period_s, decoupled)


def _case_margins(loop: StationLoop, cases, points: int, check: bool = False) -> list[LoopMargins]:
    """The margins of every case; ``check``: the closed loop's eigenvalues too (stable or not)."""
    return [loop.margins(f, label, e, points=points, check=check) for label, f, e in cases]


def _refuse_unstable(m: LoopMargins, loop: StationLoop, G: np.ndarray, spectrum: np.ndarray) -> None:
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
    """Refuse a station's model a controller cannot be designed from: non-finite or
    non-positive values, a singular G."""
    G = model.G
    if not np.all(np.isfinite(G)):
        raise ParameterError(f"{where}: G has a value that is not a finite number")
    for name, m in zip(model.names, model.channels):
        check_model(m, where if model.n == 1 else f"{where}: channel {name}")
    cond = np.linalg.cond(G)
    if not math.isfinite(cond) or cond > 1e8:
        raise ParameterError(f"{where}: G is singular (condition number {cond:.3g}): some load "
                             "pattern cannot be made by any valve commands; check the rig model")


def design(model: PlantModel | RigModel, period_s: float = 0.002,
           command_limit_pct: float = COMMAND_LIMIT_PCT, feedback: str = "decoupled",
           feedforward: str | None = None, coupling_error: float = COUPLING_ERROR) -> ControllerDesign:
    """The station's controller (module docstring) for its model: a rig's, or one channel's
    (a one-channel stand, its channel :data:`~loading.programme.STAND`). ``feedback``:
    ``decoupled`` or ``independent``; ``feedforward``: ``rig`` (through G⁻¹) or ``channel`` (each
    channel's own g; default: ``rig`` for several channels with decoupled feedback, else
    ``channel``: today's controller per channel, and one channel's own). Raises
    :class:`~core.errors.ParameterError` with the figure when the coupling is too strong for the
    feedback."""
    if isinstance(model, PlantModel):
        model = RigModel([model], np.array([[model.g]]), [STAND])
    if feedback not in FEEDBACKS:
        raise ParameterError(f"feedback {feedback!r}: it is one of {', '.join(FEEDBACKS)}")
    feedforward = feedforward or ("rig" if feedback == "decoupled" and model.n > 1 else "channel")
    if feedforward not in FEEDFORWARDS:
        raise ParameterError(f"feedforward {feedforward!r}: it is one of {', '.join(FEEDFORWARDS)}")
    if not (0.0 <= coupling_error < 1.0):
        raise ParameterError(f"coupling error {coupling_error}: it must be from 0 to 1 (a share)")
    check_rig_model(model, "model" if model.names == [STAND] else "rig model")
    G = np.array(model.G, float)
    names = list(model.names)
    one = []
    for name, m in zip(names, model.channels):
        try:
            one.append(design_channel(m, period_s, command_limit_pct, check=model.n == 1))
        except ParameterError as exc:
            raise ParameterError(exc if model.n == 1 else f"channel {name}: {exc}") from None
    boosts = [c.boost for c in one]
    cases = margin_cases(boosts, names, coupling_error)
    notes = [f"{name}: {n}" for name, c in zip(names, one) for n in c.notes]
    decoupled = feedback == "decoupled"
    spectrum = np.sort(np.linalg.eigvals(G / np.diag(G)[None, :]).real)
    kappa = 1.0
    if decoupled and model.n > 1:            # one loop: the channel's design meets them
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
    return ControllerDesign(names, G, channels, period_s, command_limit_pct, feedback, feedforward,
                            kappa, coupling_error, stated, notes)


