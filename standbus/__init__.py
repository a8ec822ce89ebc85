"""The bus layer: our loopback-pinned python-can interface and bus specifications.

Nothing above this package knows which python-can interface it got.
"""
from .handover import HandoverNotifier
from .loopback import LOCKSTEP_BUSY_POLL_S, prefer_busy_poll
from .spec import DEFAULT_BUS, BusSpec, BusSpecError, open_bus

__all__ = ["DEFAULT_BUS", "BusSpec", "BusSpecError", "open_bus", "HandoverNotifier",
           "LOCKSTEP_BUSY_POLL_S", "prefer_busy_poll"]
