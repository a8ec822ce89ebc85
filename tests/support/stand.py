"""The stand's default plant, as most tests simulate it."""
from __future__ import annotations

from plant.config import PlantConfig, load_plant_config

#: g (kgf/(%·s)), tau (s), delta (kgf/s): the emulator's defaults (plant.config.DEFAULT_VALUES),
#: written out so that a test states the truth it checks against
BASE = {"g": 120.0, "tau": 0.05, "delta": 8.0}


def plant(overrides: dict | None = None, model: str | None = None) -> PlantConfig:
    """The emulator's plant configuration with ``overrides`` (plant values) and ``model`` (spec)."""
    return load_plant_config(None, model, overrides or {})
