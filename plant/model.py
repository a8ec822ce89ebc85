r"""The plant model: the paper's base model plus effects from the catalogue.

One implementation serves both the emulator (a few steps per control period, ``n = 1``) and the
analysis (whole records cut into windows that are simulated side by side, ``n`` = number of
windows). Time is discrete with step ``dt``; the command is held over each step (zero-order hold,
as a CAN command is), and the delay is realised exactly for that: with ``τ = (m + f)·dt`` the
average of ``u(t − τ)`` over step ``k`` is ``(1 − f)·u[k−m] + f·u[k−m−1]``, so τ is continuous
(fit by least squares, not only whole samples). The force after step k is

.. math::  y[k+1] = y[k] + dt\cdot\big(g\,q[k]\prod_i G_i + \Delta + \sum_j D_j\big).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping

import numpy as np
from scipy.signal import lfilter

from core.jit import njit
from core.kept import Kept

from .catalogue import effect_class, order
from .contract import Effect, Stage
from .params import ModelError, Param

#: The paper's model (eq. 1) with the constant trend Δ of eq. 2.
BASE_PARAMS: tuple[Param, ...] = (
    Param("g", 120.0, 0.01, 1e5, "kgf/(%·s)", "integrator gain g", log=True),
    Param("tau", 0.05, 0.0, 2.0, "s", "transport delay τ"),
    Param("delta", 0.0, -1e4, 1e4, "kgf/s", "constant force trend Δ (valve null offset and the like)"),
)


#: the force-dependent integration (:meth:`PlantModel._integrate_in_blocks`) stops iterating a
#: block when a pass moves the force by less than this share of its size (plus 1 kgf)
INTEGRATION_TOL = 1e-12
#: its first and its largest block, steps
INTEGRATION_FIRST_BLOCK = 1024
INTEGRATION_MAX_BLOCK = 4096

#: the factors of FLOW effects that do not read the force, by effect, values and drive arrays
#: (:func:`_flow_factor`): a fit's Jacobian moves one parameter at a time, and for most
#: columns (g, Δ, a force law, a sensor, another effect's value) these factors stay the same
_FACTORS = Kept(48)


def _flow_factor(eff: Effect, q: np.ndarray, aux) -> np.ndarray:
    """``eff.gain(q, aux, None)`` of a FLOW effect that does not read the force, kept for
    read-only arrays ``q`` and ``aux`` (a fit's cached drives, :mod:`analysis.identification.windows`)
    and the effect's type and values (:class:`core.kept.Kept`): the gain is a function of them
    alone (the contract). Arrays that may still change (the emulator's blocks) are not kept:
    the gain is computed."""
    return _FACTORS.get((q, aux), (type(eff), tuple(eff.values.items())),
                        lambda: np.asarray(eff.gain(q, aux, None)))


@dataclass
class PlantState:
    """Everything a simulation carries from one block to the next (``n`` trajectories)."""

    y: np.ndarray                 #: force, kgf, shape (n,)
    t: np.ndarray                 #: time since the run (record) began, s, shape (n,)
    history: np.ndarray           #: past commands for the delay line, shape (n, H)
    effects: list[dict] = field(default_factory=list)
    reading: np.ndarray | None = None  #: what the dynamometer reports (y through SENSOR effects)
    #: the valve stage's output of the last step (the fraction of the delay after the valve
    #: reads it); None: not yet known, the valve's first output stands in (settled on ``u0``)
    valve_last: np.ndarray | None = None


@dataclass
class Drive:
    """The input side of a block: flow command after the valve stage and auxiliary signals."""

    q: np.ndarray                 #: flow command, %, (n, K)
    aux: list                     #: per FLOW effect, its prepared signal (or None)
    dist: np.ndarray | None       #: summed DISTURBANCE force rate, kgf/s, (n, K) or None


class PlantModel:
    """``dy/dt = g·u(t−τ) + Δ`` refined by catalogue effects (see :mod:`plant.contract`, :mod:`plant.effects`)."""

    def __init__(self, g: float = 120.0, tau: float = 0.05, delta: float = 0.0,
                 effects: Iterable[Effect] = ()) -> None:
        base = dict(g=g, tau=tau, delta=delta)
        self.g, self.tau, self.delta = (p.validate(base[p.name], "base") for p in BASE_PARAMS)
        effects = list(effects)
        names = [e.name for e in effects]
        dupes = {n for n in names if names.count(n) > 1}
        if dupes:
            raise ModelError(f"effect(s) listed twice: {', '.join(sorted(dupes))}")
        self.effects: list[Effect] = sorted(effects, key=lambda e: (e.stage, order(e.name)))
        # per stage, once (the emulator steps a few samples per SYNC: this is its hot path)
        self._n_valve = sum(e.stage is Stage.VALVE for e in self.effects)   # the first ones
        self._flow = [e for e in self.effects if e.stage is Stage.FLOW]
        self._force = [e for e in self.effects if e.stage is Stage.FORCE]
        self._needs_time = any(e.stage is Stage.DISTURBANCE or e.reads_time for e in self.effects)
        self._sensor = [i for i, e in enumerate(self.effects) if e.stage is Stage.SENSOR]

    # -- description --------------------------------------------------------------------------
    @property
    def spec(self) -> str:
        """The model as written on the command line, e.g. ``base+reversal+deadzone``."""
        return "+".join(["base"] + [e.name for e in self.effects])

    def __repr__(self) -> str:
        return f"PlantModel({self.spec}, {self.params()})"

    @classmethod
    def from_spec(cls, spec: str, values: Mapping[str, float] | None = None) -> "PlantModel":
        """Build from ``"base+reversal+deadzone"`` and optional ``{"g": .., "reversal.boost": ..}``."""
        parts = [p.strip() for p in (spec or "").split("+") if p.strip()]
        if not parts or parts[0] != "base":
            raise ModelError(
                f"model {spec!r} must start with 'base', e.g. 'base' or 'base+reversal+lag'")
        values = dict(values or {})
        base = {p.name: values.pop(p.name, p.default) for p in BASE_PARAMS}
        effects = []
        for name in parts[1:]:
            klass = effect_class(name)
            own = {k.split(".", 1)[1]: values.pop(k) for k in list(values)
                   if k.startswith(name + ".")}
            effects.append(klass(**own))
        if values:
            raise ModelError(
                f"parameter(s) {', '.join(sorted(values))} do not belong to model {spec!r}")
        return cls(effects=effects, **base)

    def effect(self, name: str) -> Effect | None:
        return next((e for e in self.effects if e.name == name), None)

    # -- parameters as a flat vector (for fitting) ---------------------------------------------
    def param_specs(self) -> list[tuple[str, Param]]:
        out = [(p.name, p) for p in BASE_PARAMS]
        for e in self.effects:
            out += [(f"{e.name}.{p.name}", p) for p in e.params]
        return out

    def params(self) -> dict[str, float]:
        out = {"g": self.g, "tau": self.tau, "delta": self.delta}
        for e in self.effects:
            out.update({f"{e.name}.{k}": v for k, v in e.values.items()})
        return out

    def with_params(self, values: Mapping[str, float]) -> "PlantModel":
        """A copy with some parameters replaced (names as in :meth:`params`)."""
        merged = self.params()
        unknown = set(values) - set(merged)
        if unknown:
            raise ModelError(f"model {self.spec} has no parameter(s) {', '.join(sorted(unknown))}")
        merged.update(values)
        return PlantModel.from_spec(self.spec, merged)

    def drive_key(self) -> tuple:
        """What :meth:`drive` depends on besides the command: the delay and the values of the
        effects it runs (VALVE, FLOW preparation: :meth:`Effect.prepared_values`, DISTURBANCE).
        Two models with equal keys give the same drive for the same commands (the fit's
        Jacobian moves one parameter at a time: for g, Δ, a boost's size and the
        force-dependent laws the drive is the same)."""
        return (self.tau,) + tuple((e.name, e.prepared_values()) for e in self.effects
                                   if e.stage in (Stage.VALVE, Stage.FLOW, Stage.DISTURBANCE))

    # -- simulation ----------------------------------------------------------------------------
    def _delay_split(self, dt: float) -> tuple[int, float]:
        steps = self.tau / dt
        m = int(math.floor(steps + 1e-12))
        return m, steps - m

    def delay_steps(self, dt: float) -> int:
        """Whole steps of ``dt`` in the delay: the command of step k first acts in step k + m,
        so the force over the next m steps does not depend on commands not yet given (0 when
        an effect reads the undelayed command)."""
        if any(e.reads_command for e in self.effects):
            return 0
        return self._delay_split(dt)[0]

    def new_state(self, n: int, dt: float, y0: float | np.ndarray = 0.0,
                  u0: float | np.ndarray = 0.0, t0: float | np.ndarray = 0.0) -> PlantState:
        """Initial state of ``n`` trajectories at force ``y0``, with the command ``u0`` held
        before time ``t0`` (the delay line is filled with it)."""
        m, _ = self._delay_split(dt)
        u_init = np.broadcast_to(np.asarray(u0, float), (n,)).copy()
        hist = np.repeat(u_init[:, None], m + 1, axis=1)
        y = np.broadcast_to(np.asarray(y0, float), (n,)).copy()
        return PlantState(
            y=y,
            t=np.broadcast_to(np.asarray(t0, float), (n,)).copy(),
            history=hist,
            effects=[e.init_state(n, u_init) for e in self.effects],
            reading=y.copy(),
        )

    def drive(self, u: np.ndarray, dt: float, state: PlantState) -> Drive:
        """Input side for a block of commands ``u`` (n, K): delay, VALVE, FLOW preparation and
        DISTURBANCE terms. Advances the input-side state and the time."""
        u = np.asarray(u, float)
        n, K = u.shape
        m, f = self._delay_split(dt)
        H = state.history.shape[1]
        if H < m + 1:  # parameters changed since the state was made: extend with the oldest
            pad = np.repeat(state.history[:, :1], m + 1 - H, axis=1)
            state.history = np.concatenate([pad, state.history], axis=1)
            H = m + 1
        ext = np.concatenate([state.history, u], axis=1)
        # The delay is split: its whole steps m before the valve stage, its fraction f after.
        # A time-invariant valve commutes with a delay, and so the valve effects see the held
        # command exactly as it is (a step at a step boundary: a slew ramp starts where it
        # should, a dead zone cuts the held value, not an average across the step), and the
        # fraction shifts their output by interpolating its step averages (exact for outputs
        # that are straight within two steps: held values and ramps). Step k reads ext[H+k−m].
        a = H - m
        q = ext[:, a:a + K].copy()
        state.history = ext[:, -H:].copy()
        aux: list = []
        dist = None
        t = None
        if self._needs_time:
            t = state.t[:, None] + dt * np.arange(K)[None, :]
        # the valve runs f·dt ahead of the plant: what it does at t reaches the flow at t + f·dt
        t_valve = t + f * dt if (t is not None and f) else t
        effects = list(zip(self.effects, state.effects))     # sorted by stage: VALVE first
        nv = self._n_valve
        for eff, est in effects[:nv]:
            q = eff.shape(q, dt, est, **({"t": t_valve} if eff.reads_time else {}))
        q = self._fractional_delay(q, f, state)
        for eff, est in effects[nv:]:
            extra = {"t": t} if eff.reads_time else {}
            if eff.stage is Stage.FLOW:
                if eff.reads_command:
                    extra["command"] = u
                aux.append(eff.prepare(q, dt, est, **extra))
            elif eff.stage is Stage.DISTURBANCE:
                d = eff.disturbance(t, dt)
                dist = d if dist is None else dist + d
        state.t = state.t + K * dt
        return Drive(q=q, aux=aux, dist=dist)

    @staticmethod
    def _fractional_delay(v: np.ndarray, f: float, state: PlantState) -> np.ndarray:
        """The valve stage's output ``v`` (n, K) delayed by the fraction ``f`` of a step: each
        step's average is ``(1 − f)·v[k] + f·v[k − 1]``, with ``v[−1]`` the last step of the
        previous block (kept in ``state.valve_last``)."""
        last = state.valve_last if state.valve_last is not None else v[:, 0]
        state.valve_last = v[:, -1].copy()
        if not f:
            return v
        prev = np.concatenate([last[:, None], v[:, :-1]], axis=1)
        return (1.0 - f) * v + f * prev

    def integrate(self, drv: Drive, y0: np.ndarray, dt: float,
                  guess: np.ndarray | None = None, growth: list | None = None) -> np.ndarray:
        """Force trajectory (n, K+1) from ``y0`` (n,) under the block's drive. ``guess``: a
        trajectory of the same shape near the answer (the last one of a fit, whose next
        simulation moves one parameter a little), where the force-dependent integration starts
        (:meth:`_integrate_in_blocks`); the answer does not depend on it. ``growth``: a list
        that gets the recursion's growth factors along the answer, ``1 + dt·f'`` (n, K), when
        the rate depends on the force (for :meth:`integrate_linearised`)."""
        y0 = np.asarray(y0, float)
        n, K = drv.q.shape
        lam = self.force_decay()
        if lam is not None:   # the force terms are -λ·y: integrated exactly below
            rate = self._rate(drv.q, drv.aux, drv.dist, None, force_terms=False)
            out = np.empty((n, K + 1))
            out[:, 0] = y0
            if lam == 0.0:
                np.cumsum(rate * dt, axis=1, out=out[:, 1:])
                out[:, 1:] += y0[:, None]
            else:  # y[k+1] = (1 - λ dt) y[k] + dt·rate[k]  (linear: one filter pass)
                a = 1.0 - lam * dt
                out[:, 1:], _ = lfilter([dt], [1.0, -a], rate, axis=1, zi=(a * y0)[:, None])
            return out
        return self._integrate_in_blocks(drv, y0, dt, guess, growth)

    def integrate_linearised(self, drv: Drive, y0: np.ndarray, dt: float, base: np.ndarray,
                             growth: np.ndarray) -> np.ndarray:
        r"""The force trajectories (n, K+1) from ``y0`` (n,), linearised about ``base``: the
        answer of :meth:`integrate` for a model (or drive) near the one whose answer ``base`` is,
        with ``growth`` (n, K) that one's growth factors ``1 + dt·f'`` along it
        (``integrate(..., growth=[])``). One pass of the linear recursion
        ``y[k+1] = ŷ_k + dt·f_k(ŷ_k) + (1 + dt·f'_k)·(y[k] − ŷ_k)``, ``ŷ = base``, this model's
        rate ``f`` along the base: the tangent-linear model, exact to first order in the change
        of the parameters, the drive and the start (second-order terms left out: of the size of
        a forward difference's own error when they are its step). For a finite-difference
        column of a fit's Jacobian this is the whole simulation's cost but one rate evaluation
        (:func:`analysis.identification.windows.linearised_columns`). Only for a model whose
        rate depends on the force (:attr:`depends_on_force`)."""
        rate = self._force_dependent_rate(drv)
        n, K = drv.q.shape
        out = np.empty((n, K + 1))
        out[:, 0] = y0
        guess = np.ascontiguousarray(base[:, :-1])
        with np.errstate(all="ignore"):
            f = rate(0, K, guess)
            f *= dt
            _newton_pass(growth, f, guess, out)
        return out

    def force_decay(self) -> float | None:
        """``λ`` (1/s) when the force rate is linear in the force, ``r(t) − λ·y``: no FLOW
        effect reads the force and every FORCE term is a decay (0 without FORCE effects);
        None when the rate depends on the force otherwise (:attr:`depends_on_force`)."""
        if any(e.depends_on_force for e in self._flow):
            return None
        rates = [e.decay_rate() for e in self._force]
        if any(r is None for r in rates):
            return None
        return sum(rates)

    def _integrate_in_blocks(self, drv: Drive, y0: np.ndarray, dt: float,
                             guess: np.ndarray | None = None,
                             growth: list | None = None) -> np.ndarray:
        r"""The force when its rate depends on it: the explicit recursion
        ``y[k+1] = y[k] + dt·f_k(y[k])`` of every step, solved a block of steps at a time.

        Each pass linearizes the rate about a guess ``ŷ`` of the block's trajectory,
        ``f_k(y) ≈ f_k(ŷ_k) + f'_k·(y − ŷ_k)`` (``f'`` by a forward difference), and solves the
        linear recursion that results for the correction ``e = y − ŷ`` in closed form,
        ``e[k+1] = (1 + dt·f'_k)·e[k] + (ŷ_k + dt·f_k(ŷ_k) − ŷ_{k+1})``, ``e`` at the block's
        start 0 (Newton's method on the whole block; the recursion runs compiled,
        :func:`_newton_pass`). Its fixed point is the step-by-step solution exactly; a rate linear
        in the force is solved in one pass, a smooth one in two or three; and as the recursion
        is causal, each pass makes at least one more step exact whatever the law. Passes stop
        when one changes the trajectory by less than :data:`INTEGRATION_TOL` of its size
        (1e-9 kgf at 1000 kgf: far below any dynamometer's resolution, and the fit's finite
        differences move the force by 1e-5 kgf or more). All hooks are called on blocks of
        shape ``(n, B)``, as elsewhere.
        """
        n, K = drv.q.shape
        rate = self._force_dependent_rate(drv)
        out = np.empty((n, K + 1))
        out[:, 0] = y0
        kept = np.empty((n, K)) if growth is not None else None
        warm = guess is not None and guess.shape == out.shape and bool(np.all(np.isfinite(guess)))
        a, block = 0, K if warm else INTEGRATION_FIRST_BLOCK
        with np.errstate(all="ignore"):   # a guess may stray where the law is steep
            while a < K:
                b = min(K, a + block)
                seg = out[:, a:b + 1]            # a view: seg[:, 0] is known
                start = seg[:, :1]
                if warm:
                    seg[:, 1:] = guess[:, 1:]
                    warm = False
                else:  # the rate at the block's start, held (explicit Euler over the block)
                    seg[:, 1:] = start + rate(a, a + 1, start) * (dt * np.arange(1, b - a + 1))
                for _ in range(b - a + 1):   # each pass makes one more step exact, at least
                    guess = seg[:, :-1].copy()
                    size = np.max(np.abs(guess), initial=0.0, where=np.isfinite(guess)) + 1.0
                    h = 1e-6 * size
                    f = rate(a, b, guess)
                    grow = rate(a, b, guess + h)    # 1 + dt·f', f' by a forward difference
                    grow -= f
                    grow *= dt / h
                    grow += 1.0
                    f *= dt
                    if _newton_pass(grow, f, guess, seg) <= INTEGRATION_TOL * size:
                        break
                if kept is not None:
                    kept[:, a:b] = grow
                a = b
                block = min(2 * block, INTEGRATION_MAX_BLOCK)
        if growth is not None:
            growth.append(kept)
        return out

    def _force_dependent_rate(self, drv: Drive):
        """``rate(a, b, y)``: the force rate over steps ``a`` to ``b`` of the drive at the
        forces ``y`` (n, b − a), for :meth:`_integrate_in_blocks`."""
        # what does not depend on the force, once: g·q times the other FLOW factors, Δ and the
        # disturbances; per pass only the force-dependent factors and terms
        static = self.g * drv.q
        varying = []
        for eff, a in zip(self._flow, drv.aux):
            if eff.depends_on_force:
                varying.append((eff, a))
            else:
                static = static * _flow_factor(eff, drv.q, a)
        added = self.delta if drv.dist is None else self.delta + drv.dist
        force = self._force

        def rate(a: int, b: int, y: np.ndarray) -> np.ndarray:
            r = static[:, a:b]
            for eff, aux in varying:
                r = r * eff.gain(drv.q[:, a:b], None if aux is None else aux[:, a:b], y)
            r = r + (added if np.ndim(added) == 0 else added[:, a:b])
            for eff in force:
                r = r + eff.force_rate(y)
            return r

        return rate

    def sense(self, y: np.ndarray, dt: float, start: np.ndarray,
              states: list[dict] | None = None) -> np.ndarray:
        """What the dynamometer reports along force trajectories ``y`` (n, K+1): ``y`` itself,
        or through the SENSOR effects, from the reading ``start`` (n,). ``states``: the effects'
        states, aligned with :attr:`effects` (None: each filter starts settled)."""
        if not self._sensor:
            return y
        rate = np.diff(y, axis=1) / dt
        for i in self._sensor:
            rate = self.effects[i].filter_rate(rate, dt, states[i] if states is not None else {})
        out = np.empty_like(y)
        out[:, 0] = start
        np.cumsum(rate * dt, axis=1, out=out[:, 1:])
        out[:, 1:] += np.asarray(start, float)[:, None]
        return out

    def advance(self, state: PlantState, u: np.ndarray, dt: float) -> np.ndarray:
        """Advance ``state`` by the command block ``u`` (n, K); returns the dynamometer's
        reading after each step (the force, unless a SENSOR effect filters it), shape (n, K).
        This is what the emulator calls every control period."""
        y = self.integrate(self.drive(u, dt, state), state.y, dt)
        state.y = y[:, -1].copy()
        if self._sensor:
            y = self.sense(y, dt, state.reading, state.effects)
        state.reading = y[:, -1].copy()
        return y[:, 1:]

    def simulate(self, u: np.ndarray, dt: float, y0: float = 0.0, u_before: float | None = None,
                 t0: float = 0.0) -> np.ndarray:
        """Free-run simulation of one record: ``y[k]`` (N,) for commands ``u[k]`` (N,), starting
        at ``y[0] = y0``; the command before the record is taken as ``u_before`` (default u[0])."""
        u = np.asarray(u, float)
        state = self.new_state(1, dt, y0, u[0] if u_before is None else u_before, t0)
        y = self.integrate(self.drive(u[None, :], dt, state), state.y, dt)
        return self.sense(y, dt, state.reading, state.effects)[0, :-1]

    def simulate_windows(self, u: np.ndarray, y: np.ndarray, dt: float, window: int,
                         t0: float = 0.0, u_before: float | None = None) -> np.ndarray:
        """Windowed free-run simulation: the record is cut into windows of ``window`` samples,
        each simulated from the measured force at its first sample, the input history (delay,
        valve states) running continuously over the whole record. Returns ŷ (N,)."""
        u = np.asarray(u, float)
        y = np.asarray(y, float)
        N = len(u)
        window = max(2, min(int(window), N))
        state = self.new_state(1, dt, 0.0, u[0] if u_before is None else u_before, t0)
        drv = self.drive(u[None, :], dt, state)
        nw = -(-N // window)
        pad = nw * window - N

        def cut(a: np.ndarray | None) -> np.ndarray | None:
            if a is None:
                return None
            a = a[0]
            if pad:
                a = np.concatenate([a, np.repeat(a[-1:], pad)])
            return a.reshape(nw, window)

        wdrv = Drive(q=cut(drv.q), aux=[cut(a) for a in drv.aux], dist=cut(drv.dist))
        starts = y[np.arange(nw) * window]
        sensor = (self.window_filter_states(drv, y, dt, np.arange(nw) * window)
                  if self._sensor else None)
        yy = self.integrate_from_readings(wdrv, starts, dt, sensor)[:, :-1]
        return yy.reshape(-1)[:N]

    def integrate_from_readings(self, drv: Drive, readings: np.ndarray, dt: float,
                                sensor: list[dict] | None) -> np.ndarray:
        """Readings along windows (n, K+1) that start from measured ``readings`` (n,): the force
        trajectories from the force under each reading (:meth:`force_under`), through the
        SENSOR filters whose states at the starts are ``sensor`` (None: no SENSOR effect)."""
        y = self.integrate(drv, self.force_under(readings, sensor), dt)
        return y if sensor is None else self.sense(y, dt, readings, sensor)

    def force_under(self, readings: np.ndarray, sensor: list[dict] | None) -> np.ndarray:
        """The force under the dynamometer's ``readings`` (n,) for the SENSOR filters' states
        ``sensor`` (None: no SENSOR effect, the readings themselves)."""
        y0 = np.asarray(readings, float)
        if sensor is not None:
            for i in self._sensor:
                y0 = y0 + self.effects[i].force_minus_reading(sensor[i])
        return y0

    @property
    def depends_on_force(self) -> bool:
        """True if the force rate depends on the force (a FLOW law of the force, or a FORCE term
        that is not a plain decay): the integration then solves for it
        (:meth:`_integrate_in_blocks`)."""
        return self.force_decay() is None

    @property
    def has_sensor_effects(self) -> bool:
        return bool(self._sensor)

    def _rate(self, q: np.ndarray, aux: list, dist: np.ndarray | None, y: np.ndarray | None,
              force_terms: bool = True) -> np.ndarray:
        """The force rate for flow command ``q``, the FLOW effects' ``aux``, the disturbance
        rate ``dist`` and the force ``y`` (all the same shape: one step, or many at once);
        ``force_terms=False`` leaves out the FORCE effects' terms."""
        r = self.g * q
        for eff, a in zip(self._flow, aux):
            r = r * (eff.gain(q, a, y) if eff.depends_on_force else _flow_factor(eff, q, a))
        r = r + self.delta
        if dist is not None:
            r = r + dist
        if force_terms:
            for eff in self._force:
                r = r + eff.force_rate(y)
        return r

    def flow(self, q: np.ndarray, aux: list, y: np.ndarray | None) -> np.ndarray:
        """The flow command after the FLOW effects, ``w = q·Π G_i(q, y)``: what the gain
        multiplies (``g`` here, a row of ``G`` in a rig: :mod:`plant.rig`)."""
        w = q
        for eff, a in zip(self._flow, aux):
            w = w * (eff.gain(q, a, y) if eff.depends_on_force else _flow_factor(eff, q, a))
        return w

    def rate_terms(self, dist: np.ndarray | None, y: np.ndarray) -> np.ndarray:
        """The force rate besides the flow's: ``Δ`` + the disturbances + the FORCE terms at
        the force ``y``."""
        r = np.full(np.shape(y), self.delta)
        if dist is not None:
            r = r + dist
        for eff in self._force:
            r = r + eff.force_rate(y)
        return r

    def rate_along(self, drv: Drive, y: np.ndarray) -> np.ndarray:
        """The force rate over each step of the drive (n, K) if the force were ``y`` (n, K) at
        the steps' starts: all steps at once, no integration."""
        return self._rate(drv.q, drv.aux, drv.dist, y)

    def window_filter_states(self, drv: Drive, y: np.ndarray, dt: float,
                             steps: np.ndarray) -> list[dict]:
        """The SENSOR filters' states at the window starts ``steps`` of one record (continuous
        drive ``drv``, shape (1, K)), run over the rate along the measured force ``y`` (K,)
        (exact when the rate does not depend on the force). Aligned with :attr:`effects`, for
        :meth:`sense`."""
        rate = self.rate_along(drv, np.asarray(y, float)[None, :drv.q.shape[1]])
        states: list[dict] = [{} for _ in self.effects]
        for i in self._sensor:
            eff = self.effects[i]
            states[i] = eff.filter_states(rate, dt, steps)
            rate = eff.filter_rate(rate, dt, {})
        return states


@njit
def _newton_pass(grow: np.ndarray, step: np.ndarray, guess: np.ndarray, seg: np.ndarray) -> float:
    """One pass of the linearised recursion from ``seg[:, 0]``:
    ``y[k+1] = y[k] + step[k] + (grow[k] − 1)·(y[k] − guess[k])`` into ``seg[:, 1:]`` (n, B),
    ``step = dt·f(guess)``, ``grow = 1 + dt·f'(guess)``. Where the guess was the answer, so is
    the pass (a step is computed from values, not as a change of the old one: the steps made
    exact stay exact whatever the rest held). A value that is not finite is replaced by the one
    before it (a guess for the next pass). Returns the largest change (inf after a
    replacement: not converged)."""
    n, B = grow.shape
    largest = 0.0
    for i in range(n):
        y = seg[i, 0]
        for k in range(B):
            new = y + step[i, k] + (grow[i, k] - 1.0) * (y - guess[i, k])
            if np.isfinite(new):
                change = abs(new - seg[i, k + 1])
                y = new
            else:
                change = np.inf
            if not change <= largest:      # also a NaN change
                largest = np.inf if change != change else change
            seg[i, k + 1] = y
    return largest
