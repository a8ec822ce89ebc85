"""The plant model, shared by the emulator and the analysis.

- :mod:`plant.model`: the paper's base model ``dy/dt = g·u(t−τ) + Δ`` and its simulation;
- :mod:`plant.effects`: the catalogue of physical effects (one documented class each);
- :mod:`plant.sensor`: the dynamometer (noise, resolution, range);
- :mod:`plant.config`: model files and emulator configuration (TOML).
"""
from .config import PlantConfig, load_model_file, load_plant_config, model_to_toml
from .effects import CATALOGUE, Effect, Stage, register
from .model import BASE_PARAMS, PlantModel, PlantState
from .params import ModelError, Param
from .sensor import Dynamometer

__all__ = [
    "BASE_PARAMS", "CATALOGUE", "Dynamometer", "Effect", "ModelError", "Param", "PlantConfig",
    "PlantModel", "PlantState", "Stage", "load_model_file", "load_plant_config",
    "model_to_toml", "register",
]
