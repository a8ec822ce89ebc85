"""Run-time protection: decides every cycle whether the run may go on, and shapes the command.

Checked every cycle (each check names the reason written into the run's metadata):

* ``force_limit``: |y| beyond the force limit;
* ``heartbeat_lost``: no heartbeat from a node for longer than the consumer time;
* ``force_pdo_stale``: no fresh force PDO for N consecutive cycles;
* ``emcy``: an emergency message from a node (other than "error reset");
* ``nmt_state``: a node left OPERATIONAL.

The command is clamped to ±``command_limit_pct`` and rate-limited to ``slew_pct_per_s`` if set.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

from dbc import profile as P

from .master import StandMaster


@dataclass
class SafetyLimits:
    force_limit_kgf: float = 9500.0
    command_limit_pct: float = 100.0
    slew_pct_per_s: float | None = None
    heartbeat_timeout_s: float = 0.35
    stale_cycles: int = 25


class Supervisor:
    def __init__(self, master: StandMaster, limits: SafetyLimits, period_s: float) -> None:
        self.master = master
        self.limits = limits
        self.period_s = period_s
        self._stale_run = 0
        self._last_u = 0.0
        self._emcy: list[str] = []
        self._lock = threading.Lock()
        self.emcy_log: list[dict] = []
        for link in master.links:
            link.node.emcy.add_callback(self._emcy_callback(link))

    def _emcy_callback(self, link):
        def on_emcy(entry) -> None:
            record = {"node": link.id, "role": link.role, "code": entry.code,
                      "register": entry.register, "text": P.emcy_text(entry.code),
                      "time": time.time()}
            with self._lock:
                self.emcy_log.append(record)
                if entry.code & 0xFF00:
                    self._emcy.append(f"EMCY 0x{entry.code:04X} from {link.role} node {link.id}: "
                                      f"{P.emcy_text(entry.code)}")
        return on_emcy

    def reset(self) -> None:
        with self._lock:
            self._emcy.clear()
        self._stale_run = 0
        self._last_u = 0.0

    def check(self, y: float, stale: bool) -> tuple[str, str] | None:
        """``(reason, message)`` if the run must stop now, else None."""
        lim = self.limits
        if stale:
            self._stale_run += 1
            if self._stale_run >= lim.stale_cycles:
                return "force_pdo_stale", (f"no fresh force PDO for {self._stale_run} cycles "
                                           f"({self._stale_run * self.period_s * 1e3:.0f} ms)")
        else:
            self._stale_run = 0
            if not math.isfinite(y) or abs(y) > lim.force_limit_kgf:
                return "force_limit", f"force {y:.0f} kgf beyond the limit ±{lim.force_limit_kgf:.0f} kgf"
        with self._lock:
            if self._emcy:
                return "emcy", self._emcy[0]
        now = time.monotonic()
        for link in self.master.links:
            if link.last_heartbeat is None or now - link.last_heartbeat > lim.heartbeat_timeout_s:
                age = "never" if link.last_heartbeat is None else f"{(now - link.last_heartbeat) * 1e3:.0f} ms ago"
                return "heartbeat_lost", f"{link.role} node {link.id}: last heartbeat {age}"
            if link.nmt_state != 5:
                return "nmt_state", f"{link.role} node {link.id} left OPERATIONAL (state {link.nmt_state})"
        return None

    def shape_command(self, u: float) -> float:
        """Clamp, rate-limit and sanitise the command (NaN/inf → 0)."""
        lim = self.limits
        if not math.isfinite(u):
            u = 0.0
        u = max(-lim.command_limit_pct, min(lim.command_limit_pct, u))
        if lim.slew_pct_per_s:
            step = lim.slew_pct_per_s * self.period_s
            u = max(self._last_u - step, min(self._last_u + step, u))
        self._last_u = u
        return u
