r"""Stability margins of the station's loops: one loop's in discrete time, and N loops together
by their characteristic loci.

**One loop** (:func:`margins`): at the control period ``T`` the force is read at SYNC k and the
command ``u_k`` applies from then to the next SYNC; the model's delay ``τ = (m + f)·T`` and
integrator give, exactly in discrete time (zero-order hold, no Padé approximation),

.. math::  P(z) = g\,T\,\frac{(1 - f)\,z + f}{z^{m+1}\,(z - 1)},\qquad
           C(z) = K_p\left(1 + \frac{T}{T_i}\,\frac{z}{z - 1}\right),

and the margins of ``L = C·P`` come from a dense frequency grid up to Nyquist, cross-checked
against python-control's ``stability_margins(method='frd')``: the crossover, the gain and phase
margins and the peak sensitivity ``Ms = max |1/(1 + L)|``.

**The loops together** (:class:`StationLoop`): at the control period ``T``, each channel with
its own delay ``τ_j = (m_j + f_j)·T`` (zero-order hold, exact, as for one loop):

.. math::  \hat P_j(z) = T\,\frac{(1 - f_j)\,z + f_j}{z^{m_j+1}\,(z - 1)},\qquad
           P(z) = G\,\operatorname{diag}(\rho_j\,\hat P_j(z)),

``G`` the rig's gain matrix (``G_ii`` channel i's g, :mod:`plant.rig`), ``ρ_j`` channel j's gain
factor (1 nominal, its largest, the reversal boost, when boosted). The controller is one PI per
channel, ``C_i(z) = K_{p,i}(1 + (T/T_{i,i})·z/(z − 1))``, its outputs through a static matrix
``M``: ``K(z) = M·diag(C_i(z))`` with ``M = I`` (independent loops, each from its own g) or
``M = \hat G^{-1}\operatorname{diag}(\hat g)`` (decoupled: each loop sees its own g when the
model ``\hat G`` is the plant's G and the delays are equal). The loop gain matrix (broken at the
forces) is

.. math::  L(z) = P(z)\,K(z).

**Generalized Nyquist criterion** (MacFarlane & Postlethwaite 1977): the closed loop
``(I + L)^{-1}`` is stable iff the eigenvalues ``λ_k(e^{jωT})`` of ``L`` (the characteristic
loci), traced over the Nyquist contour, encircle −1 as the open loop's unstable poles ask.
Here the open loop has only poles at ``z = 1`` (the integrators) and the loci are read as the
one-channel loop is: a scalar gain ``k`` on every loop moves every locus by ``k``, so

* the **gain margin** is ``1/|x|`` at the loci's farthest crossing of the negative real axis
  inside the unit circle, ``x`` the crossing: how far all gains may rise together (a crossing
  beyond −1 is a margin for a gain that falls: at low frequency, where the double integration
  keeps the loci near −180°, they graze the axis far out without meaning anything);
* the **phase margin** is ``180° − |∠λ|`` at every crossing of the unit circle (the smallest);
* the **peak sensitivity** ``Ms = max_ω σ̄((I + L)^{-1})`` (the MIMO one: how much the loops
  amplify a disturbance in the worst direction at the worst frequency).

Why characteristic loci: they are the exact multi-loop stability test for a scalar gain change
of all loops, which is what the plant's gain uncertainty is when the rig's channels share a
structure, they reduce to the one-channel margins for one channel (or a diagonal G), and they
show what coupling does to each mode (with ``M = I``, the loop of the mode ``v`` of
``G·diag(1/g)`` has its gain times that eigenvalue: 1.49 on the example rig). A channel's own
gain rising alone is another direction: it is computed as its own case (one channel boosted,
the others nominal). The loci's margins are cross-checked against the closed loop's
eigenvalues (python-control: the MIMO loop as a state-space system, :func:`closed_loop_poles`),
which also decide stability: the margins read this way assume the loci start as a stable loop's
do (from −180° at low frequency); a mode whose loop gain has turned negative (a plant's coupling
far from the model's through a nearly singular G) looks well damped on the loci and is unstable,
which only the encirclements, or the eigenvalues, tell.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Sequence

import numpy as np


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


def critical_p_gain(g: float, tau: float, period_s: float) -> float:
    """The P gain (%/kgf) at which the loop with plant gain ``g`` reaches its stability limit."""
    return margins(1.0, math.inf, g, tau, period_s, check=False).gain_margin


#: frequency points of the loci (up to Nyquist)
POINTS = 2000


@dataclass
class LoopMargins:
    """Margins of a rig's loops together at one set of plant gains."""

    label: str                       #: "nominal", "boosted", "boosted: root", ...
    factors: list[float]             #: each channel's gain factor ρ_j in the plant
    coupling_error: float            #: the plant's off-diagonal G over the model's, minus 1
    gain_margin: float
    phase_margin_deg: float
    crossover_hz: float              #: the highest crossover of the loci
    peak_sensitivity: float          #: max σ̄((I + L)^-1)
    stable: bool | None = None       #: from the closed loop's eigenvalues (None: not computed)

    def text(self) -> str:
        err = f", coupling {100 * self.coupling_error:+.0f} %" if self.coupling_error else ""
        stab = "" if self.stable is None else ("" if self.stable else "  UNSTABLE")
        return (f"{self.label + err:<28} crossover {self.crossover_hz:6.3f} Hz, gain margin "
                f"{self.gain_margin:5.2f}, phase margin {self.phase_margin_deg:5.1f}°, "
                f"Ms {self.peak_sensitivity:4.2f}{stab}")

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class StationLoop:
    """What the loop is made of (module docstring): the model's G (the controller's), each
    channel's delay and PI, and the mixing matrix ``M``."""

    G: np.ndarray                    #: the model's gain matrix
    taus_s: np.ndarray               #: each channel's delay
    kp: np.ndarray                   #: each PI's gain, %/kgf
    ti_s: np.ndarray                 #: each PI's integral time (inf: P)
    period_s: float
    decoupled: bool
    M: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        G = np.asarray(self.G, float)
        M = np.linalg.solve(G, np.diag(np.diag(G))) if self.decoupled else np.eye(len(G))
        object.__setattr__(self, "M", M)

    @property
    def n(self) -> int:
        return len(self.taus_s)

    def plant_G(self, coupling_error: float = 0.0) -> np.ndarray:
        """The plant's G when its coupling (off-diagonal) is ``1 + coupling_error`` times the
        model's."""
        G = np.asarray(self.G, float)
        d = np.diag(np.diag(G))
        return d + (1.0 + coupling_error) * (G - d)

    def response(self, w: np.ndarray, factors: Sequence[float], coupling_error: float = 0.0,
                 scale: float = 1.0) -> np.ndarray:
        """``scale·L(e^{jωT})`` at the frequencies ``w`` (rad/s): (W, N, N)."""
        T = self.period_s
        z = np.exp(1j * w * T)
        P = np.empty((self.n, len(w)), complex)
        C = np.empty((self.n, len(w)), complex)
        for j, (tau, kp, ti) in enumerate(zip(self.taus_s, self.kp, self.ti_s)):
            whole = tau / T
            m = math.floor(whole + 1e-9)
            f = whole - m
            P[j] = T * ((1 - f) * z + f) / (z ** (m + 1) * (z - 1))
            C[j] = kp * (1 + (T / ti if math.isfinite(ti) else 0.0) * z / (z - 1))
        Gp = self.plant_G(coupling_error) * np.asarray(factors, float)[None, :]
        # L = Gp · diag(P) · M · diag(C)
        left = Gp[None, :, :] * P.T[:, None, :]                     # (W, N, N): Gp·diag(P)
        right = self.M[None, :, :] * C.T[:, None, :]                # M·diag(C)
        return scale * np.einsum("wij,wjk->wik", left, right)

    def margins(self, factors: Sequence[float], label: str, coupling_error: float = 0.0,
                points: int = POINTS, check: bool = False, sensitivity: bool = True) -> LoopMargins:
        """The loci's margins at the plant gain factors ``factors`` (module docstring); with
        ``check`` the closed loop's eigenvalues say whether it is stable; without
        ``sensitivity`` Ms is not computed (NaN: a search that needs only the margins)."""
        w = np.geomspace(1e-2, math.pi / self.period_s * 0.9999, points)
        L = self.response(w, factors, coupling_error)
        gm, pm, wc = loci_margins(np.linalg.eigvals(L), w)
        ms = peak_sensitivity(L) if sensitivity else math.nan
        stable = None
        if check:
            stable = bool(np.max(np.abs(closed_loop_poles(self, factors, coupling_error))) < 1.0)
        return LoopMargins(label, [float(f) for f in factors], float(coupling_error), gm, pm,
                           wc / (2 * math.pi), ms, stable)


def loci_margins(lam: np.ndarray, w: np.ndarray) -> tuple[float, float, float]:
    """Gain margin, phase margin (degrees) and the highest crossover (rad/s) from the
    characteristic loci ``lam`` (W, N) at the frequencies ``w`` (module docstring). The loci
    are followed between neighbouring frequencies by nearest eigenvalues; a crossing is
    interpolated linearly between the two points."""
    a = lam[:-1]                                           # (W-1, N)
    d = np.abs(a[:, :, None] - lam[1:, None, :])           # (W-1, N, N)
    partner = np.argmin(d, axis=2)
    b = np.take_along_axis(lam[1:], partner, axis=1)
    # the negative real axis inside the unit circle
    gm = math.inf
    ai, bi = a.imag, b.imag
    cross = (ai * bi <= 0) & (ai != bi)
    if cross.any():
        s = ai[cross] / (ai[cross] - bi[cross])
        x = a.real[cross] + s * (b.real[cross] - a.real[cross])
        inside = (x < 0) & (x > -1)
        if inside.any():
            gm = float(np.min(1.0 / np.abs(x[inside])))
    # the unit circle
    am, bm = np.abs(a) - 1, np.abs(b) - 1
    ucross = (am * bm <= 0) & (am != bm)
    pm, wc = math.inf, math.nan
    if ucross.any():
        s = am[ucross] / (am[ucross] - bm[ucross])
        pa, pb = np.angle(a[ucross]), np.angle(b[ucross])
        jump = np.abs(pb - pa) > math.pi                  # across ±180°: take the nearer side
        pb = np.where(jump, pb - np.sign(pb - pa) * 2 * math.pi, pb)
        ang = pa + s * (pb - pa)
        ang = (ang + math.pi) % (2 * math.pi) - math.pi
        pm = float(np.min(180.0 - np.degrees(np.abs(ang))))
        k = np.nonzero(ucross)[0]
        wc = float(np.max(w[k] + s * (w[k + 1] - w[k])))
    return gm, pm, wc


def peak_sensitivity(L: np.ndarray) -> float:
    """``max_ω σ̄((I + L)^{-1})`` over the frequency points of ``L`` (W, N, N)."""
    n = L.shape[1]
    S = np.linalg.inv(np.eye(n)[None, :, :] + L)
    return float(np.max(np.linalg.svd(S, compute_uv=False)[:, 0]))


def closed_loop_poles(loop: StationLoop, factors: Sequence[float], coupling_error: float = 0.0,
                      scale: float = 1.0) -> np.ndarray:
    """The closed loop's poles (python-control): each channel's ``P̂_j`` and ``C_i`` as
    discrete transfer functions, the loop ``scale·Gp·diag(ρ)·diag(P̂)·M·diag(C)`` as one
    state-space system, unity negative feedback. Stable iff every |pole| < 1 (the brute-force
    check of the loci)."""
    import control
    T = loop.period_s
    plants = [control.ss(plant_tf(1.0, tau, T)) for tau in loop.taus_s]
    pis = [control.ss(pi_tf(kp, ti, T) if math.isfinite(ti) else control.tf([kp], [1.0], T))
           for kp, ti in zip(loop.kp, loop.ti_s)]
    P = control.append(*plants)
    C = control.append(*pis)
    Gp = loop.plant_G(coupling_error) * np.asarray(factors, float)[None, :] * scale
    n = loop.n
    static = lambda K: control.ss([], [], [], np.asarray(K, float), T)   # noqa: E731
    L = control.series(C, static(loop.M), P, static(Gp))
    closed = control.feedback(L, static(np.eye(n)))
    return np.asarray(closed.poles())


def critical_scale(loop: StationLoop, factors: Sequence[float], coupling_error: float = 0.0,
                   upper: float = 20.0, steps: int = 30) -> float:
    """The common gain factor at which the closed loop's poles leave the unit circle, by
    bisection on the closed loop's eigenvalues (the brute-force gain margin, for checks)."""
    def stable(k: float) -> bool:
        return bool(np.max(np.abs(closed_loop_poles(loop, factors, coupling_error, k))) < 1.0)
    if not stable(1.0):
        lo, hi = 0.0, 1.0
    elif stable(upper):
        return math.inf
    else:
        lo, hi = 1.0, upper
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    return 0.5 * (lo + hi)
