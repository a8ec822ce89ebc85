"""Faults the emulated stand makes itself at a scheduled stand time (``stand emulate --fault``):
what a test of the gateway's interlocks needs from the stand's side of the real bus, in a
process the test does not drive (an endurance test's gateway runs as ``stand test start``).

* ``spike:CHANNEL:KGF@T`` — at the first SYNC at or after stand time ``T`` the channel's
  dynamometer reads ``KGF`` more than the force for that one reading (a load spike or a sensor
  glitch): the gateway's force limit or its load's guard trips on it.
* ``heartbeat:CHANNEL@T+D`` — from stand time ``T`` the channel's valve sends no heartbeat for
  ``D`` s of the wall clock (its PDOs go on): the master's heartbeat consumer trips. The wall
  clock, because heartbeats are timed on it even in lockstep, and a master that trips stops
  the SYNCs that make the stand's time.

``T`` is the plant's stand time (s), the clock ``--change`` counts on: in lockstep the
communication cycles answered since the emulator started, in real time the time since it
started. Each fault happens once.

On the bus the bus-level faults (frames lost or late, a flood: :mod:`standbus.faults`) are
another matter: they act on frames, these on what the stand's nodes say.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Sequence

from plant.params import ModelError

KINDS = ("spike", "heartbeat")
FAULT_FORM = "spike:CHANNEL:KGF@T or heartbeat:CHANNEL@T+D, e.g. spike:root:6000@120 or heartbeat:inner@300+5"
FAULT_RE = re.compile(r"^(?P<kind>[a-z]+):(?P<channel>[^:@+\s]+)(?::(?P<value>[^@]+))?@(?P<at>[^+]+)"
                      r"(?:\+(?P<duration>.+))?$")


@dataclass(frozen=True)
class ScheduledFault:
    """One fault (module docstring): ``kind``, the channel's index, stand time ``at_s``, the
    spike's ``value_kgf`` or the heartbeat's silence ``duration_s``."""

    kind: str
    channel: int
    at_s: float
    value_kgf: float = 0.0
    duration_s: float = 0.0

    def text(self, names: Sequence[str]) -> str:
        """The fault as the emulator's ready line says it."""
        name = names[self.channel]
        if self.kind == "spike":
            return f"{name}'s dynamometer reads {self.value_kgf:+g} kgf once at {self.at_s:g} s of stand time"
        return f"{name}'s valve sends no heartbeat for {self.duration_s:g} s from {self.at_s:g} s of stand time"


def parse_fault(text: str, names: Sequence[str]) -> ScheduledFault:
    """``--fault TEXT`` (:data:`FAULT_FORM`) for a station of the channels ``names``;
    :class:`plant.params.ModelError` naming what is wrong."""
    where = f"--fault {text!r}"
    m = FAULT_RE.match(text.strip())
    if not m:
        raise ModelError(f"{where}: give it as {FAULT_FORM}")
    kind, channel = m["kind"], m["channel"]
    if kind not in KINDS:
        raise ModelError(f"{where}: {kind!r} is not a fault; the faults are {', '.join(KINDS)} ({FAULT_FORM})")
    if channel not in names:
        raise ModelError(f"{where}: no channel {channel!r}; the station has {', '.join(names)}")

    def number(key: str, what: str) -> float:
        try:
            v = float(m[key])
        except (TypeError, ValueError):
            raise ModelError(f"{where}: give {what} ({FAULT_FORM})") from None
        if not math.isfinite(v):
            raise ModelError(f"{where}: {what} must be a finite number")
        return v

    at = number("at", "the stand time T in s")
    if at < 0:
        raise ModelError(f"{where}: the stand time {at:g} s is before the emulator started")
    if kind == "spike":
        if m["duration"] is not None:
            raise ModelError(f"{where}: a spike is one reading; leave +D out ({FAULT_FORM})")
        value = number("value", "the spike's size in kgf (spike:CHANNEL:KGF@T)")
        if value == 0:
            raise ModelError(f"{where}: a spike of 0 kgf is none")
        return ScheduledFault(kind, list(names).index(channel), at, value_kgf=value)
    if m["value"] is not None:
        raise ModelError(f"{where}: a heartbeat's silence takes no value; give heartbeat:CHANNEL@T+D")
    duration = number("duration", "how long the heartbeat stays away, +D in s (heartbeat:CHANNEL@T+D)")
    if duration <= 0:
        raise ModelError(f"{where}: the heartbeat's silence must last more than 0 s")
    return ScheduledFault(kind, list(names).index(channel), at, duration_s=duration)


class FaultSchedule:
    """The faults still to come, in the order of their stand times."""

    def __init__(self, faults: Sequence[ScheduledFault] = ()) -> None:
        self.pending = sorted(faults, key=lambda f: f.at_s)

    def due(self, stand_time_s: float) -> list[ScheduledFault]:
        """The faults whose time has come (each once)."""
        n = 0
        while n < len(self.pending) and self.pending[n].at_s <= stand_time_s + 1e-9:
            n += 1
        due, self.pending = self.pending[:n], self.pending[n:]
        return due
