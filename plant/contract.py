r"""The contract every effect keeps: the built-ins of :mod:`plant.effects` and a user's
plug-ins alike.

The base model (paper, eq. 1, with the constant trend of eq. 2) is

.. math::  \dot y(t) = g\,u(t-\tau) + \Delta

with the force ``y`` in kgf, the valve command ``u`` in % (±100 % = ±10 V), the gain ``g`` in
kgf/(%·s), the transport delay ``τ`` in s and the trend ``Δ`` in kgf/s. Effects refine it at one of
five places of the signal path, applied in this order::

    u(t-τ) ─▶ VALVE (spool/flow command q) ─▶ FLOW (gain factors on g·q) ─▶ Σ ─▶ ∫ ─▶ y ─▶ SENSOR ─▶ y_m
                                                   DISTURBANCE, FORCE (rate terms) ─┘

so the complete rate law is

.. math::  \dot y = g\,q\,\prod_i G_i(q, y, t) + \Delta + \sum_j D_j(y, t).

An effect is one class: a subclass of :class:`Effect` that declares ``name``, ``stage`` and
``params`` (:class:`~plant.params.Param`, so the fit, the TOML loader and the CLI pick them up),
implements the hook of its stage and carries all it knows (physics and equation in its docstring,
start grid, look-alikes, what the controller design asks). Every hook works on arrays of shape
``(n, K)``: ``n`` independent trajectories (simulation windows) by ``K`` time steps, carrying its
state between blocks, so the emulator (``K`` small, one block per control period) and the
analysis (whole records, windows side by side) run the same code.

A module of such classes is a plug-in (:mod:`plant.loader` registers them into
:data:`CATALOGUE`); the project's own effects are plug-ins too (:mod:`plant.effects`,
:mod:`plant.catalogue`), so they are the first examples of this contract.
"""
from __future__ import annotations

import enum
from typing import Any, ClassVar, Mapping

import numpy as np

from .evidence import BASE_LOOK_ALIKES, DEFAULT_EXPERIMENT, Ambiguity, Evidence
from .params import ModelError, Param
from .start_grids import generic_starts


class Stage(enum.IntEnum):
    """Where in the signal path an effect acts (also the order of application)."""

    VALVE = 1        #: transforms the delayed command into the flow command q (%)
    FLOW = 2         #: multiplies the flow-driven force rate g·q by a factor
    DISTURBANCE = 3  #: adds a force rate that depends on time only
    FORCE = 4        #: adds a force rate that depends on the force itself
    SENSOR = 5       #: filters what the dynamometer reports (the force rate it sees)


#: every effect registered, by name (:mod:`plant.catalogue` fills it with the built-ins first and
#: orders it; plug-ins join it through :mod:`plant.loader`)
CATALOGUE: dict[str, type["Effect"]] = {}


def register(cls: type["Effect"]) -> type["Effect"]:
    """Class decorator: add an effect to the catalogue under ``cls.name`` now (optional in a
    plug-in module: the loader registers every effect class the module defines)."""
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
    #: FLOW stage: the parameters :meth:`prepare` reads (its ``aux``), e.g. a boost's decay but
    #: not its size, which only :meth:`gain` uses; ``None``: all of them. A fit reuses the
    #: prepared flow while it moves only the others (:meth:`prepared_values`); the plug-in
    #: check verifies the claim (moving any other parameter leaves ``aux`` as it was)
    prepared_from: ClassVar[tuple[str, ...] | None] = None

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

    @classmethod
    def own_evidence(cls, values: Mapping[str, float]) -> tuple[bool, str]:
        """Whether the fitted ``values`` (``{"name.param": value}``) show what only this effect
        can do, and in words: ``(False, why)`` when they make it one of its simpler look-alikes
        with a spare parameter (an overdamped resonance is a lag), which the diagnosis then
        does not let in; ``(True, what)`` when they show its own evidence (``what`` says why
        it is preferred over its look-alikes; may be empty). Default: ``(True, "")``."""
        return True, ""

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

    def prepared_values(self) -> tuple[float, ...]:
        """The values the drive depends on: for a FLOW effect those :meth:`prepare` reads
        (:attr:`prepared_from`; none if it does not override it), else all of them."""
        if self.stage is not Stage.FLOW:
            return tuple(self.values.values())
        if type(self).prepare is Effect.prepare:
            return ()
        if self.prepared_from is None:
            return tuple(self.values.values())
        return tuple(self.values[k] for k in self.prepared_from)

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


def separating_experiment(a: str, b: str) -> str:
    """What tells ``a`` from ``b`` (effects, or the base model's ``gain``, ``delay``,
    ``trend``): either effect's :attr:`~plant.Effect.look_alikes`, else a richer excitation."""
    for x, y in ((a, b), (b, a)):
        cls = CATALOGUE.get(x)
        if cls is not None and y in cls.look_alikes:
            return cls.look_alikes[y]
    return DEFAULT_EXPERIMENT
