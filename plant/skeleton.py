"""``stand effects --new NAME --stage STAGE``: a commented effect plug-in to start from.

The skeleton is a working effect (it passes the check on load), with a sample law for its
stage that the user replaces by theirs; docs/your-own-effect.md walks through one.
"""
from __future__ import annotations

import re

from .contract import Stage
from .loader import NAME_RE, PluginError

_HEAD = '''"""{name}: <one line: what this effect models>.

An effect plug-in for hydrostand (docs/your-own-effect.md). Use it with any command that takes a
model, e.g.::

    stand diagnose DATA --effects {name}.py
    stand fit DATA --effects {name}.py --model base+{name}
    stand emulate --effects {name}.py --model base+{name} --set {name}.{first}=...
"""
import numpy as np

from plant import Effect, Param, Stage, register


@register
class {cls}(Effect):
    r"""<Physics: what happens in the stand, and why.>

    <The law, as the hook below computes it:>

    .. math::  {math}

    <How it shows in data: where a model without it is wrong, and what tells it from the
    effects it looks like.>
    """

    #: written --model base+{name}; its parameters are {name}.NAME
    name = "{name}"
    #: {stage_doc}
    stage = Stage.{stage}
    summary = "<one line for `stand effects`>"
    # Param(name, default, lower, upper, unit, doc, log=False): the fit explores [lower, upper],
    # so make the bounds what is physical; log=True for a positive scale (a time constant, a
    # frequency). A parameter in Hz also starts where the diagnosis found the residual periodic.
    params = (
{params}
    )

    # Every hook works on arrays of shape (n, K): n trajectories (the emulator: 1; the fit:
    # the windows side by side) by K steps of dt seconds, and must return that shape.
{hook}
    # Optional, see docs/your-own-effect.md:
    # look_alikes = {{"gain": "the experiment that tells the two apart"}}
    #
    # @classmethod
    # def start_grid(cls, s, base):
    #     """Where the fit starts its local searches: [{{"{name}.{first}": value, ...}}, ...]
    #     (default: each parameter's default, and values across its bounds)."""
'''

_STAGES = {
    Stage.VALVE: dict(
        stage_doc="maps the delayed command u (%) to the flow command q (%)",
        math=r"q = L\,\tanh(u(t-\tau)/L)",
        params='        Param("limit", 30.0, 1.0, 200.0, "%", "flow command the valve tends to", log=True),',
        hook='''    def shape(self, q, dt, state, t=None):
        """The flow command for the (delayed) command block q (n, K), %."""
        return self.limit * np.tanh(q / self.limit)
'''),
    Stage.FLOW: dict(
        stage_doc="a factor G on the flow-driven force rate g·q",
        math=r"\dot y = g\,q\,G,\qquad G = 1 + k\,|q|/100",
        params='        Param("k", 0.2, -0.9, 5.0, "1", "relative change of the gain at a full opening"),',
        hook='''    def gain(self, q, aux, y):
        """The factor G on g·q for the flow commands q (n, K); aux is what prepare() returned
        (override prepare(self, q, dt, state) for a factor with a memory); y the force (kgf),
        given only when depends_on_force = True."""
        return 1.0 + self.k * np.abs(q) / 100.0
'''),
    Stage.DISTURBANCE: dict(
        stage_doc="adds a force rate that depends on time only",
        math=r"y_d = A\sin(2\pi f t + \varphi),\qquad \dot y \mathrel{+}= \dot y_d",
        params='''        Param("amplitude", 20.0, 0.0, 5000.0, "kgf", "amplitude A"),
        Param("frequency", 1.0, 0.05, 50.0, "Hz", "frequency f", log=True),
        Param("phase", 0.0, -3.1416, 3.1416, "rad", "phase φ at the start of a record"),''',
        hook='''    def disturbance(self, t, dt):
        """The force rate (kgf/s) averaged over the steps that start at t (n, K, seconds since
        the record began) and last dt: here the step's change of A·sin(2πft + φ) over dt."""
        w = 2 * np.pi * self.frequency
        return self.amplitude * (np.sin(w * (t + dt) + self.phase)
                                 - np.sin(w * t + self.phase)) / dt
'''),
    Stage.FORCE: dict(
        stage_doc="adds a force rate that depends on the force",
        math=r"\dot y \mathrel{+}= -c\,\tanh(y/Y)",
        params='''        Param("rate", 50.0, 0.0, 5000.0, "kgf/s", "largest drift rate c"),
        Param("scale", 1000.0, 10.0, 1e5, "kgf", "force Y at which the drift is 76 % of c", log=True),''',
        hook='''    def force_rate(self, y):
        """The force rate (kgf/s) added at the force y (kgf), same shape as y."""
        return -self.rate * np.tanh(y / self.scale)
'''),
    Stage.SENSOR: dict(
        stage_doc="filters what the dynamometer reports",
        math=r"T\,\dot y_m = y - y_m",
        params='        Param("time_constant", 0.01, 1e-4, 1.0, "s", "filter time constant T", log=True),',
        hook='''    # A sensor filter works on the force rate; its state x is the reading's rate.
    def filter_rate(self, rate, dt, state):
        """The reading's rate over each step from the force rate (n, K); state["x"] (n,)
        carries the filter from block to block (absent: start settled)."""
        a = np.exp(-dt / self.time_constant)
        x = state.get("x", rate[:, 0].copy())
        out = np.empty_like(rate)
        for k in range(rate.shape[1]):
            x = a * x + (1 - a) * rate[:, k]
            out[:, k] = x
        state["x"] = x
        return out

    def filter_states(self, rate, dt, steps):
        """The state at the start of the given steps of one record's rate (1, K)."""
        a = np.exp(-dt / self.time_constant)
        x, xs = rate[0, 0], np.empty(rate.shape[1])
        for k in range(rate.shape[1]):
            xs[k] = x
            x = a * x + (1 - a) * rate[0, k]
        return {"x": xs[steps]}

    def force_minus_reading(self, state):
        """Force minus reading for the state: T·ẏ_m."""
        return self.time_constant * state["x"]
'''),
}


def skeleton(name: str, stage: str) -> str:
    """The source of a plug-in effect ``name`` at ``stage`` (valve, flow, disturbance, force,
    sensor)."""
    if not NAME_RE.match(name or "") or name == "base":
        raise PluginError(f"--new {name!r}: an effect name is lower-case letters, digits and _, "
                          "starting with a letter (e.g. pump_ripple)")
    try:
        st = Stage[stage.upper()]
    except KeyError:
        raise PluginError(f"--stage {stage!r}: give one of "
                          f"{', '.join(s.name.lower() for s in Stage)}") from None
    spec = _STAGES[st]
    first = re.search(r'Param\("(\w+)"', spec["params"]).group(1)
    cls = "".join(part.capitalize() for part in name.split("_"))
    return _HEAD.format(name=name, cls=cls, stage=st.name, first=first, **spec)
