"""Raw bus capture of a run, written through python-can's loggers.

The default file is a candump log (``capture.log``, can-utils' ``candump -L`` format): line based,
so a crash loses at most the last partial line, and readable by can-utils, python-can's
``LogReader`` and our decoder. (python-can's BLF and MF4 writers lose everything if the process
dies before ``stop()``, so they are offered only on request.)

Frames reach the capture from two sides: received frames from the network's Notifier (this is a
``can.Listener``) and frames the gateway itself sends (:class:`TappedNetwork`), because a
SocketCAN-like bus does not echo a sender's own frames. A background thread does the writing, so
the control loop only pays for a queue put; it flushes at least every ``flush_s`` seconds.
"""
from __future__ import annotations

import os
import queue
import threading
import time
from pathlib import Path

import can
import canopen


class BusCapture(can.Listener):
    """Queue frames and write them from a background thread with periodic flushes."""

    def __init__(self, path: str | Path, flush_s: float = 0.25) -> None:
        self.path = Path(path)
        self._writer = can.Logger(str(self.path))
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._flush_s = flush_s
        self._closed = threading.Event()
        self.frames = 0
        self._thread = threading.Thread(target=self._drain, name="bus-capture", daemon=True)
        self._thread.start()

    def on_message_received(self, msg: can.Message) -> None:
        self._queue.put(msg)

    def on_sent(self, msg: can.Message) -> None:
        self._queue.put(msg)

    def _drain(self) -> None:
        last_flush = time.monotonic()
        while True:
            try:
                msg = self._queue.get(timeout=self._flush_s / 2)
            except queue.Empty:
                msg = None
            if msg is not None:
                self._writer.on_message_received(msg)
                self.frames += 1
            now = time.monotonic()
            if now - last_flush >= self._flush_s or (msg is None and self._closed.is_set()):
                self._flush()
                last_flush = now
                if msg is None and self._closed.is_set():
                    return

    def _flush(self) -> None:
        fh = getattr(self._writer, "file", None)
        if fh is not None and not fh.closed:
            fh.flush()
            try:
                os.fsync(fh.fileno())
            except (OSError, ValueError):
                pass

    def stop(self) -> None:
        """Write everything queued, then close the file."""
        self._closed.set()
        self._thread.join()
        self._writer.stop()


class TappedNetwork(canopen.Network):
    """A canopen network that also hands every frame it sends to a capture."""

    def __init__(self, bus: can.BusABC | None = None) -> None:
        super().__init__(bus)
        self.capture: BusCapture | None = None

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        msg = can.Message(is_extended_id=can_id > 0x7FF, arbitration_id=can_id, data=data,
                          is_remote_frame=remote, is_rx=False, channel=getattr(self.bus, "channel", None))
        with self.send_lock:
            self.bus.send(msg)
        capture = self.capture
        if capture is not None:
            msg.timestamp = time.time()
            capture.on_sent(msg)
