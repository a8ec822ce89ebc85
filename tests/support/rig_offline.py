"""The example rig for offline load passes (gateway.offline: the emulator's coupled lockstep
plant, no bus)."""
from __future__ import annotations

from gateway.offline import OfflinePass, emulated_truth, run_offline_pass  # noqa: F401

from .rig import EXAMPLE_RIG

T = 0.002


def example_truth():
    """The example rig's coupled plant as the emulator runs it, and each channel's noise."""
    return emulated_truth(EXAMPLE_RIG)
