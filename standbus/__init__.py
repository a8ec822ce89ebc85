"""The bus layer: our loopback-pinned python-can interface and bus specifications.

Nothing above this package knows which python-can interface it got.
"""
from .spec import DEFAULT_BUS, BusSpec, BusSpecError, open_bus

__all__ = ["DEFAULT_BUS", "BusSpec", "BusSpecError", "open_bus"]
