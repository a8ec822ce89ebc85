"""Records for the diagnosis tests: the paper's three excitations on our plant model, and the
independent simulator's data sets."""
from __future__ import annotations

import numpy as np

from analysis.records import synthetic as S
from analysis import make_record
from plant import Dynamometer
from tests.support import independent_stand as sim


def meander4(model, seed=1, **kw):
    """Open-loop meanders at 5, 10, 15 and 20 %, two cycles of 2 s each."""
    return S.meander(model, (5.0, 10.0, 15.0, 20.0), period_s=2.0, cycles=2, seed=seed, **kw)


def relay(model, seed=1, **kw):
    """Relay feedback at 10 % around 0, 1500 and -1500 kgf, 6 s each."""
    return S.relay(model, 10.0, (0.0, 1500.0, -1500.0), 6.0, seed=seed, **kw)


def pfeedback(model, seed=1, omegas=(0.6283, 1.5), **kw):
    """P feedback (gain 0.005) on a 2000 kgf sinusoidal reference at each of ``omegas`` rad/s."""
    return S.pfeedback(model, gain=0.005, amplitude_kgf=2000.0, omegas_rad_s=omegas, seed=seed, **kw)


def held_at_limit(model, amplitudes_pct, limit_kgf: float, cycles: int, seed: int = 1,
                  period_s: float = 4.0, dt: float = 0.002, noise_kgf: float = 2.0) -> list:
    """Open-loop meanders (one record per amplitude, from zero force) on a stand whose force
    cannot rise above ``limit_kgf`` (a relief valve): it stays there, the dynamometer's noise on
    top, while the flow pushes, and leaves as the flow turns. For a ``model`` whose force rate
    does not depend on the force (checked): the free run's increments, held at the limit."""
    out = []
    for i, a in enumerate(amplitudes_pct):
        u = S.square_wave(a, period_s, cycles, dt)
        step = np.diff(model.simulate(u, dt, u_before=0.0))
        if not np.allclose(step, np.diff(model.simulate(u, dt, y0=limit_kgf, u_before=0.0))):
            raise ValueError(f"{model.spec}: the force rate depends on the force")
        y = np.empty(len(u))
        y[0] = 0.0
        for k, dy in enumerate(step):
            y[k + 1] = min(y[k] + dy, limit_kgf)
        reading, _ = Dynamometer(noise_kgf=noise_kgf, seed=1000 * seed + i).measure(y)
        out.append(make_record(np.arange(len(u)) * dt, u, reading,
                               source=f"meander {a:g} % held at {limit_kgf:g} kgf"))
    return out


def independent_records(effects: str, seed: int, fixed_phase: float | None = None) -> list:
    """The independent simulator's eight runs with ``effects`` ("none", or names joined by
    "+"); ``fixed_phase``: an oscillation or ripple starts in that phase in every run."""
    return [make_record(t, u, y, r if np.isfinite(r).any() else None, source=name)
            for name, _, t, u, y, r, _ in sim.make_dataset(effects, seed, fixed_phase)]


#: simulator effect -> the catalogue effects that name it exactly or equivalently (one effect,
#: or both where the data cannot tell them apart)
EQUIVALENT = {"rev_flow": {"reversal"}, "rev_cmd": {"command_reversal"},
              "rev_force": {"travel_reversal"},
              "lag": {"lag", "sensor_lag"}, "sensorlag": {"lag", "sensor_lag"},
              "deadzone": {"deadzone"}, "saturation": {"saturation"}, "asymmetry": {"asymmetry"},
              "loadpress": {"load_pressure"}, "leakage": {"leakage"}, "backlash": {"backlash"},
              "flownl": {"flow_curve"}, "friction": {"deadzone"},   # Coulomb friction on the rate
              "stiffening": {"stiffness"}, "stiction": {"stiction"}, "softload": {"unloading"},
              "dirdelay": {"direction_delay"}, "res": {"resonance"},
              "valve2nd": {"resonance"},        # the same law at 25 Hz, ζ = 0.5
              "slew": {"slew"}, "supply": {"supply"}, "gaindrift": {"gain_drift"},
              "nulldrift": {"null_drift"},
              "lostmotion": {"stiction"}, "dirlatch": {"direction_delay"}}       # a play in the rod's travel: one in force
