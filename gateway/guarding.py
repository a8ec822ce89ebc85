"""Node guarding, the master's side (CiA 301 §7.2.8.3.2.1): for a device without a heartbeat.

Every guard time the master sends a remote frame on 0x700 + node id; the node answers with one
byte, its NMT state in bits 0-6 and a toggle bit 7 that alternates from answer to answer. The
answers reach the master's heartbeat handler like heartbeats (the state is what the supervisor
watches: an answer older than the heartbeat timeout stops the run); a toggle that does not
alternate is counted. The node guards its life the other way round: no remote frame within
guard time × life time factor (0x100C × 0x100D) and it goes to its own safe state.

One thread for every guarded node of a gateway; the remote frames go out through the network's
send path, so the run's capture has them.
"""
from __future__ import annotations

import logging
import threading

import can

from dbc import profile as P

log = logging.getLogger(__name__)

#: a guard request's data length code: the answer's (one byte), as CiA 301 devices expect
GUARD_RTR_DLC = 1


class NodeGuarding:
    """Guards ``links`` (master :class:`~gateway.master.NodeLink`) on ``network`` every
    ``period_s``; :meth:`poll` asks at once (the master waiting for a state)."""

    def __init__(self, network, links, period_s: float) -> None:
        self.network = network
        self.links = list(links)
        self.period_s = period_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        for link in self.links:
            link.poll = self.poll

    def start(self) -> "NodeGuarding":
        if self._thread is None and self.links:
            self._thread = threading.Thread(target=self._run, name="node-guarding", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2 * self.period_s + 1.0)
            self._thread = None
        for link in self.links:
            link.poll = None

    def poll(self) -> None:
        """One guard request to every guarded node, now."""
        for link in self.links:
            msg = can.Message(arbitration_id=P.HEARTBEAT_BASE + link.id, is_extended_id=False,
                              is_remote_frame=True, dlc=GUARD_RTR_DLC)
            try:
                self.network.send_raw_message(msg)
            except (can.CanError, OSError, AttributeError) as exc:
                log.debug("node guarding: request to node %d not sent: %s", link.id, exc)

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self.poll()
