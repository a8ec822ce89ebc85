"""The errors a user can act on live in :mod:`core.errors` (every layer raises them); this name
stays for scripts that import them from the gateway."""
from core.errors import DataError, NodeError, ParameterError, SafetyStop, StandError

__all__ = ["DataError", "NodeError", "ParameterError", "SafetyStop", "StandError"]
