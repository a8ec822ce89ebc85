"""Reading a bus in tests."""
from __future__ import annotations

import time


def recv_frames(bus, n: int, timeout: float = 2.0, poll: float = 0.1) -> list:
    """Up to ``n`` frames from ``bus``, waiting at most ``timeout`` seconds in all."""
    out = []
    deadline = time.monotonic() + timeout
    while len(out) < n and time.monotonic() < deadline:
        m = bus.recv(poll)
        if m is not None:
            out.append(m)
    return out
