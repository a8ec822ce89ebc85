"""Errors a user can act on. The CLI prints their message (no traceback) and exits with 2."""
from __future__ import annotations


class StandError(Exception):
    """Base class: the message says what was wrong and what to do."""


class ParameterError(StandError):
    """An experiment or configuration parameter is out of range or malformed."""


class NodeError(StandError):
    """A CANopen node is missing, the wrong device, or misbehaving."""

    def __init__(self, node_id: int, message: str) -> None:
        super().__init__(message)
        self.node_id = node_id


class SafetyStop(StandError):
    """The supervisor brought the stand to its safe state; ``reason`` names the cause."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


class DataError(StandError):
    """Input data (a run, a CSV, a capture) is unusable for the requested analysis."""
