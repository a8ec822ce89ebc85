"""Replay a captured run as the plant: the stand's two CANopen nodes answer the gateway, and the
dynamometer publishes the *recorded* force sequence, one sample per SYNC.

So a gateway change can be regression-tested against recorded bench behaviour without the bench:
record a run on the bench (its ``capture.log``), then ::

    stand replay bench/capture.log --as-plant --bus udp_loopback:regress
    stand run meander ... --bus udp_loopback:regress --lockstep

The replayed stand is the emulator (:class:`plant_emulator.EmulatedStand`: NMT, SDO, PDO mapping,
valve state machine, EMCY, heartbeats) with its two plant hooks replaced:

* :meth:`ReplayedStand.advance_plant` does nothing (no model);
* :meth:`ReplayedStand.measure_force` returns the force the dynamometer sent after SYNC k of the
  captured run at the k-th SYNC since the nodes were started (NMT start, which the gateway sends
  at every run start), so the sequence restarts with each run.

The force goes out as the same counts (INT32, 0.1 N): the reading is counts × DBC factor kgf and
the dynamometer rounds it back with the same factor. The over-range bits come from the captured
ForceStatus. Beyond the end of the recording the last sample is held (and counted). The valve is
the emulated one: it follows the commands of the gateway under test, which the recorded force
does not — this is a replay of the plant's output, not a model of it.
"""
from __future__ import annotations

import logging
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import can
import numpy as np

from core.errors import DataError
from dbc import profile as P
from plant.config import load_plant_config

from .process import EmulatorProcess
from .stand import EmulatedStand, EmulatorOptions

log = logging.getLogger(__name__)


@dataclass
class ForceTrace:
    """The dynamometer's answers to the SYNCs of one captured run."""

    counts: np.ndarray        #: int32 process value at SYNC k (k = 0, 1, ... including the run's last SYNC)
    status: np.ndarray        #: AI status (0x6150:01) at SYNC k
    scale_kgf: float          #: kgf per count (the DBC's Force factor)
    period_s: float
    source: str
    run: int = 0

    def __len__(self) -> int:
        return len(self.counts)

    @property
    def kgf(self) -> np.ndarray:
        return self.counts * self.scale_kgf


class ReplayedStand(EmulatedStand):
    """Both nodes of the stand on ``bus``, the dynamometer replaying ``trace``."""

    def __init__(self, bus: can.BusABC, trace: ForceTrace, options: EmulatorOptions | None = None) -> None:
        if not len(trace):
            raise DataError(f"{trace.source}: the force trace is empty")
        # One sample per SYNC whatever the wall clock: lockstep-capable by construction.
        options = replace(options or EmulatorOptions(), lockstep=True)
        super().__init__(bus, load_plant_config(None, "base", {}), options)
        self.trace = trace
        self.index = 0
        self.runs_started = 0
        self.exhausted_syncs = 0
        self.warnings: list[str] = []

    def run_started(self) -> None:
        """A run starts (the dynamometer entered OPERATIONAL): replay from the first sample."""
        self.index = 0
        self.runs_started += 1
        period_us = int(self.valve.value(P.COMM_CYCLE_PERIOD))
        if period_us and abs(period_us * 1e-6 - self.trace.period_s) > 1e-9:
            msg = (f"the gateway runs a {period_us / 1000:g} ms period but the recording has "
                   f"{self.trace.period_s * 1e3:g} ms: the force samples keep the recorded spacing")
            self.warnings.append(msg)
            log.warning(msg)

    def advance_plant(self) -> None:
        """No plant: the force comes from the recording."""

    def measure_force(self) -> tuple[float, bool]:
        k = self.index
        self.index += 1
        if k >= len(self.trace):
            self.exhausted_syncs += 1
            if self.exhausted_syncs == 1:
                log.warning("the recording has only %d samples: holding the last one", len(self.trace))
            k = len(self.trace) - 1
        counts = int(self.trace.counts[k])
        over = bool(int(self.trace.status[k]) & (P.AI_STATUS_POSITIVE_OVERLOAD | P.AI_STATUS_NEGATIVE_OVERLOAD))
        return counts * self.trace.scale_kgf, over


class ReplayProcess(EmulatorProcess):
    """``stand replay CAPTURE --as-plant`` as a separate process (like
    :class:`plant_emulator.process.EmulatorProcess` for ``stand emulate``)::

        with ReplayProcess("udp_loopback:regress", "bench/capture.log"):
            ...   # run the gateway under test against the recorded plant
    """

    def __init__(self, bus: str, capture: str | Path, run: int | None = None,
                 extra_args: list[str] | None = None, ready_timeout_s: float = 30.0) -> None:
        super().__init__(bus, None, lockstep=True, seed=None, extra_args=extra_args,
                         ready_timeout_s=ready_timeout_s)
        self.capture = str(capture)
        self.run = run

    def command(self) -> list[str]:
        cmd = [sys.executable, "-m", "stand", "replay", self.capture, "--as-plant", "--bus", self.bus]
        if self.run is not None:
            cmd += ["--run", str(self.run)]
        return cmd + self.extra_args
