"""The plant model, shared by the emulator and the analysis.

- :mod:`plant.model`: the paper's base model ``dy/dt = g·u(t−τ) + Δ`` and its simulation;
- :mod:`plant.effects`: the catalogue of physical effects (one documented class each);
- :mod:`plant.sensor`: the dynamometer (noise, resolution, range);
- :mod:`plant.config`: model files and emulator configuration (TOML).
"""
from __future__ import annotations

import importlib

# Names are imported on first use (PEP 562), so `import plant.x` and the command line's --help do
# not pay for the numerics and the CAN stack behind them.
_LAZY = {
    "PlantConfig": ".config",
    "load_model_file": ".config",
    "load_plant_config": ".config",
    "model_to_toml": ".config",
    "CATALOGUE": ".effects",
    "Effect": ".effects",
    "Stage": ".effects",
    "register": ".effects",
    "BASE_PARAMS": ".model",
    "PlantModel": ".model",
    "PlantState": ".model",
    "ModelError": ".params",
    "Param": ".params",
    "Dynamometer": ".sensor",
}
__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
