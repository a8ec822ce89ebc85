"""Run-time protection: decides every cycle whether the run may go on, shapes the command, and
takes the stand to its safe state when it may not — the way servo-hydraulic test controllers do
it (MTS, Moog: limit detectors with a chosen action, error detectors, controlled unload),
with CANopen's own mechanisms (heartbeat consumer, EMCY, the valve's status word).

Detectors (each *trip* names the reason written into the run's metadata; see docs/safety.md
for the stated reaction times):

=================  =======================================================  =================
reason             condition                                                action
=================  =======================================================  =================
force_limit        fresh |y| > ``force_limit_kgf``                          ``force_action``
error_limit        |r − y| > ``error_limit_kgf`` for ``error_time_s``        ``error_action``
force_pdo_stale    no fresh force PDO for ``stale_cycles`` cycles            hold
heartbeat_lost     a node's last heartbeat older than ``heartbeat_timeout_s`` hold
nmt_state          a node's heartbeat says it left OPERATIONAL               hold
emcy               an EMCY (code ≠ 0x00xx) from a configured node            hold
valve_fault        the valve's status word shows a fault state               hold
valve_not_active   the valve not ACTIVE for ``stale_cycles`` fresh cycles    hold
overrun            a real-time cycle starts > ``overrun_limit_s`` late        hold
=================  =======================================================  =================

Actions:

* ``indicate`` — log an event in the run (``events`` in run.json) and go on;
* ``hold`` — stop the run: valve control word HOLD with zero setpoint (the valve's hold
  setpoint 0x6314, zero flow): the actuator stops where it is;
* ``unload`` — controlled unload (:class:`Unloader`): the experiment stops, a gentle closed loop
  ramps the force to about zero, then hold. Needs fresh force readings: a communication fault
  during the unload switches to hold at once;
* ``zero`` — immediate zero setpoint and the valve to DISABLED (spool to its fail-safe
  position; 'hydraulics off'), bypassing any slew limit.

The command of every cycle is clamped to ±``command_limit_pct`` (and to the experiment's own
declared ``max_command_pct``) and rate-limited to ``slew_pct_per_s`` (NaN/inf → 0):
:meth:`Supervisor.shape_command`.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from dbc import profile as P

from .limits import SafetyLimits  # noqa: F401 (re-exported: the supervisor's configuration)

if TYPE_CHECKING:
    from .master import StandMaster

#: status word values (bits 0-3) of the valve's fault states
_FAULT_STATES = frozenset(s.value for s in P.ValveState if s.is_fault)
_ACTIVE = P.ValveState.ACTIVE.value
#: an indicate-only detector re-arms when the quantity falls below this share of its limit
_REARM = 0.95


@dataclass
class Trip:
    """A detector fired: why, what to do, and the times that bound the reaction."""

    reason: str
    message: str
    action: str                       #: hold | unload | zero
    onset_wall: float                 #: when the fault became observable (time.time())
    bound_s: float                    #: stated bound from onset to the safe command, s
    detected_wall: float = field(default_factory=time.time)
    safe_wall: float | None = None    #: when the safe-state command went out
    #: a rig: the channel whose detector fired (None: the loop's own, e.g. an overrun)
    channel: str | None = None

    def record(self) -> dict[str, Any]:
        """The ``safety`` block of run.json."""
        out = {"reason": self.reason, "action": self.action, "message": self.message,
               "onset": self.onset_wall, "detected": self.detected_wall,
               "safe_state": self.safe_wall, "bound_s": self.bound_s}
        if self.channel is not None:
            out["channel"] = self.channel
        if self.safe_wall is not None:
            out["reaction_s"] = self.safe_wall - self.onset_wall
        return out


class Unloader:
    """Controlled unload: ramp the force to about zero with a gentle closed loop, then hold.

    Reference ``r(t) = y0 − sign(y0)·min(R·t, |y0|)`` (R = ``unload_rate_kgf_per_s``), command
    ``u = clip(K·(r − y), ±u_max)`` with K = ``unload_gain_pct_per_kgf``. For the paper's plant
    dy/dt = g·u(t−τ) (eq. 1) the loop gain is K·g (1/s) and its phase margin
    π/2 − K·g·τ: the defaults (K = 0.02 %/kgf, g ≈ 120 kgf/(%·s), τ = 50 ms) give a time
    constant 1/(K·g) ≈ 0.4 s and a phase lag K·g·τ ≈ 0.12 rad: no oscillation even if g is
    several times larger. Done when the ramp has ended and |y| ≤ ``unload_tolerance_kgf``;
    gives up (→ hold) if, after a grace time of :attr:`GRACE_S` (the command in flight and the
    transport delay still push the force on at first), the force is still more than the
    tolerance above where it started, or it overshoots by 10 % of the force limit at any time,
    or after ``unload_timeout_s``.
    """

    GRACE_S = 0.5

    def __init__(self, y0: float, limits: SafetyLimits, period_s: float) -> None:
        self.y0 = y0
        self.limits = limits
        self.period_s = period_s
        self.t = 0.0
        self.done = False
        self.outcome: str | None = None   #: "unloaded", "force_rising", "timeout"
        self.cycles = 0

    def step(self, y: float) -> tuple[float, float]:
        """One cycle: ``(command %, reference kgf)``; sets :attr:`done` when finished."""
        lim = self.limits
        drop = min(lim.unload_rate_kgf_per_s * self.t, abs(self.y0))
        r = self.y0 - math.copysign(drop, self.y0)
        self.t += self.period_s
        self.cycles += 1
        rise = abs(y) - abs(self.y0)
        if rise > 0.1 * lim.force_limit_kgf or (self.t > self.GRACE_S and rise > lim.unload_tolerance_kgf):
            self.done, self.outcome = True, "force_rising"
            return 0.0, r
        if drop >= abs(self.y0) and abs(y) <= lim.unload_tolerance_kgf:
            self.done, self.outcome = True, "unloaded"
            return 0.0, r
        if self.t > lim.unload_timeout_s:
            self.done, self.outcome = True, "timeout"
            return 0.0, r
        u = lim.unload_gain_pct_per_kgf * (r - y)
        return max(-lim.unload_max_pct, min(lim.unload_max_pct, u)), r

    def record(self, y_end: float) -> dict[str, Any]:
        return {"from_kgf": self.y0, "to_kgf": y_end, "duration_s": self.t, "outcome": self.outcome}


class Supervisor:
    """Watches one stand (the master's two nodes) for one control loop."""

    def __init__(self, master: "StandMaster", limits: SafetyLimits, period_s: float,
                 lockstep: bool = False) -> None:
        self.master = master
        self.limits = limits.resolved(lockstep)
        self.period_s = period_s
        #: the longest the loop waits inside a cycle between two looks at the watchdogs, s
        #: (set by the loop: lockstep answer slice, or 0.8 period in real time)
        self.wait_s = period_s
        self._lock = threading.Lock()
        self._emcy: list[tuple[str, float]] = []     # (message, onset wall time) of pending EMCYs
        self.emcy_log: list[dict] = []
        #: indicate-only events of the current run (force or error limit crossed)
        self.events: list[dict] = []
        self.clamped = 0
        self.reset()
        for link in master.links:
            link.node.emcy.add_callback(self._emcy_callback(link))

    def _emcy_callback(self, link):
        def on_emcy(entry) -> None:
            now = time.time()
            ts = entry.timestamp if entry.timestamp and abs(entry.timestamp - now) < 5.0 else now
            record = {"node": link.id, "role": link.role, "code": entry.code,
                      "register": entry.register, "text": P.emcy_text(entry.code),
                      "time": now}
            with self._lock:
                self.emcy_log.append(record)
                if entry.code & 0xFF00:
                    self._emcy.append((f"EMCY 0x{entry.code:04X} from {link.role} node {link.id}: "
                                       f"{P.emcy_text(entry.code)}", ts))
        return on_emcy

    def reset(self, max_command_pct: float | None = None) -> None:
        """Start of a run: forget pending EMCYs, counters and detector states. The command is
        clamped to the smaller of ``command_limit_pct`` and the experiment's own declared
        ``max_command_pct``."""
        with self._lock:
            self._emcy.clear()
        self._stale_run = 0
        self._stale_since = 0.0
        self._inactive_run = 0
        self._err_run = 0
        self._err_since = 0.0
        #: indicate-only detectors that logged their event and wait to re-arm
        self._indicated: set[str] = set()
        self._last_u = 0.0
        #: the last command if it passed :meth:`shape_command` unchanged (NaN: none)
        self._held = math.nan
        slew = self.limits.slew_pct_per_s
        self._steady = not slew or (slew > 0 and self.period_s > 0)
        self.events = []
        self.clamped = 0
        lim = self.limits
        T = self.period_s
        self._err_cycles = max(1, math.ceil(lim.error_time_s / T - 1e-9))
        self.u_max = lim.command_limit_pct
        if max_command_pct is not None and math.isfinite(max_command_pct) and max_command_pct >= 0:
            self.u_max = min(self.u_max, float(max_command_pct))

    # -- bounds ------------------------------------------------------------------------------------
    def bound_s(self, reason: str) -> float:
        """The stated time from a fault's onset to the safe command (s)."""
        lim, T, wait_s = self.limits, self.period_s, self.wait_s
        return {
            "force_limit": T,
            "error_limit": self._err_cycles * T + T,
            "force_pdo_stale": lim.stale_cycles * T + T,
            "heartbeat_lost": lim.heartbeat_timeout_s + T + wait_s,
            "nmt_state": T + wait_s,
            "emcy": 2 * T + wait_s,
            "valve_fault": T,
            "valve_not_active": lim.stale_cycles * T + T,
            "overrun": T,
        }.get(reason, T + wait_s)

    def make_trip(self, reason: str, message: str, onset: float, action: str = "hold") -> Trip:
        """A trip with this supervisor's stated bound for ``reason``."""
        return Trip(reason, message, action, onset, self.bound_s(reason))

    # -- per cycle -------------------------------------------------------------------------------
    def check(self, y: float, stale: bool, status: int = _ACTIVE, sync_wall: float = 0.0,
              force: bool = True) -> Trip | None:
        """A :class:`Trip` if the run must stop (or unload) now, else None. ``force=False``
        skips the force-limit detector (during an unload)."""
        lim = self.limits
        if stale:
            if self._stale_run == 0:
                self._stale_since = sync_wall
            self._stale_run += 1
            if self._stale_run >= lim.stale_cycles:
                return self.make_trip("force_pdo_stale",
                                  f"no fresh force PDO for {self._stale_run} cycles "
                                  f"({self._stale_run * self.period_s * 1e3:.0f} ms)", self._stale_since)
        else:
            self._stale_run = 0
            if force and not abs(y) <= lim.force_limit_kgf:      # also NaN
                trip = self._force_limit(y, sync_wall)
                if trip is not None:
                    return trip
            elif abs(y) <= _REARM * lim.force_limit_kgf:
                self._indicated.discard("force_limit")
        if self._emcy:
            with self._lock:
                message, onset = self._emcy[0]
            return self.make_trip("emcy", message, onset)
        state = status & 0xF
        if state != _ACTIVE and status:
            if state in _FAULT_STATES:
                return self.make_trip("valve_fault", f"the valve reports a fault state "
                                  f"({P.ValveState(state).name}, status word 0x{status:04X}); it "
                                  "stays latched until reset: remove the cause, then run with "
                                  "--reset-faults (Gateway.reset_faults())", sync_wall)
            self._inactive_run += 1
            if self._inactive_run >= lim.stale_cycles:
                name = P.ValveState(state).name if state in P.ValveState._value2member_map_ else "?"
                return self.make_trip("valve_not_active", f"the valve stayed {name} (status word "
                                  f"0x{status:04X}) for {self._inactive_run} cycles although "
                                  "commanded ACTIVE", sync_wall)
        else:
            self._inactive_run = 0
        return self.check_nodes()

    def _limit_reached(self, reason: str, action: str, message: str, onset: float,
                       sync_wall: float, **values: float) -> Trip | None:
        """A limit detector fired: its trip, or for ``indicate`` one event per excursion
        (re-armed when the quantity is back below :data:`_REARM` of the limit) and go on."""
        if action != "indicate":
            return self.make_trip(reason, message, onset, action)
        if reason not in self._indicated:
            self._indicated.add(reason)
            self.events.append({"reason": reason, "message": message, "time": sync_wall, **values})
        return None

    def _force_limit(self, y: float, sync_wall: float) -> Trip | None:
        lim = self.limits
        message = f"force {y:.0f} kgf beyond the limit ±{lim.force_limit_kgf:.0f} kgf"
        return self._limit_reached("force_limit", lim.force_action, message, sync_wall, sync_wall,
                                   force_kgf=y)

    def check_error(self, r: float, y: float, stale: bool, sync_wall: float = 0.0) -> Trip | None:
        """The error detector, after the experiment gave this cycle's reference ``r``."""
        lim = self.limits
        if lim.error_limit_kgf is None or stale:
            return None
        e = r - y
        if not abs(e) > lim.error_limit_kgf:        # also r = NaN (no reference): no error
            self._err_run = 0
            if abs(e) <= _REARM * lim.error_limit_kgf:
                self._indicated.discard("error_limit")
            return None
        if self._err_run == 0:
            self._err_since = sync_wall
        self._err_run += 1
        if self._err_run < self._err_cycles:
            return None
        message = (f"control error |r − y| = {abs(e):.0f} kgf beyond {lim.error_limit_kgf:.0f} kgf "
                   f"for {self._err_run * self.period_s * 1e3:.0f} ms")
        return self._limit_reached("error_limit", lim.error_action, message, self._err_since,
                                   sync_wall, error_kgf=e)

    def check_nodes(self) -> Trip | None:
        """Communication watchdogs that need no cycle: EMCY, heartbeat, NMT state (also called
        while the loop waits for a node's answer)."""
        if self._emcy:
            with self._lock:
                message, onset = self._emcy[0]
            return self.make_trip("emcy", message, onset)
        now = time.monotonic()
        timeout = self.limits.heartbeat_timeout_s
        for link in self.master.links:
            hb = link.last_heartbeat
            if hb is None or now - hb > timeout:
                age = "never" if hb is None else f"{(now - hb) * 1e3:.0f} ms ago"
                onset = time.time() - (0.0 if hb is None else now - hb)
                return self.make_trip("heartbeat_lost", f"{link.role} node {link.id}: last heartbeat {age} "
                                  f"(timeout {timeout * 1e3:.0f} ms)", onset)
            if link.nmt_state != 5:
                return self.make_trip("nmt_state", f"{link.role} node {link.id} left OPERATIONAL "
                                  f"(state {link.nmt_state})", time.time() - (now - hb))
        return None

    def overrun(self, lateness_s: float, scheduled_wall: float) -> Trip | None:
        """Real time: a cycle that starts ``lateness_s`` after its scheduled time."""
        if lateness_s <= self.limits.overrun_limit_s:
            return None
        return self.make_trip("overrun", f"control cycle started {lateness_s * 1e3:.0f} ms late "
                          f"(limit {self.limits.overrun_limit_s * 1e3:.0f} ms): the command was "
                          "held that long", scheduled_wall)

    def shape_command(self, u: float) -> float:
        """Clamp, rate-limit and sanitise the command (NaN/inf → 0), in %."""
        if u == self._held:      # the last command again, which passed unchanged: so again
            return u
        lim = self.limits
        u_in = u
        u_max = self.u_max
        if not (-u_max <= u <= u_max):   # also NaN
            u = max(-u_max, min(u_max, u)) if math.isfinite(u) else 0.0
        if lim.slew_pct_per_s:
            step = lim.slew_pct_per_s * self.period_s
            u = max(self._last_u - step, min(self._last_u + step, u))
        if u != u_in:
            self.clamped += 1
        self._last_u = u
        # it passes unchanged again as long as it is asked for again: it is within ±u_max and
        # a slew step from itself (a positive step) is no step
        self._held = u if u == u_in and self._steady else math.nan
        return u

    def unloader(self, y0: float) -> Unloader:
        return Unloader(y0, self.limits, self.period_s)


class SupervisorBank:
    """A rig's supervisors asked together in the common cycle (:meth:`quiet`): every reading
    fresh and well inside its limit, every valve ACTIVE, no EMCY, every heartbeat recent and
    OPERATIONAL, no detector counting. Then every :meth:`Supervisor.check` would return None
    and change nothing, and the loop skips them (16 channels: ~60 µs of Python a cycle, now one
    pass of plain comparisons; numpy's per-call cost made a vectorised pass slower at this
    size); any other cycle asks each supervisor as before."""

    def __init__(self, supervisors: list[Supervisor]) -> None:
        self.supervisors = supervisors
        self.rearm = [_REARM * s.limits.force_limit_kgf for s in supervisors]
        self.links = [link for s in supervisors for link in s.master.links]
        self.heartbeat_timeout_s = min(s.limits.heartbeat_timeout_s for s in supervisors)

    def quiet(self, ys, statuses) -> bool:
        """True when every channel's :meth:`Supervisor.check` of a fresh reading (force
        detector on) would return None and change none of its state."""
        for s, y, status, rearm in zip(self.supervisors, ys, statuses, self.rearm):
            if s._stale_run or s._inactive_run or s._indicated or s._emcy:
                return False
            if not abs(y) <= rearm:                                # also NaN
                return False
            if status and status & 0xF != _ACTIVE:
                return False
        oldest = time.monotonic() - self.heartbeat_timeout_s
        for link in self.links:
            hb = link.last_heartbeat
            if hb is None or hb < oldest or link.nmt_state != 5:
                return False
        return True
