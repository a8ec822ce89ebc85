r"""A force controller designed from the identified model: feedforward plus PI feedback.

The loop, at the control period ``T``: the force ``y_k`` is read at SYNC k and the command
``u_k`` applies from then to the next SYNC; the model's delay ``τ = (m + f)·T`` and integrator
give, exactly in discrete time (zero-order hold, no Padé approximation),

.. math::  P(z) = \frac{Y}{U} = g\,T\,\frac{(1 - f)\,z + f}{z^{m+1}\,(z - 1)} .

The feedback is a PI with the integral updated before use,

.. math::  C(z) = K_p\left(1 + \frac{T}{T_i}\,\frac{z}{z - 1}\right),

from the SIMC family for an integrating process with dead time θ = τ + T/2:
``K_p = 1/(g·(λ + θ))``, ``T_i = 4·(λ + θ)``. The closed-loop time constant λ is the smallest (by
bisection) for which the loop keeps a **gain margin ≥ 2 at the largest gain the model predicts**
(``g·ρ``: the reversal boost right after a rod reversal, ``ρ = 1 + b`` at ``|q| = u_ref``, times
``1 + |a|`` of an asymmetry) and a **phase margin ≥ 45°** at both the nominal and the boosted
gain. The gain margin is how far the plant's gain may rise before the loop oscillates, so this
is what keeps the paper's self-oscillation after reversals away.

Margins come from python-control (``stability_margins(method='frd')`` on the loop's dense
frequency response) and are cross-checked on a dense grid computed here; the printout gives the
crossover, gain and phase margins and the peak sensitivity ``Ms = max |1/(1 + L)|`` at both
gains. The tracking itself comes from the feedforward (:mod:`loading.feedforward`); the
feedback handles what the model does not know.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from core.errors import ParameterError
from plant import PlantModel
from plant.params import ModelError

#: required margins
GAIN_MARGIN_MIN = 2.0
PHASE_MARGIN_MIN_DEG = 45.0
#: the closed-loop time constants searched, as multiples of the dead time θ, and the steps
LAMBDA_RANGE = (0.25, 40.0)
LAMBDA_BISECTIONS = 14
#: the loop's command limit (%) unless given
COMMAND_LIMIT_PCT = 100.0
SCHEMA = "hydrostand-controller/1"


@dataclass
class Margins:
    """Stability margins of one loop gain."""

    gain: float                 #: the plant gain the loop was evaluated at, kgf/(%·s)
    crossover_hz: float
    gain_margin: float
    phase_margin_deg: float
    peak_sensitivity: float     #: Ms = max |1/(1 + L)|
    #: the same margins from python-control's stability_margins (cross-check)
    control_gain_margin: float = math.nan
    control_phase_margin_deg: float = math.nan

    def text(self, label: str) -> str:
        return (f"{label:<8} g = {self.gain:7.1f} kgf/(%·s): crossover {self.crossover_hz:6.3f} Hz, "
                f"gain margin {self.gain_margin:5.2f}, phase margin {self.phase_margin_deg:5.1f}°, "
                f"Ms {self.peak_sensitivity:4.2f}")


@dataclass
class ControllerDesign:
    """A controller file's content: the model, the loop period and the PI gains."""

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


def plant_tf(g: float, tau: float, period_s: float):
    """P(z) of the loop as a python-control transfer function (see the module docstring)."""
    import control
    whole = tau / period_s
    m = int(math.floor(whole + 1e-9))
    f = whole - m
    den = np.polymul(np.r_[1.0, np.zeros(m + 1)], [1.0, -1.0])      # z^(m+1)·(z − 1)
    num = g * period_s * np.array([1.0 - f, f])
    return control.tf(num, den, period_s)


def pi_tf(kp: float, ti: float, period_s: float):
    import control
    a = period_s / ti
    return control.tf([kp * (1 + a), -kp], [1.0, -1.0], period_s)


def _frequency_response(kp: float, ti: float, g: float, tau: float, T: float, w: np.ndarray) -> np.ndarray:
    z = np.exp(1j * w * T)
    whole = tau / T
    m = math.floor(whole + 1e-9)
    f = whole - m
    P = g * T * ((1 - f) * z + f) / (z ** (m + 1) * (z - 1))
    C = kp * (1 + (T / ti) * z / (z - 1))
    return C * P


def margins(kp: float, ti: float, g: float, tau: float, period_s: float, check: bool = True,
            points: int = 20000) -> Margins:
    """Margins of the loop on a dense frequency grid up to Nyquist; with ``check``, python-
    control's ``stability_margins(method='frd')`` beside them (on every 5th point)."""
    w = np.geomspace(1e-3, math.pi / period_s * 0.9999, points)
    L = _frequency_response(kp, ti, g, tau, period_s, w)
    mag = np.abs(L)
    phase = np.unwrap(np.angle(L))
    cross = np.flatnonzero((mag[:-1] >= 1) & (mag[1:] < 1))
    if len(cross):
        k = cross[0]
        wc = float(w[k])
        pm = math.degrees(phase[k]) + 180.0
        pm = (pm + 180.0) % 360.0 - 180.0
    else:
        wc, pm = math.nan, math.inf
    turns = np.flatnonzero(np.diff(np.floor((phase + math.pi) / (2 * math.pi))) != 0)
    gm = min((1 / mag[k] for k in turns), default=math.inf)
    ms = float(np.max(1 / np.abs(1 + L)))
    out = Margins(g, wc / (2 * math.pi), float(gm), float(pm), ms)
    if check:
        import control
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            frd = control.frd(L[::5], w[::5])
            cgm, cpm, *_ = control.stability_margins(frd, method="frd")
        out.control_gain_margin = float(cgm) if cgm is not None else math.inf
        out.control_phase_margin_deg = float(cpm) if cpm is not None else math.inf
    return out


def proportional(kp_pct_per_kgf: float, model: PlantModel, period_s: float = 0.002) -> ControllerDesign:
    """A P controller without feedforward (the paper's ``u = k·(r − y)``), for comparisons."""
    rho, notes = largest_gain_factor(model)
    return ControllerDesign(period_s, model.spec, model.params(), kp_pct_per_kgf, math.inf,
                            boost=rho, feedforward=False,
                            nominal=margins(kp_pct_per_kgf, math.inf, model.g, model.tau, period_s),
                            boosted=margins(kp_pct_per_kgf, math.inf, model.g * rho, model.tau, period_s),
                            notes=notes)


def critical_p_gain(g: float, tau: float, period_s: float) -> float:
    """The P gain (%/kgf) at which the loop with plant gain ``g`` reaches its stability limit."""
    return margins(1.0, math.inf, g, tau, period_s, check=False).gain_margin


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


def design(model: PlantModel, period_s: float = 0.002,
           command_limit_pct: float = COMMAND_LIMIT_PCT, check: bool = True) -> ControllerDesign:
    """The fastest PI of the SIMC family that keeps GM >= 2 at the boosted gain and PM >= 45°
    at the nominal and the boosted gain (see the module docstring). ``check``: the stated
    margins cross-checked by python-control (a rig's design checks its loops together instead,
    :mod:`loading.rig_design`)."""
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
    return ControllerDesign(
        period_s=period_s, model_spec=model.spec, model_params=model.params(), kp_pct_per_kgf=kp,
        ti_s=ti, command_limit_pct=command_limit_pct, boost=rho, lambda_s=lam,
        nominal=margins(kp, ti, g, tau, period_s, check), boosted=margins(kp, ti, g * rho, tau, period_s, check),
        notes=notes)


def load_controller(path: str | Path, period_s: float | None = None) -> ControllerDesign:
    """A controller file, validated: its period must be the loop's (if given), every value finite."""
    from plant.config import load_named_plugins, read_toml
    path = Path(path)
    try:
        data = read_toml(path)
    except ModelError as exc:
        raise ParameterError(str(exc)) from None
    try:
        loop, fb, mdl = data["loop"], data["feedback"], dict(data["model"])
        spec = mdl.pop("spec")
        load_named_plugins({"plugins": mdl.pop("plugins", [])}, f"{path} [model]", path.parent)
        c = ControllerDesign(period_s=float(loop["period_s"]), model_spec=str(spec),
                             model_params={k: float(v) for k, v in mdl.items()},
                             kp_pct_per_kgf=float(fb["kp_pct_per_kgf"]), ti_s=float(fb["ti_s"]),
                             command_limit_pct=float(loop.get("command_limit_pct", COMMAND_LIMIT_PCT)),
                             feedforward=bool(loop.get("feedforward", True)),
                             boost=float(data.get("design", {}).get("boost", 1.0)),
                             lambda_s=float(data.get("design", {}).get("lambda_s", math.nan)))
    except KeyError as exc:
        raise ParameterError(f"{path}: no {exc.args[0]!r}; a controller file has [loop] period_s, "
                             "[feedback] kp_pct_per_kgf and ti_s, [model] spec and its parameters "
                             "(write one with `stand design MODEL.toml -o FILE`)") from None
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{path}: a value is not a number ({exc})") from None
    try:
        needed = set(PlantModel.from_spec(c.model_spec).params())
    except ModelError as exc:
        raise ParameterError(f"{path}: {exc}") from None
    missing = sorted(needed - set(c.model_params))
    if missing:
        raise ParameterError(f"{path}: [model] lacks {', '.join(missing)} of {c.model_spec}; every "
                             "parameter of the model must be given (stand design writes them all)")
    for name, v in (("period_s", c.period_s), ("kp_pct_per_kgf", c.kp_pct_per_kgf), ("ti_s", c.ti_s),
                    ("command_limit_pct", c.command_limit_pct)):
        if not (v > 0 and (math.isfinite(v) or name == "ti_s" and v == math.inf)):
            raise ParameterError(f"{path}: {name} = {v} must be a positive finite number")
    if c.command_limit_pct > 100:
        raise ParameterError(f"{path}: command_limit_pct = {c.command_limit_pct} is over 100 %")
    try:
        check_model(c.model, str(path))
    except ModelError as exc:
        raise ParameterError(f"{path}: {exc}") from None
    if period_s is not None and abs(c.period_s - period_s) > 1e-9:
        raise ParameterError(f"{path} was designed for a period of {c.period_s * 1e3:g} ms but the loop "
                             f"runs at {period_s * 1e3:g} ms; design it again with "
                             f"`stand design MODEL --period-ms {period_s * 1e3:g}`")
    return c
