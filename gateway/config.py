"""How to reach and drive the stand (:class:`GatewayConfig`): bus, node ids, period, clock,
limits; or a rig's buses and channels (:class:`rig.config.RigConfig`). Nothing here describes
the plant; nothing here opens the bus."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from dbc import profile as P
from standbus.realtime import DEFAULT_PRIORITY
from standbus.spec import DEFAULT_BUS, BusSpec, BusSpecError

from .errors import ParameterError
from .experiments.base import check_range
from .limits import SafetyLimits

if TYPE_CHECKING:
    from devices import DeviceSet
    from rig.config import ChannelConfig, RigConfig

#: how long the master waits for a node's SDO answer (canopen's default is 0.3 s, with no
#: retry). A device answers in milliseconds; the slack is for a loaded host or a slow emulator
#: (user-mode Linux), where a lost answer would end a run before it began.
SDO_TIMEOUT_S = 1.0

#: what a channel's communication or valve fault does to a rig's other channels
FAULT_ACTIONS = ("hold", "unload")


@dataclass
class GatewayConfig:
    """How to reach and drive the stand. Nothing here describes the plant."""

    bus: str = DEFAULT_BUS
    valve_id: int = P.VALVE_NODE_ID
    dynamometer_id: int = P.DYNAMOMETER_NODE_ID
    period_s: float = 0.002
    lockstep: bool = False
    boot_timeout_s: float = 5.0
    #: how long the master waits for a node's SDO answer (SDO_TIMEOUT_S)
    sdo_timeout_s: float = SDO_TIMEOUT_S
    heartbeat_ms: int = 100
    rpdo_timeout_ms: int = 100
    limits: SafetyLimits = field(default_factory=SafetyLimits)
    #: real time: SCHED_FIFO priority of the process's threads (loop, bus reader, recorder,
    #: capture) during a run where the host allows it (standbus.realtime); 0: ordinary scheduling
    rt_priority: int = DEFAULT_PRIORITY
    #: a rig: its buses and channels (then ``bus``, the node ids, ``period_s`` and
    #: ``heartbeat_ms`` come from it, and each channel's force limit from its channel)
    rig: "RigConfig | None" = None
    #: a rig: what a channel's communication or valve fault does to the other channels: hold
    #: them all, or unload them keeping the load ratios (docs/safety.md)
    fault_action: str = "hold"
    #: the stand's valve drive and amplifier (:mod:`devices`; None: the emulated pair); a rig's
    #: come from its channels
    devices: "DeviceSet | None" = None

    def __post_init__(self) -> None:
        if self.rig is not None:
            self.period_s = self.rig.period_s
            self.heartbeat_ms = self.rig.heartbeat_ms

    def channel_limits(self, channel: "ChannelConfig") -> SafetyLimits:
        """A rig channel's limits: the shared ones with the channel's own force limit."""
        return dataclasses.replace(self.limits, force_limit_kgf=channel.limit_kgf)

    def life_time_factor(self) -> int:
        """Node guarding: a guarded node's life time in guard times (``heartbeat_ms``), as long
        as the master's own timeout for its answers (the supervisor's heartbeat timeout), at
        least 3: a node must not give its master up sooner than the master gives it up."""
        timeout_ms = 1000 * self.limits.resolved(self.lockstep).heartbeat_timeout_s
        return max(3, min(255, math.ceil(timeout_ms / self.heartbeat_ms)))

    def validate(self) -> None:
        if self.fault_action not in FAULT_ACTIONS:
            raise ParameterError(f"fault_action = {self.fault_action!r}: choose one of "
                                 f"{', '.join(FAULT_ACTIONS)}")
        check_range("period_s", self.period_s, 0.0005, 0.1, "s")
        check_range("rt_priority", self.rt_priority, 0, 99, integer=True)
        check_range("valve_id", self.valve_id, 1, 127, integer=True)
        check_range("dynamometer_id", self.dynamometer_id, 1, 127, integer=True)
        if self.valve_id == self.dynamometer_id:
            raise ParameterError("valve_id and dynamometer_id must differ")
        check_range("boot_timeout_s", self.boot_timeout_s, 0.1, 600, "s")
        check_range("sdo_timeout_s", self.sdo_timeout_s, 0.01, 60, "s")
        check_range("heartbeat_ms", self.heartbeat_ms, 10, 10000, "ms", integer=True)
        check_range("rpdo_timeout_ms", self.rpdo_timeout_ms, 0, 60000, "ms", integer=True)
        self.limits.validate()
        heartbeat_timeout_s = self.limits.resolved(self.lockstep).heartbeat_timeout_s
        if heartbeat_timeout_s * 1000 <= self.heartbeat_ms:
            raise ParameterError(
                f"heartbeat timeout {heartbeat_timeout_s * 1e3:g} ms must exceed the "
                f"nodes' heartbeat period {self.heartbeat_ms} ms (CiA 301: consumer time > producer "
                "time; 2-3.5x is usual)")
        try:
            BusSpec.parse(self.bus)
        except BusSpecError as exc:
            raise ParameterError(str(exc)) from None
