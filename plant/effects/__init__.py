"""The effects the project ships: one module each (the reversal's three timings share one), each
a plug-in of the same contract as a user's (:mod:`plant.contract`), registered by
:mod:`plant.catalogue` through the same loader (:mod:`plant.loader`).

Importing this package imports none of them; :data:`BUILTIN_MODULES` lists them in the
catalogue's order: by stage (VALVE, FLOW, DISTURBANCE, FORCE, SENSOR), which is also the order
a model applies the effects of one stage in.
"""
from __future__ import annotations

BUILTIN_MODULES: tuple[str, ...] = tuple(f"{__name__}.{m}" for m in (
    # VALVE: the delayed command -> the flow command q
    "null_drift", "lag", "resonance", "slew", "deadzone", "saturation", "backlash",
    "direction_delay", "flow_curve",
    # FLOW: factors on g·q
    "asymmetry", "supply", "gain_drift", "reversal", "load_pressure", "stiffness", "unloading",
    # DISTURBANCE: a force rate of time alone
    "oscillation",
    # FORCE: a force rate of the force
    "leakage",
    # SENSOR: what the dynamometer reports
    "sensor_lag", "stiction",
))
