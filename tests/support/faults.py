"""Shared pieces of the fault-injection tests (no tests here): small experiments, a bus
sniffer, capture queries, and the reaction-time log.

Reaction times are measured from the moment the test injects a fault to the first frame of
the reaction on the bus (e.g. the gateway's safe-state RPDO in its capture, with the sender's
wall-clock time stamp). Each test asserts the stated bound plus :data:`LOAD_ALLOWANCE_S` for
scheduling on a loaded shared 2-core machine. With ``HYDROSTAND_REACTIONS=FILE`` set, every
measurement is appended to FILE as one JSON line (for the table in docs/benchmarks.md).
"""
from __future__ import annotations

import json
import math
import os
import struct
import threading
import time
from pathlib import Path

import can

from dbc import profile as P
from gateway.capture import read_capture
from gateway.experiments import Experiment
from standbus import open_bus

#: what the tests allow on top of a stated bound for a loaded, shared 2-core machine, s
LOAD_ALLOWANCE_S = 0.25
SAFE_WORDS = (int(P.CW_HOLD), int(P.CW_DISABLED))


def log_reaction(fault: str, measured_s: float, bound_s: float, **info) -> None:
    path = os.environ.get("HYDROSTAND_REACTIONS")
    if path:
        with open(path, "a") as fh:
            fh.write(json.dumps({"fault": fault, "measured_s": measured_s, "bound_s": bound_s,
                                 **info}) + "\n")


class Const(Experiment):
    """Open loop: a constant command for ``duration`` seconds."""

    name = "const"

    def __init__(self, u: float = 1.0, duration: float = 3.0) -> None:
        self.u, self.duration = u, duration

    @property
    def duration_s(self) -> float:
        return self.duration

    def params(self):
        return {"u": self.u, "duration": self.duration}

    def step(self, t, y):
        return self.u, math.nan


class RampReference(Experiment):
    """A reference ramp the command does not follow (u = 0): |r − y| grows at ``rate``."""

    name = "ramp_reference"

    def __init__(self, rate_kgf_s: float = 1000.0, duration: float = 2.0) -> None:
        self.rate, self.duration = rate_kgf_s, duration
        self.y0 = 0.0

    @property
    def duration_s(self):
        return self.duration

    def params(self):
        return {"rate": self.rate}

    def begin(self, y0):
        self.y0 = y0

    def step(self, t, y):
        return 0.0, self.y0 + self.rate * t


class Stall(Const):
    """Const, but ``step`` blocks once for ``stall_s`` at ``at_s`` (a computation that hangs)."""

    name = "stall"

    def __init__(self, u=1.0, duration=3.0, at_s=1.0, stall_s=0.3):
        super().__init__(u, duration)
        self.at_s, self.stall_s = at_s, stall_s
        self.stalled_at: float | None = None

    def step(self, t, y):
        if t >= self.at_s and self.stalled_at is None:
            self.stalled_at = time.time()
            time.sleep(self.stall_s)
        return self.u, math.nan


def rpdos(run_dir: Path, node: int = 1) -> list[tuple[float, int, int]]:
    """The valve commands in a run's capture: ``(time, control word, setpoint counts)``. Only
    classic data frames with an 11-bit id are commands: a flood's extended-id frame 0x201 with
    four bytes is not (the valve drops it), so it must not count as one."""
    out = []
    for f in read_capture(Path(run_dir) / "capture.log"):
        if (f.arbitration_id == 0x200 + node and len(f.data) == 4 and not f.is_extended_id
                and not (f.is_remote_frame or f.is_error_frame or f.is_fd)):
            cw, sp = struct.unpack("<Hh", bytes(f.data))
            out.append((f.timestamp, cw, sp))
    return out


def first_safe_command(run_dir: Path, after: float) -> tuple[float, int, int]:
    """The first safe-state RPDO (HOLD or DISABLED, zero setpoint) sent after ``after``."""
    for ts, cw, sp in rpdos(run_dir):
        if ts >= after and cw in SAFE_WORDS and sp == 0:
            return ts, cw, sp
    raise AssertionError(f"no safe-state command after {after} in {run_dir}")


def emcys(frames, node: int) -> list[tuple[float, int]]:
    """``(time, code)`` of the EMCYs of ``node`` among ``frames``."""
    return [(f.timestamp, struct.unpack_from("<H", bytes(f.data))[0]) for f in frames
            if f.arbitration_id == 0x80 + node and len(f.data) == 8]


class Sniffer:
    """Records every frame on a bus from a thread of the test process (a passive listener)."""

    def __init__(self, bus_spec: str) -> None:
        self.bus = open_bus(bus_spec)
        self.frames: list[can.Message] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            m = self.bus.recv(0.05)
            if m is not None:
                self.frames.append(m)

    def __enter__(self) -> "Sniffer":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self.bus.shutdown()

    def wait_for(self, predicate, timeout: float) -> can.Message | None:
        deadline = time.monotonic() + timeout
        seen = 0
        while time.monotonic() < deadline:
            frames = self.frames
            for m in frames[seen:]:
                if predicate(m):
                    return m
            seen = len(frames)
            time.sleep(0.01)
        return None


def valve_state(bus_spec: str, node: int = 1) -> P.ValveState | None:
    """Read the valve's status word 0x6041 over SDO from a separate canopen client."""
    import canopen

    from dbc import VALVE_EDS
    net = canopen.Network(open_bus(bus_spec))
    net.NOTIFIER_CYCLE = 0.1
    net.connect()
    try:
        remote = net.add_node(node, str(VALVE_EDS))
        return P.ValveState.from_status(remote.sdo[P.STATUS_WORD].raw)
    finally:
        net.disconnect()
