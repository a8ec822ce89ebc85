"""A plug-in effect the catalogue lacks, for the tests (tests/test_rig_unseen_effects.py): a
pilot-operated check valve in the actuator's line that opens only a moment after the rod
reverses. Its action is local in time: nothing until ``after`` seconds past each reversal of
the channel's own rod, then a pulse of extra flow for ``width`` seconds, then nothing again.

Written on its own, not from the catalogue's reversal laws (which boost the gain from the
reversal on and decay): the time since the reversal is counted here step by step, and the pulse
is a window, not a decay."""
import numpy as np

from plant import Effect, Param, Stage


class CheckValve(Effect):
    r"""The volume trapped behind a pilot-operated check valve is released a moment after the
    rod reverses: a pulse of extra force rate ``g·p·u_ref`` in the new direction (a fixed force
    ``g·p·u_ref·w`` per reversal, whatever the command), from ``a`` to ``a + w`` after it:

    .. math::  G = 1 + p\,\frac{u_{ref}}{\max(|q|,\ 0.5\,\%)}\,W(s),\qquad
               W(s) = [a \le s < a + w],\quad u_{ref} = 10\ \%,

    ``s`` the time since the flow command last changed sign (a zero keeps the last sign),
    ``W`` averaged over each step it covers in part."""

    name = "check_valve"
    stage = Stage.FLOW
    summary = "a pulse of extra flow from a to a + w after each reversal of the rod (check valve)"
    U_REF = 10.0
    params = (Param("pulse", 0.5, 0.0, 20.0, "1", "extra force rate p, in g·u_ref"),
              Param("after", 0.05, 0.0, 1.0, "s", "the pulse begins a after the reversal"),
              Param("width", 0.08, 0.001, 1.0, "s", "the pulse lasts w"))

    def init_state(self, n, u0):
        return {"sign": np.sign(np.asarray(u0, float)), "since": np.full(n, np.inf)}

    def prepare(self, q, dt, state, command=None, t=None):
        n, K = q.shape
        sign, since = state["sign"].copy(), state["since"].copy()
        out = np.empty((n, K))
        a, b = self.after, self.after + self.width
        for k in range(K):
            now = np.sign(q[:, k])
            turned = (now != 0) & (sign != 0) & (now != sign)
            since = np.where(turned, 0.0, since)
            sign = np.where(now != 0, now, sign)
            # the share of the step [since, since + dt) inside the window [a, b)
            lo, hi = np.maximum(since, a), np.minimum(since + dt, b)
            out[:, k] = np.clip(hi - lo, 0.0, dt) / dt
            since = since + dt
        state["sign"], state["since"] = sign, since
        return out

    def gain(self, q, aux, y):
        return 1.0 + self.pulse * self.U_REF / np.maximum(np.abs(q), 0.5) * aux
