"""Raw bus capture of a run, and the network the gateway talks through.

The default file is a candump log (``capture.log``, can-utils' ``candump -L`` format): line
based, readable by can-utils, python-can's ``LogReader`` and our decoder. Lines are formatted
by python-can's ``CanutilsLogWriter`` into memory and written to the file only as whole lines
(one ``os.write`` per flush, then ``fsync``) at least every ``flush_s`` = 0.25 s, so a killed
gateway leaves a file that ends with a complete line in all but the rarest case (a kill inside
that write); :func:`read_capture` also drops a trailing partial line. python-can's BLF writer
keeps frames in a 128 KiB in-memory container (about 2,700 frames: one to two seconds of this
bus at a 2 ms period) and writes it only when full or on ``stop()``, so a killed process loses
up to that much — a short run loses all of it (tests/test_crash_safety.py shows it); its MF4
writer (asammdf) finishes the file only on ``stop()``. They are used only when asked for by the
file name.

Frames reach the capture from two sides: received frames from the network's Notifier (this is a
``can.Listener``) and frames the gateway itself sends (:class:`TappedNetwork`), because a
SocketCAN-like bus does not echo a sender's own frames. A background thread does the writing, so
the control loop only pays for a queue put.

:class:`TappedNetwork` also puts a :class:`standbus.faults.FrameFilter` in front of the canopen
stack: only classic 11-bit data frames pass, and once the master has declared its nodes, only
frames on their ids with the right length (wrong DLC, unexpected ids: counted and dropped).
"""
from __future__ import annotations

import io
import logging
import os
import queue
import threading
import time
from pathlib import Path
from typing import Iterator

import can
import canopen
from canopen.network import MessageListener

from standbus import HandoverNotifier, together, wire
from standbus.faults import FrameFilter

log = logging.getLogger(__name__)


#: how often the capture thread formats what is queued, s. In real time its batch holds the
#: GIL that long in 0.2 ms slices (a rig bus's eighth of a second: ~1 ms), and a control cycle
#: whose work fell into that window ran past the next SYNC's time; a 10 ms batch (~0.1 ms, one
#: slice) does not (8 channels on 2 buses at 2 ms: docs/decisions.md). Lockstep keeps the long
#: batch, as measured there.
BATCH_REALTIME_S = 0.01
BATCH_LOCKSTEP_S = 0.125


#: candump's error-frame id and FD flags, as python-can's CanutilsLogWriter writes them
_ERROR_ID = 0x20000000 | 0x00000080
_FD_BRS, _FD_ESI = 0x01, 0x02


class CandumpLines:
    """candump ``-L`` lines of frames, exactly as python-can's ``CanutilsLogWriter`` writes
    them (its rules: a missing stamp, or one earlier than the first frame's, is written as the
    first frame's; a numeric channel as ``canN``), but from raw frames (:mod:`standbus.wire`) sent at one instant, so a
    batch's stamp and channel are formatted once (a rig's bus: ~0.4 µs a frame against 1.3)."""

    def __init__(self) -> None:
        self.last: float | None = None

    def lines(self, stamp: float | None, channel, frames, received: bool) -> str:
        if self.last is None:
            self.last = stamp or 0.0
        if stamp is None or stamp < self.last:
            stamp = self.last
        if channel is None:
            channel = "vcan0"                      # CanutilsLogWriter's default channel
        if isinstance(channel, int) or (isinstance(channel, str) and channel.isdigit()):
            channel = f"can{channel}"
        head = f"({stamp:f}) {channel} "
        eol = " R\n" if received else " T\n"
        out = []
        for flags, arb_id, _dlc, data in frames:
            if flags & wire.FLAG_ERROR:
                out.append(f"{head}{_ERROR_ID:08X}#{data.hex().upper()}\n")
                continue
            ident = f"{arb_id:08X}#" if flags & wire.FLAG_EXTENDED else f"{arb_id:03X}#"
            if flags & wire.FLAG_REMOTE:
                out.append(f"{head}{ident}R{eol}")
            elif flags & wire.FLAG_FD:
                fd = (_FD_BRS if flags & wire.FLAG_BRS else 0) | (_FD_ESI if flags & wire.FLAG_ESI else 0)
                out.append(f"{head}{ident}#{fd:X}{data.hex().upper()}{eol}")
            else:
                out.append(f"{head}{ident}{data.hex().upper()}{eol}")
        return "".join(out)


class CaptureTap(can.Listener):
    """Something that takes a network's frames, received and sent: attached first in line to
    its notifier (so frames come in the order received) and as its capture."""

    def attach(self, network: "TappedNetwork") -> None:
        """Capture every frame ``network`` receives (first, in the order received) and sends."""
        notifier = network.notifier
        if isinstance(notifier, HandoverNotifier):
            notifier.tap = self.on_frames
        else:
            notifier.listeners.insert(0, self)
        network.capture = self

    def detach(self, network: "TappedNetwork") -> None:
        network.capture = None
        notifier = network.notifier
        if isinstance(notifier, HandoverNotifier) and notifier.tap is not None:
            notifier.tap = None
        else:
            notifier.remove_listener(self)


class StartupCapture(CaptureTap):
    """The frames of the start-up (boot-ups, identity, the configuration's SDO transfers, node
    guarding), kept in memory while the gateway connects, so that each run's capture can begin
    with them (:meth:`BusCapture.write_first`): the traffic a user needs when a device will not
    start. Attached and detached as a :class:`BusCapture` is."""

    def __init__(self) -> None:
        self.items: list = []

    def on_message_received(self, msg: can.Message) -> None:
        self.items.append(msg)

    def on_sent(self, msg: can.Message) -> None:
        self.items.append(msg)

    def on_frames(self, stamp: float, frames, received: bool, channel=None) -> None:
        self.items.append((stamp, tuple(frames), received, channel))

    @property
    def frames(self) -> int:
        return sum(len(i[1]) if isinstance(i, tuple) else 1 for i in self.items)

    @property
    def last_stamp(self) -> float | None:
        if not self.items:
            return None
        last = self.items[-1]
        return last[0] if isinstance(last, tuple) else last.timestamp



class BusCapture(CaptureTap):
    """Queue frames and write them from a background thread: formatted every ``batch_s``,
    flushed to the file every ``flush_s``. Frames come as Messages (:meth:`on_message_received`,
    :meth:`on_sent`) or raw, a datagram's worth at a time (:meth:`on_frames`)."""

    def __init__(self, path: str | Path, flush_s: float = 0.25, batch_s: float = BATCH_LOCKSTEP_S) -> None:
        self.path = Path(path)
        self._lines: io.StringIO | None = None
        self._candump: CandumpLines | None = None
        if self.path.suffix.lower() == ".log":
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            self._lines = io.StringIO()
            self._candump = CandumpLines()
        else:   # BLF, MF4, ASC, ...: python-can's own writers, as asked for
            self._fd = None
            self._writer = can.Logger(str(self.path))
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        #: held while an item is taken from the queue and written (by this thread or by
        #: :meth:`write_one` on the control loop's), and while the lines go to the file: the
        #: lines keep the queue's order and none is lost between the two
        self._writing = threading.Lock()
        self._flush_s = flush_s
        self._batch_s = min(batch_s, flush_s / 2)
        self._closed = threading.Event()
        self.frames = 0
        self.write_errors = 0
        self._thread = threading.Thread(target=self._drain, name="bus-capture", daemon=True)
        self._thread.start()

    def on_message_received(self, msg: can.Message) -> None:
        self._queue.put(msg)

    def on_sent(self, msg: can.Message) -> None:
        self._queue.put(msg)

    def write_first(self, startup: StartupCapture | None) -> None:
        """Begin the file with the start-up's frames (call before :meth:`attach`)."""
        for item in startup.items if startup is not None else ():
            self._queue.put(item)

    def on_frames(self, stamp: float, frames, received: bool, channel=None) -> None:
        """Raw frames (:mod:`standbus.wire`) received or sent at ``stamp`` on ``channel``. The
        sequence is copied (each frame is a tuple of bytes): a sender may refill its list for
        the next cycle before this thread formats it."""
        self._queue.put((stamp, tuple(frames), received, channel))

    def write_one(self) -> bool:
        """Write the oldest queued item, on the caller's thread, if the capture thread is not
        writing; whether one was written. The lockstep loop calls it while it waits for the
        stand's answers (:meth:`gateway.loop.ControlLoop._handover`): it polls anyway, and the
        capture thread formatting beside it took the cores and the GIL from both sides of the
        bus (16 channels on 4 buses: 8.5-8.8x real time without captures, 6.8-7.0x with)."""
        if not self._writing.acquire(blocking=False):
            return False
        try:
            return self._write_next()
        finally:
            self._writing.release()

    def _write_next(self) -> bool:
        """Write the oldest queued item (the caller holds ``_writing``); whether there was one."""
        try:
            item = self._queue.get_nowait()
        except queue.Empty:
            return False
        try:
            self.frames += self._write(item)
        except Exception:          # one odd frame must not stop the capture
            self.write_errors += 1
        return True

    def _write(self, item) -> int:
        """One queued item into the file's lines (or python-can's writer); its frame count."""
        if self._candump is not None:
            if isinstance(item, tuple):
                stamp, frames, received, channel = item
            else:
                stamp, frames, received, channel = (item.timestamp, [wire.raw_of(item)],
                                                    item.is_rx, item.channel)
            self._lines.write(self._candump.lines(stamp, channel, frames, received))
            return len(frames)
        if isinstance(item, tuple):
            stamp, frames, received, channel = item
            for frame in frames:
                self._writer.on_message_received(wire.message(stamp, frame, channel, received))
            return len(frames)
        self._writer.on_message_received(item)
        return 1

    def _drain(self) -> None:
        """Every ``batch_s``: format everything queued, flush once ``flush_s`` has passed.
        Waking per batch, not per frame, keeps this thread off the control loop's GIL."""
        last_flush = time.monotonic()
        while True:
            closing = self._closed.wait(self._batch_s)
            with self._writing:
                while self._write_next():
                    pass
            now = time.monotonic()
            if closing or now - last_flush >= self._flush_s:
                self._flush()
                last_flush = now
            if closing:
                return

    def _flush(self) -> None:
        try:
            if self._lines is not None:
                with self._writing:
                    text = self._lines.getvalue()
                    if text:
                        self._lines.seek(0)
                        self._lines.truncate()
                if text:
                    data = text.encode("ascii", "replace")
                    while data:                      # whole lines, in as few writes as possible
                        n = os.write(self._fd, data)
                        data = data[n:]
                os.fsync(self._fd)
                return
            fh = getattr(self._writer, "file", None)
            if fh is not None and not fh.closed:
                with self._writing:
                    fh.flush()
                os.fsync(fh.fileno())
        except (OSError, ValueError, AttributeError) as exc:
            self.write_errors += 1
            log.warning("capture %s: flush failed: %s", self.path, exc)

    def stop(self) -> None:
        """Write everything queued, then close the file."""
        self._closed.set()
        self._thread.join()
        if self._lines is not None:
            self._flush()
            os.close(self._fd)
            self._fd = None
        else:
            self._writer.stop()

def read_capture(path: str | Path) -> Iterator[can.Message]:
    """The frames of a candump ``.log`` capture, tolerating what a crash leaves behind: a last
    line without its newline is dropped instead of being parsed as a shorter frame."""
    text = Path(path).read_text(encoding="ascii", errors="replace")
    if text and not text.endswith("\n"):
        text = text[:text.rfind("\n") + 1]
    yield from can.io.CanutilsLogReader(io.StringIO(text))


class TappedNetwork(canopen.Network):
    """A canopen network that hands every frame it sends to a capture and filters what it
    receives (see the module docstring)."""

    #: the Notifier's receive timeout, s: also how long closing the network (or handing the bus
    #: to the control loop) may take
    NOTIFIER_CYCLE = 0.1

    def __init__(self, bus: can.BusABC | None = None, notifier_cycle_s: float | None = None,
                 fd: bool = False, bitrate_switch: bool = False) -> None:
        super().__init__(bus)
        if notifier_cycle_s is not None:
            self.NOTIFIER_CYCLE = notifier_cycle_s
        self.capture: BusCapture | None = None
        #: acceptance filter in front of the canopen stack (strict once ids are declared); on a
        #: CAN FD bus FD frames pass too
        self.frame_filter = FrameFilter(MessageListener(self).on_message_received, fd=fd)
        self.listeners = [self.frame_filter]
        #: the wire flags of the cyclic frames (SYNC, PDOs): classic, or on a CAN FD bus FD
        #: frames (with the bit-rate switch where the data phase is faster)
        self.cyclic_flags = (wire.FLAG_FD | (wire.FLAG_BRS if bitrate_switch else 0)) if fd else 0

    def connect(self, *args, **kwargs) -> "TappedNetwork":
        """As canopen's, with a :class:`~standbus.HandoverNotifier`: the lockstep control loop
        reads the bus on its own thread (:meth:`handover`)."""
        if self.bus is None:
            self.bus = can.Bus(*args, **kwargs)
        self.notifier = HandoverNotifier(self.bus, self.listeners, self.NOTIFIER_CYCLE)
        return self

    def handover(self, spin_s: float = 0.0, idle=None):
        """Context manager: the bus reader thread parks; yields ``pump(timeout)`` that receives
        one frame on the caller's thread (polling ``spin_s`` before it sleeps, doing a piece
        of ``idle()`` work between polls) and hands it to every listener (canopen, capture)."""
        return self.notifier.handover(spin_s, idle=idle)

    def expect(self, can_id: int, lengths=None) -> None:
        """Accept frames on ``can_id`` with these data lengths; from the first call on, frames
        on undeclared ids are counted and dropped."""
        self.frame_filter.expect(can_id, lengths)
        self.frame_filter.strict = True

    def _of_bus(self) -> "tuple[str | int | None, together.RawPath | None]":
        """What the sends need to know of the bus, looked up once per bus: its channel name for
        captured frames (some interfaces keep other objects in ``bus.channel``: python-can's
        ``virtual`` keeps its receiver list there) and its single-call send path
        (:mod:`standbus.together`)."""
        bus = self.bus
        cached = self.__dict__.get("_bus_facts")
        if cached is None or cached[0] is not bus:
            channel = getattr(bus, "channel", None)
            channel = channel if isinstance(channel, (str, int)) else None
            cached = self._bus_facts = (bus, channel, together.raw_path(bus))
        return cached[1], cached[2]

    def _channel(self):
        """The bus's channel name for captured frames (:meth:`_of_bus`)."""
        return self._of_bus()[0]

    def send_frames(self, frames) -> float:
        """Raw frames ``(flags, arbitration_id, dlc, data)`` sent at one instant (a cycle's
        commands on this bus): one datagram where the bus takes a batch
        (:meth:`standbus.loopback.LoopbackBus.send_frames`), else one ``send`` each; captured
        as handed to the bus. Returns the send stamp."""
        bus = self.bus
        capture = self.capture
        channel = self._channel()
        with self.send_lock:
            if getattr(bus, "raw_frames", False):
                stamp = bus.send_frames(frames)
            else:
                stamp = time.time()
                for frame in frames:
                    bus.send(wire.message(stamp, frame, channel, False))
            if capture is not None:
                capture.on_frames(stamp, frames, False, channel)
        return stamp

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self.send_raw_message(can.Message(is_extended_id=can_id > 0x7FF, arbitration_id=can_id,
                                          data=data, is_remote_frame=remote))

    def send_raw_message(self, msg: can.Message) -> None:
        """A frame made by the caller (a remote frame with its DLC: node guarding), sent and
        captured as :meth:`send_message`'s."""
        msg.is_rx = False
        msg.channel = self._channel()
        capture = self.capture
        with self.send_lock:
            if capture is not None:  # captured as handed to the bus: before the answers to it
                msg.timestamp = time.time()
                capture.on_sent(msg)
            self.bus.send(msg)


def send_together(networks: "list[TappedNetwork]", can_id: int, data: bytes) -> None:
    """The same frame on every network, as close together as this host allows (a rig's SYNCs):
    with every network's send lock held, :func:`standbus.together.send_together` hands the
    frames to their buses with nothing else of this process in between; then each is captured,
    stamped as it was handed over (before any answer to it: the answers are received after
    this returns), raw (no :class:`can.Message`: a rig's 4 SYNCs cost ~28 µs a cycle with
    them). A bus that fails does not keep the frame from the others; the first failure is
    raised after all were tried."""
    extended = wire.FLAG_EXTENDED if can_id > 0x7FF else 0
    frames = [(net.cyclic_flags | extended, can_id, len(data), data) for net in networks]
    facts = [net._of_bus() for net in networks]
    stamps = [0.0] * len(networks)
    taken = []
    try:
        for net in networks:
            net.send_lock.acquire()
            taken.append(net.send_lock)
        together.send_frames_together([net.bus for net in networks], frames,
                                      [path for _, path in facts], stamps)
    finally:
        try:
            for net, frame, stamp, (channel, _) in zip(networks, frames, stamps, facts):
                if net.capture is not None and stamp:
                    net.capture.on_frames(stamp, (frame,), False, channel)
        finally:
            for lock in reversed(taken):
                lock.release()
