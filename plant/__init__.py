"""The plant model, shared by the emulator and the analysis.

- :mod:`plant.contract`: what an effect is (:class:`Effect`, :class:`Stage`) and the registry;
- :mod:`plant.effects`: the project's own effects, one module each, plug-ins of that contract;
- :mod:`plant.loader`, :mod:`plant.catalogue`, :mod:`plant.plugins`: finding and registering
  effects: the built-ins first, then a user's (files, modules, installed packages), checked;
- :mod:`plant.model`: the paper's base model ``dy/dt = g·u(t−τ) + Δ`` and its simulation;
- :mod:`plant.sensor`: the dynamometer (noise, resolution, range);
- :mod:`plant.config`: model files and emulator configuration (TOML).
"""
from __future__ import annotations

from core.lazy import lazy_exports

# imported on first use (core.lazy): `import plant.x` and `stand --help` stay light
_EXPORTS = {
    "PlantConfig": ".config",
    "load_model_file": ".config",
    "load_plant_config": ".config",
    "model_to_toml": ".config",
    "CATALOGUE": ".catalogue",
    "Effect": ".contract",
    "Stage": ".contract",
    "register": ".contract",
    "BASE_PARAMS": ".model",
    "PlantModel": ".model",
    "PlantState": ".model",
    "ModelError": ".params",
    "PluginError": ".plugins",
    "load_plugins": ".plugins",
    "load_installed": ".plugins",
    "Param": ".params",
    "Dynamometer": ".sensor",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
