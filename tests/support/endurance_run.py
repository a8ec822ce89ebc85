"""Endurance sessions offline: the flights of ``examples/test.toml`` played by the session's own
player, planner and journal writer (endurance.run) on the emulator's coupled lockstep plant of
the example rig, or a stand's on the emulator's default stand (gateway.offline: the same plant,
law and noise, no bus), and the test's copy where a test may edit it."""
from __future__ import annotations

import shutil
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from endurance import run
from endurance.journal import Journal
from endurance.testfile import load_test_file
from gateway.offline import emulated_truth, run_offline_pass

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


class OfflineStand:
    """The example rig's plant across sessions: each session starts from the forces the one
    before left (its commands in flight and the rods' state are not kept)."""

    def __init__(self, seed: int = 1, stand: bool = False) -> None:
        if stand:                               # the emulator's default stand, 2 kgf noise
            from plant import PlantModel
            from plant.rig import RigModel
            self.truth, self.noise = RigModel([PlantModel.from_spec("base+reversal")], np.array([[120.0]]),
                                              ["stand"]), 2.0
        else:
            self.truth, self.noise = emulated_truth(ROOT / "examples" / "rig.toml")
        self.forces = np.zeros(self.truth.n)
        self.seed = seed
        self.runs: list = []

    def drive(self, limits, max_s: float = 5000.0):
        """A session's drive (endurance.run.Drive): the player on the plant until it is done,
        aborts or ``max_s`` of stand time have passed (then "cut", as a kill would)."""
        def drive(player, recorder, window):
            self.seed += 1
            out = run_offline_pass(player, self.truth, self.forces, seed=self.seed, noise_kgf=self.noise,
                                   force_limits=limits, max_s=max_s)
            if out.y.size:
                self.forces = out.y[:, -1].copy()
            self.runs.append(out)
            status = "complete" if player.done else "stopped"
            reason, message = out.abort if out.abort else (None, None) if player.done else ("cut", "cut short")
            recorder.close(status=status, end_reason=reason, end_message=message)
            return SimpleNamespace(status=status, reason=reason, message=message)
        return drive


def fly(testdir: Path, test_file: Path, stand: OfflineStand, flights: int | None = None,
        max_s: float = 5000.0, on_flight=None, hook=None) -> run.SessionResult:
    """A session offline: a new test in ``testdir`` (its journal made as ``stand test start``
    makes it) or the one there resumed."""
    test = load_test_file(test_file)
    testdir = Path(testdir)
    if (testdir / "journal.sqlite").exists():
        journal, kind = Journal.open(testdir, write=True), "resume"
    else:
        fp = test.fingerprint()
        journal = Journal.create(testdir, test.name, flights or test.flights, test.station.names, fp.digest,
                                 fp.to_json(), test.path.read_text())
        kind = "start"
    return run.run_session(test, testdir, journal, kind, time.time(),
                           stand.drive(test.station.force_limits_kgf, max_s), on_flight, hook)
