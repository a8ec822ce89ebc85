"""The bus capture's lines are written by its own thread and, in lockstep, by the control loop
between its polls (``BusCapture.write_one``): whoever writes, every frame is in the file once,
in the order it was queued, exactly as python-can's candump writer writes it."""
from __future__ import annotations


import can

from gateway.capture import BusCapture, read_capture


def test_frames_written_by_the_loop_between_polls_and_by_the_capture_thread_keep_their_order(tmp_path):
    path = tmp_path / "capture.log"
    capture = BusCapture(path, flush_s=0.004, batch_s=0.001)   # its thread drains every ms
    sent = []
    by_loop = 0
    for k in range(20_000):
        frames = [(0, 0x181 + (k % 7), 8, k.to_bytes(8, "little"))]
        capture.on_frames(1_000.0 + k * 1e-4, frames, bool(k % 2), "can0")
        sent.append((k, 0x181 + (k % 7)))
        if k % 3 == 0:
            by_loop += capture.write_one()
    capture.stop()
    got = [(int.from_bytes(m.data, "little"), m.arbitration_id) for m in read_capture(path)]
    assert got == sent
    assert capture.frames == len(sent) and capture.write_errors == 0
    assert by_loop > 1000            # both wrote: the loop a share, the thread the rest
    assert by_loop < len(sent)


def test_the_lines_are_python_cans_candump_lines(tmp_path):
    """The same frames through python-can's own CanutilsLogWriter give the same file."""
    ours, theirs = tmp_path / "ours.log", tmp_path / "theirs.log"
    capture = BusCapture(ours)
    writer = can.CanutilsLogWriter(str(theirs), channel="can0")
    for k in range(50):
        stamp = 1_700_000_000.0 + k * 0.002
        frames = [(0, 0x80, 1, bytes([k % 240 + 1])), (0, 0x201, 4, bytes([k, 0, 1, 2]))]
        capture.on_frames(stamp, frames, k % 2 == 0, "can0")
        if k % 4 == 0:
            capture.write_one()
        for _, arb, dlc, data in frames:
            writer.on_message_received(can.Message(timestamp=stamp, arbitration_id=arb, dlc=dlc,
                                                   data=data, is_extended_id=False,
                                                   is_rx=k % 2 == 0, channel="can0"))
    capture.stop()
    writer.stop()
    assert ours.read_text() == theirs.read_text()
