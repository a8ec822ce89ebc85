"""Put a capture back on a bus, like can-utils' ``canplayer``: original timing, scaled, or as
fast as possible, onto any python-can bus (``standbus.open_bus`` specs).

Timing: frame i goes out at ``w0 + v_i / speed``, where ``v_i`` is its capture time since the
first frame with backward steps counted as 0 and gaps longer than ``max_gap_s`` shortened to it
(python-can's ``MessageSync`` calls this ``skip``). The schedule is absolute (no drift): the
replayer sleeps until shortly before a frame's time and spins the rest, so a frame that went out
late does not delay the ones after it. ``speed=None`` sends as fast as the bus accepts.

Error frames cannot be sent and are skipped (counted).
"""
from __future__ import annotations

import random
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable

import can
import numpy as np

from .frames import ERROR, EXTENDED, FD, REMOTE, FrameChunk

LATE_SAMPLE = 100_000


@dataclass
class ReplayStats:
    frames: int = 0
    sent: int = 0
    skipped_error_frames: int = 0
    filtered: int = 0
    send_errors: int = 0
    first_send_error: str | None = None
    backwards: int = 0               #: timestamps that went backwards (sent at once)
    gaps_shortened: int = 0
    capture_span_s: float = 0.0      #: capture time covered (after shortening gaps)
    wall_s: float = 0.0
    max_late_s: float = 0.0          #: the latest a frame went out after its scheduled time
    late_s: list = field(default_factory=list, repr=False)   #: a uniform sample (at most 100,000)
    _timed: int = field(default=0, repr=False)
    _rng: random.Random = field(default_factory=lambda: random.Random(0), repr=False)

    def add_late(self, late: float) -> None:
        """Reservoir sample of the lateness, so memory stays bounded on endless replays."""
        self._timed += 1
        self.max_late_s = max(self.max_late_s, late)
        if len(self.late_s) < LATE_SAMPLE:
            self.late_s.append(late)
        else:
            j = self._rng.randrange(self._timed)
            if j < LATE_SAMPLE:
                self.late_s[j] = late

    def as_dict(self) -> dict:
        out = {k: v for k, v in self.__dict__.items() if not k.startswith("_") and k != "late_s"}
        if self.late_s:
            late = np.asarray(self.late_s)
            out["late_ms_p50"] = float(np.percentile(late, 50) * 1e3)
            out["late_ms_p99"] = float(np.percentile(late, 99) * 1e3)
        return out


class Replayer:
    """Send chunks of frames on ``bus`` with the capture's timing."""

    def __init__(self, bus: can.BusABC, speed: float | None = 1.0, max_gap_s: float | None = None,
                 ids: set[int] | None = None, clock: Callable[[], float] = time.perf_counter,
                 sleep: Callable[[float], None] = time.sleep, spin_s: float = 0.0003) -> None:
        if speed is not None and not speed > 0:
            raise ValueError(f"speed must be positive (or None for as fast as possible), not {speed}")
        if max_gap_s is not None and not max_gap_s >= 0:
            raise ValueError(f"max_gap_s must be >= 0, not {max_gap_s}")
        self.bus = bus
        self.speed = speed
        self.max_gap_s = max_gap_s
        self.ids = ids
        self.clock = clock
        self.sleep = sleep
        self.spin_s = spin_s
        self.stats = ReplayStats()
        self._w0: float | None = None
        self._v = 0.0
        self._last_ts: float | None = None

    def schedule(self, ts: np.ndarray) -> np.ndarray:
        """Capture-relative send times (s of capture time) of the frames ``ts``, continuing the
        schedule of the chunks before."""
        if not len(ts):
            return ts
        prev = ts[0] if self._last_ts is None else self._last_ts
        steps = np.diff(ts, prepend=prev)
        back = steps < 0
        self.stats.backwards += int(back.sum())
        steps = np.where(back, 0.0, steps)
        if self.max_gap_s is not None:
            long = steps > self.max_gap_s
            self.stats.gaps_shortened += int(long.sum())
            steps = np.where(long, self.max_gap_s, steps)
        v = self._v + np.cumsum(steps)
        self._v = float(v[-1])
        self._last_ts = float(ts[-1])
        self.stats.capture_span_s = self._v
        return v

    def _wait(self, target: float) -> None:
        while True:
            remaining = target - self.clock()
            if remaining <= 0:
                return
            if remaining > self.spin_s:
                self.sleep(remaining - self.spin_s)

    def play(self, chunks: Iterable[FrameChunk], stop: Callable[[], bool] | None = None) -> ReplayStats:
        st = self.stats
        t_start = self.clock()
        for chunk in chunks:
            st.frames += len(chunk)
            keep = (chunk.flags & ERROR) == 0
            st.skipped_error_frames += int((~keep).sum())
            if self.ids is not None:
                wanted = np.isin(chunk.can_id, list(self.ids))
                st.filtered += int((keep & ~wanted).sum())
                keep &= wanted
            v = self.schedule(chunk.ts)
            rows = np.flatnonzero(keep)
            ids = chunk.can_id[rows].tolist()
            flags = chunk.flags[rows].tolist()
            dlcs = chunk.dlc[rows].tolist()
            payloads = [bytes(r[:n]) for r, n in zip(chunk.data[rows], dlcs)]
            times = v[rows].tolist()
            ts = chunk.ts[rows].tolist()
            for cid, fl, dlc, data, vt, t in zip(ids, flags, dlcs, payloads, times, ts):
                if stop is not None and stop():
                    st.wall_s = self.clock() - t_start
                    return st
                if self.speed is not None:
                    if self._w0 is None:
                        self._w0 = self.clock()
                    target = self._w0 + vt / self.speed
                    self._wait(target)
                    st.add_late(self.clock() - target)
                msg = can.Message(timestamp=t, arbitration_id=cid, is_extended_id=bool(fl & EXTENDED),
                                  is_remote_frame=bool(fl & REMOTE), is_fd=bool(fl & FD), dlc=dlc,
                                  data=None if fl & REMOTE else data, check=False)
                try:
                    self.bus.send(msg)
                    st.sent += 1
                except can.CanError as exc:
                    st.send_errors += 1
                    if st.first_send_error is None:
                        st.first_send_error = str(exc)
        st.wall_s = self.clock() - t_start
        return st
