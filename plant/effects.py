r"""The catalogue of physical effects that can be added to the paper's base model.

The base model (paper, eq. 1, with the constant trend of eq. 2) is

.. math::  \dot y(t) = g\,u(t-\tau) + \Delta

with the force ``y`` in kgf, the valve command ``u`` in % (±100 % = ±10 V), the gain ``g`` in
kgf/(%·s), the transport delay ``τ`` in s and the trend ``Δ`` in kgf/s. Effects refine it at one of
five places of the signal path, applied in this order::

    u(t-τ) ─▶ VALVE (spool/flow command q) ─▶ FLOW (gain factors on g·q) ─▶ Σ ─▶ ∫ ─▶ y ─▶ SENSOR ─▶ y_m
                                                   DISTURBANCE, FORCE (rate terms) ─┘

so the complete rate law is

.. math::  \dot y = g\,q\,\prod_i G_i(q, y, t) + \Delta + \sum_j D_j(y, t).

Adding an effect = one class here (subclass :class:`Effect`, declare ``name``, ``stage``,
``params`` and implement the stage's hook) decorated with :func:`register`. Parameters are
declared with :class:`~plant.params.Param`, so the fit, the TOML loader and the CLI pick them up.
Every hook works on arrays of shape ``(n, K)``: ``n`` independent trajectories (simulation
windows) by ``K`` time steps, carrying its state between blocks, so the emulator (``K`` small, one
block per control period) and the analysis (whole records, windows side by side) run the same code.
"""
from __future__ import annotations

import enum
import functools
import math
from typing import Any, ClassVar, Mapping

import numpy as np
from scipy.linalg import expm
from scipy.ndimage import maximum_filter1d, minimum_filter1d
from scipy.signal import lfilter, ss2tf

from .evidence import AMBIGUITY_RATIO, BASE_LOOK_ALIKES, Ambiguity, Evidence, separating_experiment
from .params import ModelError, Param
from .start_grids import and_less_delay, generic_starts, renamed, warming_starts


class Stage(enum.IntEnum):
    """Where in the signal path an effect acts (also the order of application)."""

    VALVE = 1        #: transforms the delayed command into the flow command q (%)
    FLOW = 2         #: multiplies the flow-driven force rate g·q by a factor
    DISTURBANCE = 3  #: adds a force rate that depends on time only
    FORCE = 4        #: adds a force rate that depends on the force itself
    SENSOR = 5       #: filters what the dynamometer reports (the force rate it sees)


CATALOGUE: dict[str, type["Effect"]] = {}


def register(cls: type["Effect"]) -> type["Effect"]:
    """Class decorator: add an effect to the catalogue under ``cls.name`` (see
    :mod:`plant.plugins` for effects of one's own)."""
    name = getattr(cls, "name", None)
    if CATALOGUE.get(name) is cls:
        return cls
    if name == "base":
        raise ModelError("effect name 'base' is the base model's: choose another name")
    if name in CATALOGUE:
        raise ModelError(f"effect name {name!r} is already taken by {CATALOGUE[name].__name__} "
                         f"({CATALOGUE[name].summary or 'see stand effects'}): choose another name")
    CATALOGUE[name] = cls
    return cls


class Effect:
    """Base class of every effect. Subclasses document physics and equation in their docstring."""

    name: ClassVar[str]
    stage: ClassVar[Stage]
    params: ClassVar[tuple[Param, ...]]
    #: one line for listings (``stand effects``)
    summary: ClassVar[str] = ""
    #: what tells it apart from the explanations it looks like: ``{other: experiment}``, with
    #: ``other`` an effect's name or the base model's ``gain``, ``delay`` or ``trend``; the
    #: diagnosis names the experiment when the data do not separate the two
    look_alikes: ClassVar[Mapping[str, str]] = {}
    #: ``(look-alike, how)``: at a single command amplitude this effect looks exactly like
    #: the look-alike (``gain``: "a dead zone d only lowers the slope to g·(|u| − d)")
    at_one_amplitude: ClassVar[tuple[str, str] | None] = None
    #: True if the rate term needs the current force (forces step-by-step integration)
    depends_on_force: ClassVar[bool] = False
    #: False for effects that are not plant physics (disturbances): ``stand diagnose`` does not
    #: offer them as explanations, so structure they would absorb is reported as unexplained.
    diagnosable: ClassVar[bool] = True
    #: True if :meth:`prepare` reads the undelayed command (``command=`` keyword): the force then
    #: depends on a command before the delay has passed (no look-ahead over the delay)
    reads_command: ClassVar[bool] = False
    #: False if the reading is not affine in g and Δ with the other parameters fixed (a play),
    #: so the fit cannot solve g and Δ from one simulation
    linear_in_gain: ClassVar[bool] = True
    #: True if :meth:`shape` or :meth:`prepare` reads the time since the run started (``t=``
    #: keyword, (n, K): the start of every step; a record's time counts from its first sample)
    reads_time: ClassVar[bool] = False

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Starts of the fit's local searches for this effect: ``[{"name.param": value}]``.

        ``s`` summarises the data (``dt``, ``u_abs_levels``, ``u_abs_max``, ``y_abs_max``,
        ``y_span``, ``duration_s``, and what the residual of the model without this effect
        shows: ``residual_periodic(carrier)``, its dominant sinusoid read as the force, its
        rate or its rate over the flow), ``base`` is the base fit. The default
        (:func:`plant.start_grids.generic_starts`): each parameter's default and values across
        its bounds, and a parameter in Hz (kgf) also at the residual's dominant frequency
        (amplitude), read where this effect acts.
        """
        return generic_starts(cls.name, cls.params, s, cls.stage)

    @classmethod
    def ambiguities(cls, ev: Evidence) -> list[Ambiguity]:
        """What these data cannot tell apart from this effect, with the experiment that would
        (the diagnosis asks every effect; ``ev`` says which were tried and which is best). The
        default: when it was tried on square waves of a single amplitude, its
        :attr:`at_one_amplitude` look-alike. Override to add the effect's own rules."""
        ex = ev.excitation
        if cls.at_one_amplitude is None or not ex.single_amplitude or cls.name not in ev.tried:
            return []
        other, how = cls.at_one_amplitude
        return [Ambiguity([cls.name, other],
                          f"at a single command amplitude (|u| = {ex.levels[0]:g} %) {how}: it "
                          f"looks exactly like {BASE_LOOK_ALIKES.get(other, '+' + other)}.",
                          separating_experiment(cls.name, other))]

    def __init__(self, **values: float) -> None:
        known = {p.name: p for p in self.params}
        unknown = set(values) - set(known)
        if unknown:
            raise ModelError(
                f"effect {self.name!r} has no parameter(s) {', '.join(sorted(unknown))}; "
                f"it has: {', '.join(known) or 'none'}")
        self.values: dict[str, float] = {
            p.name: p.validate(values.get(p.name, p.default), self.name) for p in self.params}

    def __getattr__(self, item: str) -> float:
        values = self.__dict__.get("values")
        if values is not None and item in values:
            return values[item]
        raise AttributeError(item)

    def __repr__(self) -> str:
        inner = ", ".join(f"{k}={v:g}" for k, v in self.values.items())
        return f"{type(self).__name__}({inner})"

    # -- state carried between blocks -------------------------------------------------------
    def init_state(self, n: int, u0: np.ndarray) -> dict[str, np.ndarray]:
        """State at the start; ``u0`` (n,) is the command held before (the system is at rest
        with respect to it: a lagged spool sits at it, a moving rod moves its way)."""
        return {}

    # -- stage hooks (override the one for your stage) ----------------------------------------
    def shape(self, q: np.ndarray, dt: float, state: dict, t: np.ndarray | None = None) -> np.ndarray:
        """VALVE stage: map the command block ``q`` (n, K) to the new flow command (effects
        that declare ``reads_time`` also get the steps' times ``t`` since the run began)."""
        raise NotImplementedError

    def prepare(self, q: np.ndarray, dt: float, state: dict, command: np.ndarray | None = None,
                t: np.ndarray | None = None) -> Any:
        """FLOW stage, input side: anything that depends only on the flow-command history
        (returned as ``aux`` of shape (n, K) and handed to :meth:`gain`). Effects that declare
        ``reads_command`` also get the undelayed ``command`` of the same steps, those that
        declare ``reads_time`` the time ``t`` of the steps' starts since the run began."""
        return None

    def gain(self, q: np.ndarray, aux: Any, y: np.ndarray) -> np.ndarray:
        """FLOW stage: multiplicative factor on g·q, same shape as ``q``."""
        raise NotImplementedError

    def disturbance(self, t: np.ndarray, dt: float) -> np.ndarray:
        """DISTURBANCE stage: additive force rate (kgf/s), averaged over the steps that start
        at times ``t`` (s) and last ``dt``."""
        raise NotImplementedError

    def force_rate(self, y: np.ndarray) -> np.ndarray:
        """FORCE stage: additive force rate (kgf/s) as a function of the force ``y`` (kgf)."""
        raise NotImplementedError

    # -- what the controller design asks of an effect ------------------------------------------
    def largest_gain_factor(self) -> float:
        """The largest factor this effect puts on the plant's gain at a command of ±10 %, for
        the controller design, which keeps its margins at ``g`` times the product of these
        (:mod:`loading.design`). FLOW effects: :meth:`gain` probed along a ±10 % square wave
        with a reversal every 0.2 s, at forces across ±5000 kgf (right after a reversal for a
        boost, in the faster direction for an asymmetry); others: 1. Override with a closed
        form where there is one."""
        if self.stage is not Stage.FLOW:
            return 1.0
        dt, k = 0.002, 1000
        t = np.arange(k) * dt
        q = np.where((t // 0.2) % 2 == 0, 10.0, -10.0)[None, :]
        forces = np.linspace(-5000.0, 5000.0, 5)
        state = self.init_state(1, q[:, 0].copy())
        extra = {"t": t[None, :]} if self.reads_time else {}
        if self.reads_command:
            extra["command"] = q
        aux = self.prepare(q.copy(), dt, state, **extra)
        g = [np.asarray(self.gain(q, aux, np.full_like(q, y)), float) for y in forces]
        return float(max(1.0, np.nanmax(np.abs(g))))

    def invert(self, q: np.ndarray, dt: float) -> np.ndarray | None:
        """VALVE stage: the command that makes this effect give the flow command ``q`` (one
        record, (K,)), for the feedforward (:mod:`loading.feedforward`); None when there is no
        inverse (the feedback handles what the effect does)."""
        return None

    def decay_rate(self) -> float | None:
        """FORCE stage: if :meth:`force_rate` is ``-λ·y``, return λ (enables exact fast
        integration); otherwise None."""
        return None

    def filter_rate(self, rate: np.ndarray, dt: float, state: dict) -> np.ndarray:
        """SENSOR stage: the rate of the reading over each step, from the force rate ``rate``
        (n, K); ``state`` carries the filter between blocks (empty: start settled on the first
        step's rate)."""
        raise NotImplementedError

    def filter_states(self, rate: np.ndarray, dt: float, steps: np.ndarray) -> dict:
        """SENSOR stage: the filter's state (for :meth:`filter_rate`) at the start of the given
        ``steps`` of one continuous rate record ``rate`` (1, K), started settled: the state of
        each window cut from it."""
        raise NotImplementedError

    def force_minus_reading(self, state: dict) -> np.ndarray:
        """SENSOR stage: the force minus the reading for the filter's ``state`` (what a window
        starting from a reading must add to start from the force)."""
        raise NotImplementedError


def warming(t: np.ndarray, dt: float, T: float) -> np.ndarray:
    r"""The step average of :math:`W(t) = T\,(1 - e^{-t/T})` over ``[t, t + dt]``: how far a
    first-order warm-up with time constant ``T`` has gone, in units of its initial rate (``t``
    for ``T`` much longer than ``t``)."""
    mean_decay = np.exp(-t / T) * (-math.expm1(-dt / T) * T / dt)
    return T * (1.0 - mean_decay)


#: the thermal time constant of the effects that drift from the start of a run
WARMING_TIME_CONSTANT = Param("time_constant", 600.0, 1.0, 1e5, "s",
                              "thermal time constant T (much longer than a run: a linear drift)",
                              log=True)


# ------------------------------------------------------------------------------------------
# VALVE stage
# ------------------------------------------------------------------------------------------
@register
class NullDrift(Effect):
    r"""The valve's null drifts during a run: the spool's zero-flow position moves as the valve
    warms up.

    Physics: a servo-valve's null (the command at which no oil flows) shifts with the
    temperature of its torque motor and of the oil, and with the supply pressure; from the
    start of a run it moves toward its warm value with the thermal time constant ``T``. The
    constant part of the null offset is the base model's trend Δ; the drift adds to the spool
    a command offset that grows from zero, with ``b`` its initial rate and ``t`` the time
    since the run began (a record's first sample):

    .. math::  q = u(t-\tau) + b\,T\,(1 - e^{-t/T}),

    averaged exactly over each step (for ``T`` much longer than the run, ``b·t``). Seen in
    data as a force trend that changes during every run the same way: the same extra kgf/s
    at every command level, in both directions and at a held zero command (a drifting gain
    scales with |u| and changes sign with the direction).
    """

    name = "null_drift"
    stage = Stage.VALVE
    summary = "valve null drifting during a run (warming): q = u + b·T·(1 − exp(−t/T))"
    look_alikes = {
        "gain_drift": (
            "the meander at two amplitudes (e.g. 5 and 20 %), or holds at zero command early and "
            "late in a run: a drifting null adds the same kgf/s at every command and at zero, a "
            "drifting gain scales with |u|"),
        "trend": (
            "one long run, or holds at zero command at its start and its end: the trend Δ is the "
            "same throughout, a drifting null moves it during the run"),
    }
    reads_time = True
    params = (Param("rate", 0.002, -0.1, 0.1, "%/s",
                    "initial rate b of the null's drift (command % per second)"),
              WARMING_TIME_CONSTANT)

    def shape(self, q, dt, state, t=None):
        return q + self.rate * warming(t, dt, self.time_constant)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """The null moving by 0.05-0.5 % command over a run."""
        return warming_starts(cls.name, (-0.5, -0.1, -0.03, 0.03, 0.1, 0.5), 0.1, s)


def first_order_step_average(v: np.ndarray, dt: float, T: float, state: dict) -> np.ndarray:
    """A first-order lag ``T·ẋ = v − x`` driven by ``v`` (n, K) held over each step: the step
    average of ``x`` (exact for an integrator that follows). ``state["x"]`` (n,) is ``x`` at the
    block's start, and is advanced to its end; without it ``x`` starts settled on ``v[:, 0]``."""
    x0 = state.get("x")
    x_start, x_end = first_order_states(v, dt, T, v[:, 0].copy() if x0 is None else x0)
    state["x"] = x_end
    c = T / dt * (1.0 - math.exp(-dt / T))  # step-average weight of the initial deviation
    return v + (x_start - v) * c


def first_order_states(v: np.ndarray, dt: float, T: float,
                       x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The state of ``T·ẋ = v − x`` at the start of each step (n, K), from ``x0`` (n,), with
    ``v`` held over each step; and the state at the end of the last step (n,)."""
    a = math.exp(-dt / T)
    # x_{k+1} = a x_k + (1-a) v_k  (x_k is the state at the step start)
    x_next, _ = lfilter([1.0 - a], [1.0, -a], v, axis=1, zi=(a * x0)[:, None])
    return np.concatenate([x0[:, None], x_next[:, :-1]], axis=1), x_next[:, -1].copy()


@register
class Lag(Effect):
    r"""First-order lag of the spool/actuator, in series with the transport delay.

    Physics: the spool of a servo-valve (and the oil column) does not follow the command
    instantly; a first-order approximation of the spool position loop gives

    .. math::  T_v\,\dot q = u(t-\tau) - q .

    Discretized exactly for a command held over each step; the flow command used over the step
    is the step average of ``q`` (exact for the integrator that follows). Seen in data as a
    rounded corner after each command step that a pure delay cannot produce; from one excitation
    frequency, lag and delay are hard to tell apart (both are a phase lag).
    """

    name = "lag"
    stage = Stage.VALVE
    summary = "first-order valve/actuator lag T_v (besides the delay)"
    look_alikes = {
        "delay": (
            "a meander (step commands) or P-feedback at several reference frequencies: a lag "
            "rounds the corners and its phase grows less than linearly with frequency; a delay "
            "only shifts"),
        "sensor_lag": (
            "the dynamometer's own filter setting (its configuration or data sheet) or a second "
            "force measurement; in a linear plant nothing on the command side separates them, "
            "behind a valve nonlinearity (dead zone, flow limit, reversal boost) meanders at "
            "amplitudes near it can"),
    }
    params = (Param("time_constant", 0.03, 1e-4, 2.0, "s", "spool/actuator time constant T_v",
                    log=True),)

    def init_state(self, n, u0):
        return {"x": np.array(u0, float)}

    def shape(self, q, dt, state):
        return first_order_step_average(q, dt, self.time_constant, state)

    def invert(self, q, dt):
        """u = q + T_v·dq/dt: the lag's inverse (a lead)."""
        return q + self.time_constant * np.gradient(q, dt)

    @classmethod
    def ambiguities(cls, ev: Evidence) -> list[Ambiguity]:
        ex = ev.excitation
        out = []
        if ex.continuous and not ex.has_steps and cls.name in ev.tried and ev.best != "lag":
            what = ("a smooth single-frequency signal" if ex.single_frequency
                    else "smooth, without steps")
            out.append(Ambiguity(["lag", "delay"],
                                 f"the command is {what}: a valve lag T shifts a slow command "
                                 f"like extra delay, so mainly τ + T is determined (fitted τ = "
                                 f"{ev.base['tau'] * 1e3:.1f} ms may include a lag).",
                                 separating_experiment("lag", "delay")))
        if ev.best in ("lag", "sensor_lag"):
            other = "sensor_lag" if ev.best == "lag" else "lag"
            alt = ev.errors.get(other)
            if alt is None or alt <= AMBIGUITY_RATIO * ev.errors[ev.best]:
                out.append(Ambiguity(
                    [ev.best, other],
                    "a first-order filter in the dynamometer acts on the measured force exactly "
                    "like a valve lag on an integrating plant (the two commute), in open and "
                    "closed loop alike, unless a valve nonlinearity sits between them: these "
                    "data cannot tell where the lag is.", separating_experiment("lag", "sensor_lag")))
        return out

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        out = []
        for T in (1e-4, 2 * s.dt, 0.01, 0.03, 0.1, 0.3):
            T = max(T, 1.1e-4)
            out += and_less_delay({"lag.time_constant": T}, base, T)
        return out


@functools.lru_cache(maxsize=256)
def second_order_step_average_filter(frequency: float, damping: float,
                                     dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(b, a)`` of the discrete filter from a command held over each step to the step
    average of ``x`` in ``ẍ + 2ζω ẋ + ω² x = ω² v`` (ω = 2π·frequency): the exact zero-order
    hold discretization, with the running integral of ``x`` as a third state (Van Loan).
    Cached: it costs ~0.7 ms (expm, ss2tf), and the emulator asks for it every control period
    with the same values; callers must not modify the arrays."""
    w = 2 * math.pi * frequency
    m = np.zeros((4, 4))
    m[0, 1] = 1.0
    m[1, 0], m[1, 1], m[1, 3] = -w * w, -2 * damping * w, w * w
    m[2, 0] = 1.0                            # the integral of x
    e = expm(m * dt)
    phi, gam = e[:2, :2], e[:2, 3]
    c, d = e[2, :2] / dt, e[2, 3] / dt       # step average = (∫ over the step) / dt
    b, a = ss2tf(phi, gam[:, None], c[None, :], np.array([[d]]))
    return np.ravel(b), np.ravel(a)

@register
class Resonance(Effect):
    r"""A second-order valve/actuator: the flow rings after a command step.

    Physics: the oil column in the cylinder is a spring (bulk modulus over the chamber volume)
    that carries the piston, rod and fixture; with the servo-valve's own spool dynamics it makes
    the hydraulic natural frequency ``f_n`` (a few Hz to some tens of Hz on a loading stand),
    lightly damped by leakage and friction. A servo-valve data sheet gives its response the
    same way (the frequency at 90° phase, and a damping). The flow command follows the delayed
    command through

    .. math::  \ddot q + 2\zeta\omega_n \dot q + \omega_n^2 q = \omega_n^2\,u(t-\tau),
               \qquad \omega_n = 2\pi f_n,

    discretized exactly for a command held over each step (the flow used over a step is its
    step average). Seen in data as a force rate that overshoots after each command step and
    rings at about ``f_n·√(1−ζ²)`` (a relay loop oscillates faster and with bumps, a harmonic
    reference shows a resonant peak); a lag cannot overshoot. Well damped (ζ ≳ 1) it is a lag
    of ``2ζ/ω_n``, and far above the excitation only a delay of ``2ζ/ω_n``. The valve starts
    settled on the command held before.
    """

    name = "resonance"
    stage = Stage.VALVE
    summary = "second-order valve/actuator: natural frequency f_n, damping ζ (the flow rings)"
    look_alikes = {
        "lag": (
            "a meander (command steps) at a small amplitude, or P-feedback at reference "
            "frequencies up to the suspected f_n: a lag never overshoots, a resonance rings after "
            "each step and peaks near f_n"),
        "delay": (
            "P-feedback at several reference frequencies, up to a third of the sample rate: far "
            "below f_n a resonance only adds the delay 2ζ/ω_n, near it the phase and gain change "
            "fast"),
    }
    params = (Param("frequency", 10.0, 0.3, 200.0, "Hz", "natural frequency f_n", log=True),
              Param("damping", 0.5, 0.05, 5.0, "1",
                    "damping ratio ζ (a hydraulic actuator 0.05-0.3, a servo-valve 0.5-1)", log=True))

    def init_state(self, n, u0):
        past = np.repeat(np.array(u0, float)[:, None], 2, axis=1)
        return {"v": past, "q": past.copy()}       # the last two inputs and outputs, oldest first

    def shape(self, q, dt, state):
        b, a = second_order_step_average_filter(self.frequency, self.damping, dt)
        v1, v2 = state["v"][:, 1], state["v"][:, 0]   # x[-1], x[-2]
        y1, y2 = state["q"][:, 1], state["q"][:, 0]
        zi = np.stack([b[1] * v1 + b[2] * v2 - a[1] * y1 - a[2] * y2,
                       b[2] * v1 - a[2] * y1], axis=1)       # scipy.signal.lfiltic, per row
        out, _ = lfilter(b, a, q, axis=1, zi=zi)
        state["v"] = np.concatenate([state["v"], q], axis=1)[:, -2:].copy()
        state["q"] = np.concatenate([state["q"], out], axis=1)[:, -2:].copy()
        return out

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Natural frequencies of 2-30 Hz (below Nyquist), lightly to well damped; the step
        response's mean lag 2ζ/ω has gone into the base fit's τ, so each also starts without it."""
        out = []
        nyquist = 0.5 / s.dt
        for f in (2.0, 6.0, 15.0, 30.0):
            for zeta in (0.15, 0.4, 1.0):
                if f < nyquist:
                    out += and_less_delay({"resonance.frequency": f, "resonance.damping": zeta},
                                           base, 2 * zeta / (2 * math.pi * f))
        return out


@register
class Slew(Effect):
    r"""The spool cannot move faster than a largest speed: large command steps become ramps.

    Physics: the first stage of a two-stage servo-valve drives the spool with a limited flow
    (and a drive amplifier with a limited current or a set ramp), so the spool's speed has a
    ceiling ``R``; a data sheet shows it as a large-signal step response that takes longer than
    the small-signal one (e.g. 0 → 100 % in 25 ms: R = 4000 %/s). The spool position ``x`` is
    the command passed through a rate limit,

    .. math::  \dot x = \operatorname{clip}\big(\ldots,\ -R,\ R\big):\quad
               x \text{ follows } u(t-\tau) \text{ at once, at most at speed } R,

    and the flow over a step is its step average (exact: the ramp ends inside the step where it
    reaches the command). Seen in data as a corner after each large command step that is
    rounded for ``|Δu|/R``, longer for larger steps (a lag rounds every step in the same time
    constant, a delay shifts it): a meander's ramp starts late by ``|Δu|/(2R)``, twice as late at
    twice the amplitude. A command that changes by less than ``R·dt`` a step is reached
    within each step. The spool starts on the command held before.
    """

    name = "slew"
    stage = Stage.VALVE
    summary = "spool speed limit R: a command step of Δu becomes a ramp lasting |Δu|/R"
    look_alikes = {
        "lag": (
            "the meander at several amplitudes (e.g. 5 and 20 %): a speed limit rounds a step for "
            "|Δu|/R, four times as long at four times the step, a lag for the same time constant "
            "at every step"),
        "delay": (
            "the meander at several amplitudes: a speed-limited spool reaches the flow |Δu|/(2R) "
            "late, later for larger steps; a delay is the same at every amplitude"),
    }
    params = (Param("rate", 500.0, 1.0, 1e5, "%/s", "largest spool speed R", log=True),)

    def init_state(self, n, u0):
        return {"x": np.array(u0, float)}

    def shape(self, q, dt, state):
        s = self.rate * dt                     # the largest move in one step
        out = np.empty_like(q)
        x_end = state["x"].astype(float)
        for i in range(q.shape[0]):
            x_end[i] = _slew_row(q[i], float(x_end[i]), s, out[i])
        state["x"] = x_end
        return out

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Spool speeds from a reversal of the middle command level in 5 ms to one in 200 ms; a
        ramped step reaches the flow about |Δu|/(2R) late, which the base fit put into τ."""
        swing = 2 * max(float(np.median(s.u_abs_levels)), 1e-3)     # a reversal ±u
        out = []
        for t_ramp in (0.005, 0.02, 0.06, 0.2):
            R = min(1e5, max(1.0, swing / t_ramp))
            out += and_less_delay({"slew.rate": R}, base, t_ramp / 2)
        return out


def _slew_row(v: np.ndarray, x: float, s: float, out: np.ndarray) -> float:
    """Step averages of the rate-limited spool (moves of at most ``s`` a step) along the held
    commands ``v``, from position ``x``, into ``out``; returns the end position. Where the spool
    sits on the command and no step exceeds ``s`` it tracks (vectorized); a step from off the
    command is walked one by one until the spool is on it again."""
    K = v.shape[0]
    d_all = np.diff(v)
    jumps = np.flatnonzero(np.abs(d_all) > s) + 1     # steps a tracking spool cannot follow
    vals = v.tolist()
    k = 0
    while k < K:
        d = vals[k] - x
        if -s <= d <= s:                      # reaches the command within this step
            out[k] = vals[k] - d * abs(d) / (2 * s)
            k += 1
            j = int(jumps[np.searchsorted(jumps, k)]) if len(jumps) and jumps[-1] >= k else K
            if j > k:                          # tracking until the next jump
                dd = d_all[k - 1:j - 1]
                out[k:j] = v[k:j] - dd * np.abs(dd) / (2 * s)
            x = vals[j - 1]
            k = j
        else:
            step = s if d > 0 else -s
            out[k] = x + step / 2
            x += step
            k += 1
    return x


@register
class DeadZone(Effect):
    r"""Valve overlap (dead zone) around the null position.

    Physics: an overlapped spool covers its ports for small openings, so no flow passes until
    the command exceeds the overlap ``d``:

    .. math::  q' = \operatorname{sign}(q)\,\max(|q| - d,\ 0).

    From one command amplitude it looks exactly like a lower gain (the slope is g·(|u| − d));
    two or more amplitudes (the meander at 5, 10, 15, 20 %) separate them.
    """

    name = "deadzone"
    stage = Stage.VALVE
    summary = "valve overlap: no flow for |u| below d"
    at_one_amplitude = ("gain", "a dead zone d only lowers the slope to g·(|u| − d)")
    look_alikes = {
        "gain": (
            "the meander at several amplitudes (e.g. 5, 10, 15, 20 %): a dead zone lowers the "
            "slope by g·d at every amplitude, a lower gain in proportion to |u|"),
        "backlash": (
            "P-feedback with a harmonic reference (a command that turns smoothly): a play delays "
            "the valve at every turning point of the command, a dead zone only cuts the flow near "
            "zero; square waves (meander, relay) cannot tell them apart"),
        "flow_curve": (
            "the meander at three or more amplitudes (e.g. 5, 10, 15, 20 %): two amplitudes fit "
            "both exactly; a dead zone lowers every slope by g·d, a flow curve bends the slopes "
            "as |u|^p"),
    }
    params = (Param("width", 1.0, 0.0, 30.0, "%", "overlap d (command below which no flow)"),)

    def shape(self, q, dt, state):
        return np.sign(q) * np.maximum(np.abs(q) - self.width, 0.0)

    def invert(self, q, dt):
        """u = q + d·sign(q): the command just beyond the overlap."""
        return np.where(q > 0, q + self.width, np.where(q < 0, q - self.width, 0.0))

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        ref = float(np.median(s.u_abs_levels))
        return [{"deadzone.width": min(29.0, f * ref)} for f in (0.0, 0.05, 0.15, 0.3, 0.5, 0.8)]


@register
class Saturation(Effect):
    r"""Flow limit: the valve (or pump) cannot deliver more than a maximum flow.

    .. math::  q' = \operatorname{clip}(q,\ -q_{max},\ q_{max})

    Seen as ramps whose slope stops growing with the command beyond ``q_max``; invisible if the
    data never exceed it.
    """

    name = "saturation"
    stage = Stage.VALVE
    summary = "flow limit: |q| capped at q_max"
    at_one_amplitude = ("gain", "a flow limit below it caps the slope")
    look_alikes = {
        "gain": (
            "the meander at several amplitudes, some beyond the suspected flow limit: the slope "
            "stops growing with |u|"),
        "flow_curve": (
            "the meander at amplitudes below and beyond the suspected limit: a flow limit leaves "
            "the small amplitudes' slopes in proportion and flattens only above it, a flow curve "
            "bends them all"),
    }
    params = (Param("limit", 50.0, 0.5, 100.0, "%", "largest effective flow command q_max"),)

    def shape(self, q, dt, state):
        return np.clip(q, -self.limit, self.limit)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        top = s.u_abs_max
        return [{"saturation.limit": min(100.0, max(0.5, f * top))} for f in (0.3, 0.5, 0.7, 0.9, 1.2)]

    @classmethod
    def ambiguities(cls, ev: Evidence) -> list[Ambiguity]:
        out = super().ambiguities(ev)
        top = ev.excitation.top_command_pct
        if cls.name in ev.tried and ev.best is None and top < 100.0:
            out.append(Ambiguity(["saturation"],
                                 f"the command never exceeds {top:.3g} %: a flow limit above that "
                                 f"cannot show in these data.",
                                 "runs at larger command amplitudes"))
        return out


@register
class Backlash(Effect):
    r"""Play (backlash) between the command and the spool: hysteresis of the valve.

    Physics: the mechanical feedback wire of a two-stage servo-valve, the torque motor's
    magnetic hysteresis and any linkage between an actuator and the spool leave a play of total
    width ``w``: after the command turns back, it must travel ``w`` before the spool moves (a
    servo-valve data sheet states it as "hysteresis", typically under 3 %). The spool position
    is the play operator of the command,

    .. math::  q'_k = \min\!\big(\max(q'_{k-1},\ q_k - w/2),\ q_k + w/2\big).

    Under a square wave ``±u0`` (meander, relay) it is exactly a dead zone of ``w/2``; under a
    continuous command (P-feedback with a harmonic reference) it delays the valve by the time
    the command takes to cross the play and flattens the turning points, which a dead zone does
    not do. The spool starts centred on the command held before the data.
    """

    name = "backlash"
    stage = Stage.VALVE
    summary = "play of total width w between command and spool (hysteresis)"
    at_one_amplitude = ("gain", "a play of width w lowers the slope to g·(|u| − w/2)")
    look_alikes = {
        "gain": (
            "the meander at several amplitudes, or P-feedback with a harmonic reference"),
    }
    params = (Param("width", 1.0, 0.0, 30.0, "%", "total width w of the play"),)

    def init_state(self, n, u0):
        return {"x": np.array(u0, float)}

    def shape(self, q, dt, state):
        h = 0.5 * self.width
        x0 = state["x"]
        if h == 0.0:
            state["x"] = q[:, -1].copy()
            return q
        out = np.empty_like(q)
        for i in range(q.shape[0]):
            row = q[i]
            # the output moves only where the command changes: walk those samples, hold between
            at = np.flatnonzero(np.diff(row)) + 1
            x = float(x0[i])
            first = row[0]
            x = first - h if x < first - h else (first + h if x > first + h else x)
            moved = [x]
            for v in row[at].tolist():
                lo = v - h
                if x < lo:
                    x = lo
                else:
                    hi = v + h
                    if x > hi:
                        x = hi
                moved.append(x)
            seg = np.zeros(row.shape[0], dtype=np.intp)
            seg[at] = 1
            out[i] = np.asarray(moved)[np.cumsum(seg)]
            x0[i] = x
        state["x"] = x0
        return out

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        return [{"backlash.width": w} for w in (1.0, 6.0, 18.0)]


@register
class DirectionDelay(Effect):
    r"""The valve answers a rising command later than a falling one (or the other way round).

    Physics: the transport delay need not be the same both ways. A two-stage servo-valve whose
    pilot stage drives the spool harder one way (unequal nozzle gaps, a worn jet, a null bias), a
    proportional valve whose solenoids differ, or a drive that ramps one direction slower: a
    command step up reaches the flow ``δ`` after a step down would (``δ < 0``: a step down is
    the late one). With the base delay ``τ`` the shorter of the two, the flow is the smallest
    (``δ > 0``) or largest (``δ < 0``) delayed command of the last ``|δ|``:

    .. math::  q'(t) = \min_{t-\delta \le s \le t} q(s)\quad(\delta > 0),\qquad
               q'(t) = \max_{t-|\delta| \le s \le t} q(s)\quad(\delta < 0),

    so a rise arrives ``τ + δ`` late and a fall ``τ`` late (a fraction of a step is
    interpolated, as for ``τ``). Seen in a meander as ramps that start later after the command
    steps one way than the other, with a trend: the flow stays ``δ`` longer at the low command
    every period, which the base model can only fit with a Δ.
    """

    name = "direction_delay"
    stage = Stage.VALVE
    summary = "a rising command reaches the flow δ later than a falling one (δ < 0: falling later)"
    look_alikes = {
        "trend": (
            "meanders at two periods (e.g. 4 and 12 s): a trend Δ is the same at both, the flow's "
            "extra time at one command each period shrinks with a longer period"),
    }
    params = (Param("extra", 0.02, -0.5, 0.5, "s",
                    "extra delay δ of a command rise over a fall (< 0: a fall is the late one)"),)

    def init_state(self, n, u0):
        return {"hist": np.array(u0, float)[:, None]}

    def shape(self, q, dt, state):
        steps = abs(self.extra) / dt
        m = int(math.floor(steps + 1e-12))
        f = steps - m
        need = m + 1                           # the window of m + 2 samples: m + 1 before
        h = state["hist"]
        if h.shape[1] < need:                  # fill with the oldest (the command held before)
            h = np.concatenate([np.repeat(h[:, :1], need - h.shape[1], axis=1), h], axis=1)
        ext = np.concatenate([h[:, -need:], q], axis=1)
        state["hist"] = ext[:, -need:].copy()
        if m == 0 and f == 0.0:
            return q
        run = minimum_filter1d if self.extra > 0 else maximum_filter1d
        # trailing windows (origin (size − 1) // 2): the last m + 1, and m + 2, samples
        out = run(ext, m + 1, axis=1, origin=m // 2, mode="nearest")[:, need:]
        if f:
            wider = run(ext, m + 2, axis=1, origin=(m + 1) // 2, mode="nearest")[:, need:]
            out = (1.0 - f) * out + f * wider
        return out

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Either direction late by 10-80 ms; the base fit's τ is about the mean of the two
        delays, so each also starts with τ shortened by half the difference."""
        out = []
        for d in (-0.08, -0.03, -0.01, 0.01, 0.03, 0.08):
            out += and_less_delay({"direction_delay.extra": d}, base, abs(d) / 2)
        return out


@register
class FlowCurve(Effect):
    r"""A flow characteristic that is not a straight line: flow grows as a power of the opening.

    Physics: the valve's flow versus command is linear only for a critically lapped spool with
    rectangular ports at a constant pressure drop. Port shape (round or notched ports), lap
    (underlap raises the gain near null) and flow forces at large openings bend it; a power law
    through the point ``u_ref = 10 %`` describes the bend with one number:

    .. math::  q' = \operatorname{sign}(q)\,u_{ref}\left(\frac{|q|}{u_{ref}}\right)^{p}.

    ``p < 1``: degressive (slopes grow less than in proportion to |u|), ``p > 1``: progressive.
    ``g`` stays the gain at 10 %. One amplitude cannot show it (it is then a gain change); the
    meander at several amplitudes does: the ramp slopes go as ``|u0|^p``.
    """

    name = "flow_curve"
    stage = Stage.VALVE
    summary = "power-law flow characteristic q = sign(u)·u_ref·(|u|/u_ref)^p"
    at_one_amplitude = ("gain", "a bent flow curve only changes the slope")
    look_alikes = {
        "gain": (
            "the meander at several amplitudes: the ramp slopes grow as |u|^p instead of in "
            "proportion to |u|"),
    }
    U_REF = 10.0
    params = (Param("exponent", 1.0, 0.3, 3.0, "1", "power p of the flow curve (1: linear)"),)

    def shape(self, q, dt, state):
        p = self.exponent
        if p == 1.0:
            return q
        return np.sign(q) * self.U_REF * (np.abs(q) / self.U_REF) ** p

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        return [{"flow_curve.exponent": p} for p in (0.84, 1.0, 1.92)]


# ------------------------------------------------------------------------------------------
# FLOW stage
# ------------------------------------------------------------------------------------------
@register
class Asymmetry(Effect):
    r"""Different gain when extending and retracting.

    Physics: a single-rod cylinder has different piston areas on its two sides (and valves have
    unequal port gains), so the same command moves the load faster one way:

    .. math::  G = 1 + a\,\operatorname{sign}(q)

    i.e. ``g·(1+a)`` for q > 0 (extend, force rising) and ``g·(1−a)`` for q < 0 (retract).
    """

    name = "asymmetry"
    stage = Stage.FLOW
    summary = "different gain for extend (1+a) and retract (1-a)"
    look_alikes = {
        "trend": (
            "the meander at two amplitudes, or a hold at zero command: the trend Δ is the same at "
            "every |u|, an extend/retract asymmetry grows with |u|"),
    }
    params = (Param("ratio", 0.1, -0.8, 0.8, "1", "relative gain difference a"),)

    def gain(self, q, aux, y):
        return 1.0 + self.ratio * np.sign(q)

    def largest_gain_factor(self) -> float:
        """1 + |a|: the faster direction."""
        return 1.0 + abs(self.ratio)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        return [{"asymmetry.ratio": a} for a in (-0.3, -0.1, 0.0, 0.1, 0.3)]

    @classmethod
    def ambiguities(cls, ev: Evidence) -> list[Ambiguity]:
        ex = ev.excitation
        if not (ex.single_amplitude and cls.name in ev.tried and not ex.has_zero_hold):
            return []
        lv = f"{ex.levels[0]:g} %"
        d = ev.base["delta"]
        ramp = ev.base["g"] * ex.levels[0]
        hint = (f" The fitted trend Δ = {d:.3g} kgf/s is {abs(d) / ramp * 100:.1f} % of the "
                f"ramp rate g·|u|; if the valve's null offset is known to be small, read it as "
                f"an asymmetry a ≈ {d / ramp:+.3f} (retract {'slower' if d > 0 else 'faster'}).") \
            if ramp > 0 else ""
        return [Ambiguity(["asymmetry", "trend"],
                          f"with the command always ±{lv}, a gain that differs between extend "
                          f"and retract adds the same force rate as the trend Δ.{hint}",
                          separating_experiment("asymmetry", "trend"))]


@register
class Supply(Effect):
    r"""The supply pressure sags while the valve draws much flow, and recovers.

    Physics: the pump (and its accumulator) deliver a limited flow through a supply line with
    its own losses; a large valve opening draws more than that, so the supply pressure ``P_s``
    falls, over the accumulator's time constant, and recovers at small openings. The flow
    through the valve goes as the square root of its pressure drop, so the gain falls with it.
    With ``s`` the relative sag of ``P_s``, ``k`` the sag a full opening would settle at and
    ``T`` its time constant:

    .. math::  T\,\dot s = k\,\frac{|q|}{100\,\%} - s,\qquad G = \sqrt{\max(1 - s,\ 0)}.

    Seen in data as ramps that start at the full slope after a quiet stretch and bend down
    over ``T`` while the command stays large, more at larger amplitudes (a flow curve or limit
    bends the slopes at every instant alike, without a memory). The sag starts settled on the
    command held before.
    """

    name = "supply"
    stage = Stage.FLOW
    summary = "supply pressure sags with the flow drawn (k at full opening, time constant T)"
    look_alikes = {
        "flow_curve": (
            "a large command held for several seconds after a hold at zero: a sagging supply "
            "starts at the full slope and bends it down over its time constant, a flow curve has "
            "the lower slope from the first instant"),
        "saturation": (
            "a large command held for several seconds after a hold at zero: a flow limit caps the "
            "slope at once, a sagging supply lowers it over its time constant"),
    }
    params = (Param("sag", 0.3, 0.0, 5.0, "1", "relative supply-pressure sag k a full opening settles at"),
              Param("time_constant", 1.0, 1e-3, 100.0, "s", "time constant T of the sag", log=True))

    def init_state(self, n, u0):
        return {"x": self.sag * np.abs(np.array(u0, float)) / 100.0}

    def prepare(self, q, dt, state, command=None, t=None):
        sag = first_order_step_average(self.sag * np.abs(q) / 100.0, dt, self.time_constant, state)
        return np.sqrt(np.maximum(1.0 - sag, 0.0))

    def gain(self, q, aux, y):
        return aux

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Sags of 5-40 % at the largest command in the data, settling in 0.1-3 s."""
        top = max(s.u_abs_max, 1e-3) / 100.0
        return [{"supply.sag": min(5.0, f / top), "supply.time_constant": T}
                for f in (0.05, 0.15, 0.4) for T in (0.1, 0.5, 3.0)]

    @classmethod
    def ambiguities(cls, ev: Evidence) -> list[Ambiguity]:
        if ev.best != cls.name:
            return []
        T = ev.best_params.get("supply.time_constant", math.nan)
        return [Ambiguity(
            ["supply", "flow_curve"],
            f"at a held command the supply's sag settles at k·|u| and the gain at "
            f"√(1 − k·|u|/100), a degressive flow characteristic of its own: only the sag's "
            f"build-up over T (fitted {T:.3g} s) after |u| changes tells a sagging supply from a "
            f"bent flow curve (or a dead zone with one).",
            separating_experiment("supply", "flow_curve"))]


@register
class GainDrift(Effect):
    r"""The gain drifts during a run: the oil warms up (or the supply settles after start-up).

    Physics: the pump and the valve's throttling turn the hydraulic power into heat, so the oil
    warms from the start of a run toward its running temperature, with the circuit's thermal
    time constant ``T`` (minutes). Its viscosity falls, the spool's and the piston's leakages
    rise and the pump's delivery changes, so the flow per % command (the gain) changes with the
    temperature. With ``r`` the gain's relative rate of change at the start of the run and
    ``t`` the time since the run began (a record's first sample):

    .. math::  G(t) = \max\big(1 + r\,T\,(1 - e^{-t/T}),\ 0\big),

    averaged exactly over each step. For ``T`` much longer than the run it is the linear drift
    ``G = 1 + r·t``; ``g`` is the gain at the start of the run. Seen in data as a slope error
    along the motion that grows with time (the model too slow at the end of every run and right
    at its start, or the other way), the same in every run, at every command level and in both
    directions. In the emulator the clock restarts when the master starts the nodes.
    """

    name = "gain_drift"
    stage = Stage.FLOW
    summary = "gain drifting during a run (oil warming): G = 1 + r·T·(1 − exp(−t/T))"
    look_alikes = {
        "supply": (
            "a long run at one small command amplitude: a warming oil changes the gain whatever "
            "the flow drawn, a sagging supply hardly sags at small openings and recovers in every "
            "pause"),
        "gain": (
            "two runs, one after the other, or one long run: a drifting gain differs between the "
            "starts and the ends of the runs, a wrong gain is wrong everywhere alike"),
    }
    reads_time = True
    params = (Param("rate", 0.002, -0.05, 0.05, "1/s",
                    "relative rate of change r of the gain at the start of a run"),
              WARMING_TIME_CONSTANT)

    def prepare(self, q, dt, state, command=None, t=None):
        return np.maximum(1.0 + self.rate * warming(t, dt, self.time_constant), 0.0)

    def gain(self, q, aux, y):
        return aux

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """The gain rising or falling by 5-50 % over a run."""
        return warming_starts(cls.name, (-0.3, -0.05, 0.05, 0.2, 0.5), 0.05, s)


@register
class Reversal(Effect):
    r"""Gain boost decaying after each reversal of the rod's direction (the paper's
    "transitional portion", Figs. 4, 11, 12).

    Physics: when the rod reverses, the compressed oil volume and the elastic loading chain
    release stored energy and take up play, so for a short time the force changes much faster
    than the steady gain predicts. The direction is the sign of the flow command; ``s`` is the
    time since it last changed sign:

    .. math::  G = 1 + b\,\left(\frac{u_{ref}}{\max(|q|,\ 0.5\,\%)}\right)^{p} e^{-s/T_r},
               \qquad u_{ref} = 10\ \%.

    With ``p = 0`` the boost is a pure gain factor; with ``p = 1`` it is a fixed extra force
    rate ``g·b·u_ref·e^{-s/T_r}`` (a fixed extra force ``g·b·u_ref·T_r`` per reversal), whose
    relative size shrinks as the command amplitude grows, which is what the paper found
    (Fig. 12: the transitional gain falls as u0 rises). ``p`` is identifiable only from data
    with several amplitudes.
    """

    name = "reversal"
    stage = Stage.FLOW
    summary = "gain boost decaying after each change of the rod's direction"
    look_alikes = {
        "lag": (
            "the meander at several amplitudes and periods"),
        "command_reversal": (
            "the meander with a delay comparable to the boost's decay: a boost timed from the "
            "command already pushes the old direction during the delay, one timed from the rod "
            "starts after it"),
        "travel_reversal": (
            "the meander at several amplitudes (e.g. 5 and 20 %): a boost timed from the reversal "
            "lasts T_r at every amplitude, one that dies out over the travel lasts V_r/|u|, four "
            "times shorter at four times the command"),
    }
    U_REF = 10.0
    params = (
        Param("boost", 2.0, 0.0, 50.0, "1", "boost b right at the reversal (at |q| = u_ref)"),
        Param("decay", 0.15, 0.005, 3.0, "s", "decay time T_r of the boost", log=True),
        Param("exponent", 0.7, 0.0, 1.0, "1", "amplitude exponent p (0: gain factor, 1: fixed extra force)"),
    )

    def init_state(self, n, u0):
        return reversal_state(n, u0)

    def prepare(self, q, dt, state, command=None, t=None):
        return np.exp(-since_reversal(q, dt, state) / self.decay)

    def gain(self, q, aux, y):
        scale = (self.U_REF / np.maximum(np.abs(q), 0.5)) ** self.exponent
        return 1.0 + self.boost * scale * aux

    def largest_gain_factor(self) -> float:
        """1 + b: right after a reversal, at |q| = u_ref."""
        return 1.0 + self.boost

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        return [{"reversal.boost": b, "reversal.decay": T, "reversal.exponent": p}
                for b in (0.5, 2.0, 8.0) for T in (0.03, 0.1, 0.3) for p in (0.0, 0.7)] + [
            {"reversal.boost": 0.0, "reversal.decay": 0.1, "reversal.exponent": 0.5}]


@register
class CommandReversal(Reversal):
    r"""The reversal boost timed from the valve command's reversal, not the rod's.

    Physics: as :class:`Reversal`, but the stored energy is released when the *spool* reverses
    (the chambers swap pressure at the valve), which leads the rod's reversal by the transport
    delay when the delay sits downstream of the valve (lines, loading chain). ``s`` is the time
    since the undelayed command changed sign; the boost acts on the flow that is still arriving
    from before, then on the new one:

    .. math::  G = 1 + b\,\left(\frac{u_{ref}}{\max(|q|,\ 0.5\,\%)}\right)^{p}
               e^{-s_u/T_r}.

    With a decay much longer than the delay it looks like :class:`Reversal`; the difference is
    the push in the old direction during the delay after each command reversal.
    """

    name = "command_reversal"
    summary = "reversal boost timed from the command's sign change (before the delay)"
    look_alikes = {
        "travel_reversal": (
            "the meander at several amplitudes: a boost timed from the command lasts T_r at every "
            "amplitude and starts during the delay, one that dies out over the travel lasts "
            "V_r/|u| from the rod's reversal"),
    }
    reads_command = True

    def prepare(self, q, dt, state, command=None, t=None):
        return np.exp(-since_reversal(q if command is None else command, dt, state) / self.decay)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Starts like the rod-timed reversal (same parameters)."""
        return renamed(Reversal.start_grid(s, base), "reversal", cls.name)


@register
class TravelReversal(Effect):
    r"""Gain boost after each reversal that dies out over the rod's *travel*, not over time.

    Physics: what changes at a reversal (seal friction turning round, play in the joints taken
    up, a contact settling) is completed over a distance moved: friction in the pre-sliding
    regime (Dahl's law) evolves with displacement. The rod's travel since the reversal is the
    flow passed since then, ``V = ∫|q| dt`` (command-%·s); the boost decays with the force
    travelled, ``Δy ≈ g·V``:

    .. math::  \dot y = g\,q\,\big(1 + b\,e^{-|y - y_r|/F}\big),\qquad
               G = 1 + \frac{b}{(1+b)\,e^{V/V_r} - b},\quad F = g\,V_r,

    the second form being the first solved in closed form along the travel (exact for the base
    model; averaged exactly over each step). Every reversal adds the same extra force,
    ``F·ln(1 + b)``, at any amplitude, and the transition lasts ``V_r/|u|``: four times shorter
    at four times the command. A time-timed boost (:class:`Reversal`) lasts ``T_r`` at any
    amplitude: meanders at several amplitudes separate the two.
    """

    name = "travel_reversal"
    stage = Stage.FLOW
    summary = "reversal boost that dies out over the rod's travel since the reversal, not over time"
    params = (
        Param("boost", 2.0, 0.0, 50.0, "1", "boost b right at the reversal"),
        Param("travel", 1.0, 0.005, 50.0, "%·s",
              "travel V_r (flow passed, command % × s) over which the boost falls by e "
              "(force travelled F = g·V_r)", log=True),
    )

    def init_state(self, n, u0):
        return reversal_state(n, u0)

    def prepare(self, q, dt, state, command=None, t=None):
        move = np.abs(q) * dt
        v0 = since_reversal(q, move, state) / self.travel      # travel at each step's start
        b, a = self.boost, 1.0 + self.boost
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            e0 = np.exp(-v0)
            at_start = b * e0 / (a - b * e0)
            dv = move / self.travel
            # the step average: (V_r / move)·ln((a − b·e^−v1) / (a − b·e^−v0))
            mean = np.log1p(b * e0 * -np.expm1(-dv) / (a - b * e0)) / dv
        return np.where(dv > 1e-9, mean, at_start)

    def gain(self, q, aux, y):
        return 1.0 + aux

    def largest_gain_factor(self) -> float:
        """1 + b: right at the reversal."""
        return 1.0 + self.boost

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Boosts that die out within 0.03-0.3 s at the middle command level (travel = |u|·time)."""
        ref = max(float(np.median(s.u_abs_levels)), 1e-3)
        return [{"travel_reversal.boost": b, "travel_reversal.travel": min(50.0, max(0.005, ref * T))}
                for b in (0.5, 2.0, 8.0) for T in (0.03, 0.1, 0.3)] + [
            {"travel_reversal.boost": 0.0, "travel_reversal.travel": max(0.005, ref * 0.1)}]


def reversal_state(n: int, u0: np.ndarray) -> dict[str, np.ndarray]:
    """The state :func:`since_reversal` carries, at rest on the command ``u0`` (n,): the
    direction of the last motion (0: at rest) and no reversal yet."""
    return {"direction": np.sign(u0).astype(float), "since": np.full(n, np.inf)}


def since_reversal(q: np.ndarray, inc: float | np.ndarray, state: dict) -> np.ndarray:
    """How much of ``inc`` (per step: the step's length for a time, its travel for a distance)
    has passed since the sign of ``q`` (n, K) last changed, at each step's start (a zero keeps
    the last direction; inf before the first reversal). ``state`` carries ``direction`` and
    ``since`` across blocks."""
    n, K = q.shape
    steps = np.arange(K)
    sgn = np.sign(q)
    if sgn.all():       # no zero command: the direction is the command's sign
        held = sgn
    else:               # a zero command keeps the last direction
        idx = np.maximum.accumulate(np.where(sgn != 0, steps, -1), axis=1)
        held = np.where(idx >= 0, sgn[np.arange(n)[:, None], np.maximum(idx, 0)],
                        state["direction"][:, None])
    prev = np.empty_like(held)
    prev[:, 0] = state["direction"]
    prev[:, 1:] = held[:, :-1]
    reversal = (held != prev) & (prev != 0)
    if np.ndim(inc) == 0:
        before = steps * float(inc)            # the sum of the increments before each step
        last_inc = np.full(n, float(inc))
    else:
        before = np.cumsum(inc, axis=1) - inc
        last_inc = inc[:, -1]
    carried = state["since"][:, None] + before
    if reversal.any():
        # index of the last reversal at or before each step (-1: none in this block)
        last = np.maximum.accumulate(np.where(reversal, steps, -1), axis=1)
        if np.ndim(inc) == 0:                  # equal increments: no lookup needed
            since = np.where(last >= 0, (steps - last) * float(inc), carried)
        else:
            at_last = np.take_along_axis(before, np.maximum(last, 0), axis=1)
            since = np.where(last >= 0, before - at_last, carried)
    else:
        since = carried
    state["direction"] = held[:, -1].copy()
    state["since"] = since[:, -1] + last_inc
    return since


@register
class LoadPressure(Effect):
    r"""Load pressure reduces the flow the valve can push against the load (orifice law).

    Physics: flow through a valve orifice goes as the square root of the pressure drop across
    it. Pushing in the direction of the load pressure leaves ``P_s − P_L`` across the valve;
    with the load force proportional to the load pressure, ``F_s = P_s·A`` being the stall force:

    .. math::  G = \sqrt{\max\!\left(1 - \operatorname{sign}(q)\,\frac{y - y_n}{F_s},\ 0\right)}

    ``y_n`` is the force reading at zero load pressure: a dynamometer zero offset or a preload
    of the loading chain (default 0). Seen as ramps that slow down as the force grows in the
    direction of motion and speed up on the way back. At a single command amplitude it is, to
    first order, a leak toward ``y_n`` (``λ = g·|u|/(2F_s)``); several amplitudes separate them.
    """

    name = "load_pressure"
    stage = Stage.FLOW
    summary = "orifice law: gain scales with sqrt(1 - sign(u)·(y - y_n)/F_s)"
    look_alikes = {
        "asymmetry": (
            "runs at both positive and negative force levels: the load-pressure effect swaps "
            "extend/retract with the sign of the force"),
    }
    depends_on_force = True
    params = (Param("stall_force", 30000.0, 2000.0, 1e7, "kgf",
                    "stall force F_s = supply pressure × piston area", log=True),
              Param("offset", 0.0, -1e4, 1e4, "kgf",
                    "force reading y_n at zero load pressure (sensor offset, preload)"))

    def gain(self, q, aux, y):
        return np.sqrt(np.maximum(1.0 - np.sign(q) * (y - self.offset) / self.stall_force, 0.0))

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        ymax = max(s.y_abs_max, 100.0)
        return [{"load_pressure.stall_force": min(1e7, max(2000.0, f * ymax))}
                for f in (1.3, 2.0, 5.0, 20.0, 1000.0)]


@register
class Stiffness(Effect):
    r"""The loaded structure's stiffness changes with the load.

    Physics: the cylinder moves the rod at ``v = Q/A``; the force follows through the stiffness
    of the specimen and the loading chain, ``ẏ = K·v``, so the gain ``g`` is proportional to
    ``K``. An aircraft structure is rarely a linear spring: contacts close and joints take up
    their play as the load grows (stiffening), skins buckle (softening), and a structure can be
    stiffer in compression than in tension. To first order in the force, with ``F_fs = 10⁴ kgf``
    (the dynamometer's full scale):

    .. math::  G = \max\!\left(1 + k_{abs}\,\frac{|y|}{F_{fs}} + k_{sgn}\,\frac{y}{F_{fs}},\ 0\right)

    Seen as ramps that steepen (or flatten) away from zero force in both directions of motion,
    unlike :class:`LoadPressure` and :class:`Leakage`, which slow the motion away from zero and
    speed the way back.
    """

    name = "stiffness"
    stage = Stage.FLOW
    summary = "gain changes with the load: 1 + k_abs·|y|/10⁴ + k_sgn·y/10⁴ (non-linear specimen)"
    depends_on_force = True
    params = (Param("k_abs", 0.0, -1.0, 50.0, "1",
                    "relative gain change at |y| = 10⁴ kgf, both signs of force (>0: stiffening)"),
              Param("k_sgn", 0.0, -20.0, 20.0, "1",
                    "relative gain change per +10⁴ kgf of signed force (tension/compression)"))

    #: the force the coefficients refer to (the dynamometer's full scale), kgf
    FULL_SCALE = 1e4

    def gain(self, q, aux, y):
        x = y / self.FULL_SCALE
        return np.maximum(1.0 + self.k_abs * np.abs(x) + self.k_sgn * x, 0.0)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Gain changes at the data's largest force: −20, 0, +20, +60 % for both signs of force,
        −20, 0, +20 % between tension and compression."""
        r = 1e4 / max(s.y_abs_max, 100.0)
        return [{"stiffness.k_abs": min(50.0, a * r), "stiffness.k_sgn": max(-20.0, min(20.0, b * r))}
                for a in (-0.2, 0.0, 0.2, 0.6) for b in (-0.2, 0.0, 0.2)]


@register
class Unloading(Effect):
    r"""The loaded structure is stiffer on the way back to zero load than on the way up.

    Physics: loading a built-up structure, its joints and fasteners micro-slip and contacts
    settle, and a composite or an elastomer bearing in the loading chain creeps; unloading, the
    joints stay locked and the structure springs back along a stiffer line (the loading and
    unloading branches of its force-displacement loop). With ``g`` proportional to the stiffness
    (``ẏ = K·v``, see :class:`Stiffness`), the flow drives the force away from zero (loading,
    ``sign(q) = sign(y)``) with ``g·(1−h)`` and toward zero (unloading) with ``g·(1+h)``:

    .. math::  G = 1 - h\,\operatorname{sign}(q)\,\operatorname{sign}(y)

    ``h > 0``: stiffer unloading. Unlike :class:`Asymmetry` (extend against retract, whatever
    the force) the fast direction swaps with the sign of the force; unlike
    :class:`LoadPressure` and :class:`Stiffness`, the difference does not grow with the load,
    it switches at zero force.
    """

    name = "unloading"
    stage = Stage.FLOW
    summary = "gain g·(1-h) loading, g·(1+h) unloading (specimen hysteresis)"
    look_alikes = {
        "asymmetry": (
            "runs at both positive and negative force levels: an asymmetry keeps its fast "
            "direction, a specimen stiffer unloading swaps it with the sign of the force"),
        "load_pressure": (
            "runs at two force levels of the same sign (e.g. meanders centred at 2000 and 6000 "
            "kgf): the load-pressure effect grows with the force, the unloading stiffness only "
            "switches at zero force"),
    }
    depends_on_force = True
    params = (Param("ratio", 0.1, -0.8, 0.8, "1",
                    "relative gain difference h between unloading and loading (>0: stiffer unloading)"),)

    def gain(self, q, aux, y):
        return 1.0 - self.ratio * np.sign(q) * np.sign(y)

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        return [{"unloading.ratio": h} for h in (-0.3, -0.1, 0.0, 0.1, 0.3)]


# ------------------------------------------------------------------------------------------
# DISTURBANCE stage (not plant physics: never offered as a diagnosis)
# ------------------------------------------------------------------------------------------
@register
class Oscillation(Effect):
    r"""A periodic force disturbance from outside the loading channel (a neighbouring actuator,
    a structural resonance, pump ripple):

    .. math::  y_{dist}(t) = A \sin(2\pi f t),\qquad \dot y \mathrel{+}= 2\pi f A \cos(2\pi f t).

    It is not an effect of the valve/cylinder physics, so ``stand diagnose`` does not offer it;
    its trace in the residual is reported as *unexplained*, with its frequency. Use it in the
    emulator to test that, or add it to a model when the disturbance is known.
    """

    name = "oscillation"
    stage = Stage.DISTURBANCE
    summary = "external periodic force disturbance A·sin(2πft) (not diagnosable)"
    diagnosable = False
    params = (
        Param("amplitude", 50.0, 0.0, 5000.0, "kgf", "disturbance amplitude A"),
        Param("frequency", 3.0, 0.01, 100.0, "Hz", "disturbance frequency f", log=True),
    )

    def disturbance(self, t, dt):
        w = 2 * np.pi * self.frequency  # exact step average of 2πfA·cos(2πft)
        return self.amplitude * (np.sin(w * (t + dt)) - np.sin(w * t)) / dt


# ------------------------------------------------------------------------------------------
# FORCE stage
# ------------------------------------------------------------------------------------------
@register
class Leakage(Effect):
    r"""Leakage across the piston (and the valve's internal leakage).

    Physics: oil leaks from the loaded chamber to the other through the piston seal at a rate
    proportional to the pressure difference, i.e. to the load force, so the force drifts toward
    zero even at a zero command:

    .. math::  \dot y \mathrel{+}= -\lambda\, y .

    Seen as a drift that grows with |y|, toward zero, and a relay/feedback offset that depends on
    the force level.
    """

    name = "leakage"
    stage = Stage.FORCE
    summary = "drift toward zero force proportional to the load (-λ·y)"
    look_alikes = {
        "load_pressure": (
            "meanders at two amplitudes, or a hold at zero command away from zero force: leakage "
            "drifts toward zero at any command, the load-pressure effect scales with |u|"),
        "trend": (
            "runs around two different force levels (e.g. meanders centred at +2000 and −2000 "
            "kgf): leakage drifts toward zero, the trend Δ does not depend on the force"),
    }
    depends_on_force = True
    params = (Param("rate", 0.05, 0.0, 20.0, "1/s", "leak coefficient λ"),)

    def force_rate(self, y):
        return -self.rate * y

    def decay_rate(self):
        return self.rate

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        return [{"leakage.rate": lam} for lam in (0.0, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0)]

    @classmethod
    def ambiguities(cls, ev: Evidence) -> list[Ambiguity]:
        pair = {"leakage", "load_pressure"}
        if not ev.excitation.single_amplitude or not (pair <= ev.tried or ev.best in pair):
            return []
        return [Ambiguity(["leakage", "load_pressure"],
                          "at a single command amplitude the orifice law's slow-down "
                          "(∝ sign(u)·y) acts like a leak toward zero force.",
                          separating_experiment("leakage", "load_pressure"))]


# ------------------------------------------------------------------------------------------
# SENSOR stage
# ------------------------------------------------------------------------------------------
@register
class SensorLag(Effect):
    r"""A first-order filter in the dynamometer: its reading lags the force.

    Physics: a strain-gauge amplifier's anti-aliasing or noise filter (CiA 404 devices have a
    configurable digital filter) reports

    .. math::  T_s\,\dot y_m = y - y_m ,

    computed here on the rate (``ẏ_m`` is ``ẏ`` through the same filter), so the force itself,
    which force-dependent effects see, is unfiltered. For a linear plant it acts like a valve
    :class:`Lag` (the two commute on an integrator); behind a valve nonlinearity (dead zone, flow
    limit, reversal boost) it does not: the filter smooths what the nonlinearity made. A window
    of the analysis starts from a reading: the filter's state there is taken from the rate along
    the measured force, and the force under the reading is ``y_m + T_s·ẏ_m``.
    """

    name = "sensor_lag"
    stage = Stage.SENSOR
    summary = "dynamometer filter: the reading lags the force by T_s (first order)"
    params = (Param("time_constant", 0.01, 1e-4, 1.0, "s", "filter time constant T_s", log=True),)

    def filter_rate(self, rate, dt, state):
        return first_order_step_average(rate, dt, self.time_constant, state)

    def filter_states(self, rate, dt, steps):
        x_start, _ = first_order_states(rate, dt, self.time_constant, rate[:, 0].copy())
        return {"x": x_start[0, steps]}

    def force_minus_reading(self, state):
        return self.time_constant * state["x"]      # y − y_m = T_s·ẏ_m

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Starts like a valve lag (same parameters)."""
        return renamed(Lag.start_grid(s, base), "lag", cls.name)


@register
class Stiction(Effect):
    r"""Seal friction sticks the rod after each reversal: the measured force holds, then moves on.

    Physics: the rod seals' friction ``F_c`` opposes the rod's motion. When the force's trend
    reverses, the rod stops and stays stuck until the hydraulic force has changed by ``2F_c``;
    meanwhile the force on the specimen, which the dynamometer reads, stays where it was. The
    reading is a *play* of width ``w = 2F_c`` on the hydraulic force ``y``:

    .. math::  y_m(t) = \operatorname{clip}\big(y_m(t^-),\ y(t) - w/2,\ y(t) + w/2\big)

    so after each reversal the reading holds for ``w/|ẏ|`` (longer at small commands) and then
    follows. Force-dependent effects (leakage, load pressure) act on the hydraulic force, as the
    oil does. Seen as a dead time after each reversal that shrinks as ``1/|u|``: at one amplitude
    like more delay, at several not; unlike :class:`Backlash` (a play on the command, which a
    square wave jumps at once) it holds after a meander's reversals too. A window of the
    analysis starts from a reading; where the force sits in the play there comes from running
    the play along the measured force.
    """

    name = "stiction"
    stage = Stage.SENSOR
    summary = "rod sticks after each reversal: the reading is a play of width w on the force"
    look_alikes = {
        "delay": (
            "the meander at two or more amplitudes (e.g. 5 and 20 %): a rod stuck after each "
            "reversal holds the force w/(g·|u|), longer at small amplitudes; a delay is the same "
            "at every amplitude"),
        "backlash": (
            "the meander (square waves): a play on the command is jumped at once by a step, a "
            "stuck rod still holds the force after each reversal"),
    }
    linear_in_gain = False
    params = (Param("width", 100.0, 0.0, 5000.0, "kgf",
                    "play w = 2F_c: the change of hydraulic force that moves a stuck rod"),)

    def filter_rate(self, rate, dt, state):
        if "offset" not in state:
            state["offset"] = self._at_rest(rate.shape[0])
        engaged, _ = self._play(rate, dt, state)
        return rate * engaged

    def filter_states(self, rate, dt, steps):
        state = {"offset": self._at_rest(rate.shape[0])}
        _, offsets = self._play(rate, dt, state, track=True)
        return {"offset": offsets[0, steps].copy()}

    def force_minus_reading(self, state):
        return state["offset"]

    @staticmethod
    def _at_rest(n: int) -> np.ndarray:
        """A stand at rest: the rod stuck with the force in the middle of the play (which side
        it last moved is not known), so the first motion either way crosses half of it."""
        return np.zeros(n)

    def _play(self, rate, dt, state, track=False):
        """Engaged fraction of each step (0 while the play is being crossed), advancing
        ``state["offset"]`` (force minus reading, in [−w/2, w/2]); with ``track``, also the
        offset at each step's start. The direction of a stretch is that of its motion; where
        the offset sits says how much of the play a motion that way still has to cross."""
        half = self.width / 2
        n, K = rate.shape
        engaged = np.ones((n, K))
        offset = state["offset"].astype(float)
        offsets = np.repeat(offset[:, None], K, axis=1) if track else None
        if half <= 0:
            return engaged, offsets
        move = np.abs(rate) * dt
        sgn = np.sign(rate)
        for i in range(n):
            moving = np.flatnonzero(sgn[i])
            if not len(moving):
                continue
            signs = sgn[i, moving]
            turns = moving[1:][signs[1:] != signs[:-1]]   # steps where the motion turns
            bounds = np.concatenate([[0], turns, [K]])
            for a, b in zip(bounds[:-1], bounds[1:]):
                d = sgn[i, moving[np.searchsorted(moving, a)]]   # this stretch's direction
                room = half - d * offset[i]                     # force change still to cross
                if room <= 0:                                    # engaged: the reading follows
                    if track:
                        offsets[i, a:b] = offset[i]
                    continue
                crossed = np.cumsum(move[i, a:b])
                with np.errstate(divide="ignore", invalid="ignore"):
                    part = np.where(move[i, a:b] > 0, (crossed - room) / move[i, a:b], 1.0)
                engaged[i, a:b] = np.clip(part, 0.0, 1.0)
                if track:
                    before_step = np.concatenate([[0.0], crossed[:-1]])
                    offsets[i, a:b] = offset[i] + d * np.minimum(before_step, room)
                offset[i] += d * min(crossed[-1], room)
        state["offset"] = offset
        return engaged, offsets

    @classmethod
    def start_grid(cls, s: Any, base: Mapping[str, float]) -> list[dict]:
        """Plays of 0-30 % of the force span; a hold after each reversal looks like more delay, so
        each also starts with τ shortened by the hold at the middle command level."""
        g = abs(base.get("g", 100.0)) or 100.0
        ref = max(float(np.median(s.u_abs_levels)), 1e-3)
        out = []
        for f in (0.0, 0.01, 0.03, 0.1, 0.3):
            w = min(5000.0, f * max(s.y_span, 100.0))
            out += and_less_delay({"stiction.width": w}, base, w / (g * ref))
        return out

    @classmethod
    def ambiguities(cls, ev: Evidence) -> list[Ambiguity]:
        ex = ev.excitation
        if not (ex.single_amplitude and cls.name in ev.tried):
            return []
        return [Ambiguity(["stiction", "delay"],
                          f"at a single command amplitude (|u| = {ex.levels[0]:g} %) a rod that "
                          f"sticks after each reversal holds the force the same w/(g·|u|) every "
                          f"time: it looks like more delay (the fitted τ = "
                          f"{ev.base['tau'] * 1e3:.1f} ms may include such a hold).",
                          separating_experiment("stiction", "delay"))]


def effect_class(name: str) -> type[Effect]:
    """Look up an effect by name (the catalogue's, a plug-in's, an installed package's), with a
    helpful error."""
    if name not in CATALOGUE:
        from .plugins import load_installed
        load_installed()
    try:
        return CATALOGUE[name]
    except KeyError:
        raise ModelError(
            f"unknown effect {name!r}; the catalogue has: {', '.join(CATALOGUE)} (see `stand "
            f"effects`); an effect of your own is loaded with --effects FILE.py") from None
