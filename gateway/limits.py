"""The supervisor's configuration (:class:`SafetyLimits`): the limits, the actions a trip takes
and the controlled unload's settings, in the stand's units (kgf, %, s). The supervisor that
applies them is :mod:`gateway.supervisor`; the gateway's configuration holds them."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from .errors import ParameterError
from .experiments.base import check_range

#: what a trip may do (module docstring of gateway.supervisor)
ACTIONS = ("indicate", "hold", "unload", "zero")
#: the heartbeat consumer's timeout unless set, in real time and in lockstep
HEARTBEAT_TIMEOUT_REALTIME_S = 0.35
HEARTBEAT_TIMEOUT_LOCKSTEP_S = 1.0
#: a loading programme's tracking-error limit unless one is given (``stand load``, ``stand
#: test``): this share of the channel's programme range, at least :data:`ERROR_LIMIT_MIN_KGF`
ERROR_LIMIT_SHARE = 0.10
ERROR_LIMIT_MIN_KGF = 100.0


def programme_error_limit_kgf(range_kgf: float) -> float:
    """The tracking-error limit of a channel whose programme spans ``range_kgf`` when none is
    given: :data:`ERROR_LIMIT_SHARE` of it, at least :data:`ERROR_LIMIT_MIN_KGF`."""
    return max(ERROR_LIMIT_SHARE * float(range_kgf), ERROR_LIMIT_MIN_KGF)


@dataclass
class SafetyLimits:
    """The supervisor's configuration (all in the stand's units: kgf, %, s)."""

    force_limit_kgf: float = 9500.0
    #: what a force-limit trip does: indicate | hold | unload | zero
    force_action: str = "hold"
    command_limit_pct: float = 100.0
    #: maximum command rate, %/s (None: no slew limit)
    slew_pct_per_s: float | None = None
    #: error detector: |r − y| beyond this (kgf) for ``error_time_s`` trips (None: off)
    error_limit_kgf: float | None = None
    error_time_s: float = 0.1
    error_action: str = "hold"
    #: a node's heartbeat older than this (s) stops the run; None: 0.35 s in real time
    #: (3.5 × the 100 ms producer time) and 1.0 s in lockstep, where a busy machine may delay
    #: the emulator's wall-clock heartbeats while SYNCs run as fast as the bus goes
    heartbeat_timeout_s: float | None = None
    stale_cycles: int = 25
    #: real time: a cycle starting later than this (s) stops the run (default: the valve's
    #: RPDO timeout, beyond which it has dropped to its fail-safe state anyway)
    overrun_limit_s: float = 0.1
    #: controlled unload: reference ramp rate (kgf/s), loop gain (%/kgf), command bound (%),
    #: "unloaded" band (kgf) and the time allowed before falling back to hold (s)
    unload_rate_kgf_per_s: float = 1000.0
    unload_gain_pct_per_kgf: float = 0.02
    unload_max_pct: float = 10.0
    unload_tolerance_kgf: float = 50.0
    unload_timeout_s: float = 30.0

    def resolved(self, lockstep: bool) -> "SafetyLimits":
        """A copy with the automatic settings decided for the clock mode."""
        if self.heartbeat_timeout_s is not None:
            return self
        return dataclasses.replace(self, heartbeat_timeout_s=HEARTBEAT_TIMEOUT_LOCKSTEP_S if lockstep
                                   else HEARTBEAT_TIMEOUT_REALTIME_S)

    def validate(self) -> None:
        """Raise :class:`ParameterError` for out-of-range, NaN or infinite settings."""
        check_range("force_limit_kgf", self.force_limit_kgf, 1, 1e6, "kgf")
        check_range("command_limit_pct", self.command_limit_pct, 0, 100, "%")
        if self.slew_pct_per_s is not None:
            check_range("slew_pct_per_s", self.slew_pct_per_s, 1e-3, 1e6, "%/s")
        if self.error_limit_kgf is not None:
            check_range("error_limit_kgf", self.error_limit_kgf, 1e-3, 1e6, "kgf")
        check_range("error_time_s", self.error_time_s, 0, 60, "s")
        if self.heartbeat_timeout_s is not None:
            check_range("heartbeat_timeout_s", self.heartbeat_timeout_s, 0.01, 60, "s")
        check_range("stale_cycles", self.stale_cycles, 1, 100000, integer=True)
        check_range("overrun_limit_s", self.overrun_limit_s, 1e-4, 60, "s")
        check_range("unload_rate_kgf_per_s", self.unload_rate_kgf_per_s, 1, 1e6, "kgf/s")
        check_range("unload_gain_pct_per_kgf", self.unload_gain_pct_per_kgf, 1e-6, 10, "%/kgf")
        check_range("unload_max_pct", self.unload_max_pct, 0.01, 100, "%")
        check_range("unload_tolerance_kgf", self.unload_tolerance_kgf, 0.1, 1e5, "kgf")
        check_range("unload_timeout_s", self.unload_timeout_s, 0.1, 3600, "s")
        for name in ("force_action", "error_action"):
            if getattr(self, name) not in ACTIONS:
                raise ParameterError(f"{name} = {getattr(self, name)!r}: choose one of "
                                     f"{', '.join(ACTIONS)}")
