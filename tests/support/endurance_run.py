"""Endurance sessions offline (endurance.offline): the flights of ``examples/test.toml`` on the
emulator's coupled lockstep plant of the example rig, or a stand's on the emulator's default
stand, and the test's copy where a test may edit it."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from endurance.offline import OfflineStation, fly  # noqa: F401  (the tests' session offline)
from gateway.offline import emulated_truth

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "test.toml"


def copy_short_test(tmp_path: Path, rig_text: str | None = None) -> Path:
    """examples/test.toml with its flights, the rig file (``rig_text``: another one, e.g. on
    private buses) and the controller under ``tmp_path``; the test file's path."""
    shutil.copytree(ROOT / "examples" / "test-flights", tmp_path / "test-flights")
    (tmp_path / "endurance").mkdir()
    shutil.copy(ROOT / "examples" / "endurance" / "controller.toml", tmp_path / "endurance" / "controller.toml")
    (tmp_path / "rig.toml").write_text(rig_text or (ROOT / "examples" / "rig.toml").read_text())
    shutil.copy(EXAMPLE, tmp_path / "test.toml")
    return tmp_path / "test.toml"


class OfflineStand(OfflineStation):
    """The example rig's plant across sessions (endurance.offline), or with ``stand`` the
    emulator's default stand (base+reversal, 2 kgf noise)."""

    def __init__(self, seed: int = 1, stand: bool = False) -> None:
        if stand:
            from plant import PlantModel
            from plant.rig import RigModel
            super().__init__(RigModel([PlantModel.from_spec("base+reversal")], np.array([[120.0]]), ["stand"]),
                             2.0, seed)
        else:
            super().__init__(*emulated_truth(ROOT / "examples" / "rig.toml"), seed=seed)
