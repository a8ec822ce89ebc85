"""Node guarding, the node's side (CiA 301 §7.2.8.3.2.1): for a device without a heartbeat.

The master's remote frame on 0x700 + node id is answered with one byte: the NMT state in bits
0-6 and a toggle bit 7, 0 in the first answer after boot-up and alternating. Life guarding:
once the first request came, a node that hears none within guard time × life time factor
(0x100C × 0x100D, ms) has lost its master: :meth:`EmulatedNode.life_guard_lost` (the valve goes
to its own safe state, EMCY 0x8130). The wall clock counts, in lockstep too: the master guards
on the wall clock.
"""
from __future__ import annotations

import time

import can

from dbc import profile as P

GUARD_TIME, LIFE_TIME_FACTOR = 0x100C, 0x100D
NMT_STATE_CODES = {"INITIALISING": 0, "STOPPED": 4, "OPERATIONAL": 5, "PRE-OPERATIONAL": 127}


class GuardedNode:
    """A node's guarding state: its toggle bit and when the master last asked."""

    def __init__(self, node) -> None:
        self.node = node
        self.toggle = 0
        self.last_request: float | None = None
        self.requests = 0

    def reset(self) -> None:
        """Boot-up: the toggle starts at 0 and life guarding waits for the first request."""
        self.toggle = 0
        self.last_request = None

    def on_request(self, msg: can.Message) -> None:
        """The master's remote frame: answer with the state and the toggle bit."""
        node = self.node
        with node.lock:
            if node.heartbeat_silent:           # a silenced node answers nothing (a fault)
                return
            self.last_request = time.monotonic()
            self.requests += 1
            state = NMT_STATE_CODES.get(node.nmt_state, 0)
            data = bytes((state | self.toggle << 7,))
            self.toggle ^= 1
        node.network.send_message(P.HEARTBEAT_BASE + node.id, data)

    def life_time_s(self) -> float | None:
        """Guard time × life time factor, s; None when life guarding is off (either is 0)."""
        guard, factor = int(self.node.value(GUARD_TIME)), int(self.node.value(LIFE_TIME_FACTOR))
        return guard * factor / 1000.0 if guard and factor else None

    def life_expired(self, now: float) -> bool:
        """True once when the master's requests stopped for longer than the life time."""
        last = self.last_request
        if last is None:
            return False
        life = self.life_time_s()
        if life is None or now - last <= life:
            return False
        self.last_request = None           # reported once, until the master asks again
        return True
