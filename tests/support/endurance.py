"""Endurance tests' helpers: the example test (examples/endurance) copied where a test may edit
it, a one-channel stand's test, and a small TWIST-like test for the journal and storage."""
from __future__ import annotations

import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE_TEST = ROOT / "examples" / "endurance" / "test.toml"


def copy_example(tmp_path: Path) -> Path:
    """examples/endurance and examples/rig.toml under ``tmp_path``; the test file's path."""
    shutil.copy(ROOT / "examples" / "rig.toml", tmp_path / "rig.toml")
    shutil.copytree(ROOT / "examples" / "endurance", tmp_path / "endurance")
    return tmp_path / "endurance" / "test.toml"


def edit(path: Path, old: str, new: str, count: int = 1) -> Path:
    """Replace ``old`` by ``new`` in a file (``old`` must be there)."""
    text = path.read_text()
    assert old in text, f"{old!r} not in {path}"
    path.write_text(text.replace(old, new, count))
    return path


def stand_controller(path: Path) -> Path:
    """A one-channel controller file (stand design of the emulator's default plant)."""
    from loading.design import design
    from plant import PlantModel
    c = design(PlantModel.from_spec("base+reversal"), 0.002)
    path.write_text(c.to_toml(path))
    return path


def write_stand_test(directory: Path, flights: int = 1000, counts: dict | None = None,
                     seed: int = 1) -> Path:
    """A TWIST-like test of a one-channel stand (3 flight types unless ``counts``)."""
    from endurance.spectrum import write_twist_like
    directory.mkdir(parents=True, exist_ok=True)
    stand_controller(directory / "controller.toml")
    counts = counts or {"A": 1, "B": 3, "C": 8}
    return write_twist_like(directory, ["level"], [9500.0], "stand", "controller.toml",
                            flights=flights, n_types=len(counts), counts=counts, seed=seed)
