"""Endurance sessions without a bus: the session's own player, planner, journal writer and
monitors (:mod:`endurance.run`) on the emulator's coupled lockstep plant
(:func:`gateway.offline.run_offline_pass`: the same plant, law and noise as ``stand emulate
--lockstep``, no CANopen), for tests and benchmarks of what a session does over many flights.
Through the gateway a session is :func:`endurance.run.start` / :func:`endurance.run.resume`."""
from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace
from typing import Sequence

import numpy as np

from gateway.offline import emulated_truth, run_offline_pass

from . import run
from .journal import Journal
from .testfile import load_test_file


class OfflineStation:
    """A station's plant across sessions (``truth``: :class:`plant.rig.RigModel`, with any
    scheduled change of its structure; ``noise_kgf`` per channel): each session starts from
    the forces the one before left and goes on on the stand's clock (its commands in flight and
    the rods' state are not kept)."""

    def __init__(self, truth, noise_kgf: float | Sequence[float], seed: int = 1) -> None:
        self.truth, self.noise = truth, noise_kgf
        self.forces = np.zeros(truth.n)
        self.seed = seed
        self.stand_time_s = 0.0
        self.runs: list = []

    @classmethod
    def of_rig_file(cls, rig_file: str | Path, seed: int = 1) -> "OfflineStation":
        """The plant ``stand emulate --rig RIG_FILE`` runs (its structure's changes included)."""
        return cls(*emulated_truth(rig_file), seed=seed)

    def drive(self, limits: Sequence[float], max_s: float = 5000.0) -> run.Drive:
        """A session's drive: the player on the plant until it is done, aborts or ``max_s`` of
        stand time have passed (then "cut", as a kill would)."""
        def drive(player, recorder, window):
            self.seed += 1
            out = run_offline_pass(player, self.truth, self.forces, seed=self.seed, noise_kgf=self.noise,
                                   force_limits=limits, max_s=max_s, start_s=self.stand_time_s)
            if out.y.size:
                self.forces = out.y[:, -1].copy()
            self.stand_time_s = out.end_s
            self.runs.append(out)
            status = "complete" if player.done else "stopped"
            reason, message = out.abort if out.abort else (None, None) if player.done else ("cut", "cut short")
            recorder.close(status=status, end_reason=reason, end_message=message)
            return SimpleNamespace(status=status, reason=reason, message=message)
        return drive


def fly(testdir: str | Path, test_file: str | Path, station: OfflineStation, flights: int | None = None,
        max_s: float = 5000.0, on_flight=None, hook=None, found: str | None = None) -> run.SessionResult:
    """A session offline: a new test in ``testdir`` (its journal made as ``stand test start``
    makes it; ``flights`` its target instead of the file's) or the one there resumed (``found``:
    what the inspection after the trend's alarm found, as :func:`endurance.run.run_session` takes it)."""
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
                           station.drive(test.station.force_limits_kgf, max_s), on_flight, hook, found=found)
