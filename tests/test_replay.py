"""Replay: a capture back onto a bus with its timing (scaled, or as fast as possible), and a
captured run replayed as the plant so the gateway reproduces the recorded force sequence."""
from __future__ import annotations

import subprocess
import sys
import threading

import numpy as np
import pytest

from captures import FrameChunk, decode_capture, iter_frames
from captures.frames import ERROR, EXTENDED, REMOTE
from captures.trace import force_trace
from plant_emulator.replayed import ReplayProcess
from captures.replay import Replayer
from captures.synthetic import stand_frames, synthetic_run
from captures.writers import write_candump
from gateway import Gateway, GatewayConfig, load_run
from gateway.experiments import Meander
from standbus import open_bus
from tests.support.bus import recv_frames
from tests.support.stand import plant


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.now += s


class RecordingBus:
    def __init__(self, clock) -> None:
        self.clock = clock
        self.sent = []

    def send(self, msg, timeout=None) -> None:
        self.sent.append((self.clock(), msg))


def chunk_of(ts, ids, flags=None) -> FrameChunk:
    n = len(ts)
    return FrameChunk(np.asarray(ts, float), np.asarray(ids, np.uint32),
                      np.zeros(n, np.uint8) if flags is None else np.asarray(flags, np.uint8),
                      np.full(n, 2, np.uint8), np.tile(np.arange(8, dtype=np.uint8), (n, 1)),
                      np.zeros(n, np.int16), ["can0"])


def test_frames_go_out_on_the_capture_schedule_scaled_with_gaps_shortened():
    clock = FakeClock()
    bus = RecordingBus(clock)
    rp = Replayer(bus, speed=2.0, max_gap_s=0.5, clock=clock, sleep=clock.sleep, spin_s=0.0)
    ts = [10.0, 10.001, 10.003, 10.0025, 12.0, 12.002]
    stats = rp.play([chunk_of(ts[:3], [1, 2, 3]), chunk_of(ts[3:], [4, 5, 6], [0, ERROR, 0])])
    sent = [(t - 100.0, m.arbitration_id) for t, m in bus.sent]
    expected = [(0.0, 1), (0.0005, 2), (0.0015, 3), (0.0015, 4), (0.2525, 6)]   # (0.003 + 0.5 + 0.002) / 2
    assert [i for _, i in sent] == [i for _, i in expected], "error frames are not sent"
    assert np.allclose([t for t, _ in sent], [t for t, _ in expected], rtol=0, atol=1e-9)
    assert stats.backwards == 1 and stats.gaps_shortened == 1 and stats.skipped_error_frames == 1
    assert stats.capture_span_s == pytest.approx(0.505)
    assert bus.sent[0][1].data == bytes([0, 1])


def test_asap_ignores_the_timing_and_ids_filter():
    clock = FakeClock()
    bus = RecordingBus(clock)
    rp = Replayer(bus, speed=None, ids={0x182}, clock=clock, sleep=clock.sleep)
    rp.play([chunk_of([0.0, 5.0, 10.0], [0x182, 0x181, 0x182])])
    assert [m.arbitration_id for _, m in bus.sent] == [0x182, 0x182]
    assert clock.now == 100.0, "never waited"


@pytest.fixture
def small_capture(tmp_path):
    run = synthetic_run(600, seed=2)
    chunk = FrameChunk.concat(list(stand_frames(run)))
    # an extended id and a remote frame too
    extra = chunk_of([chunk.ts[-1] + 0.001, chunk.ts[-1] + 0.002], [0x18DAF110, 0x123], [EXTENDED, REMOTE])
    chunk = FrameChunk.concat([chunk, extra])
    path = tmp_path / "small.log"
    write_candump(path, [chunk])
    return path, chunk


def _receive(spec: str, n: int, timeout_s: float = 20.0):
    bus = open_bus(spec)
    out = []
    ready = threading.Event()

    def pump():
        ready.set()
        out.extend(recv_frames(bus, n, timeout_s))
        bus.shutdown()

    th = threading.Thread(target=pump, daemon=True)
    th.start()
    ready.wait()
    return out, th


def assert_received(received, chunk: FrameChunk) -> None:
    assert len(received) == len(chunk)
    for i, m in enumerate(received):
        assert m.arbitration_id == chunk.can_id[i]
        assert m.is_extended_id == bool(chunk.flags[i] & EXTENDED)
        assert m.is_remote_frame == bool(chunk.flags[i] & REMOTE)
        if not m.is_remote_frame:
            assert bytes(m.data) == chunk.payload(i)


@pytest.mark.parametrize("interface", ["udp_loopback", "virtual"])
def test_replay_onto_a_bus_delivers_every_frame_in_order(small_capture, channel, interface):
    path, chunk = small_capture
    spec = f"{interface}:{channel}"
    received, th = _receive(spec, len(chunk))
    bus = open_bus(spec)
    try:
        stats = Replayer(bus, speed=None).play(iter_frames(path))
    finally:
        bus.shutdown()
    th.join(20)
    assert stats.sent == len(chunk) and stats.send_errors == 0
    assert_received(received, chunk)


def test_stand_replay_command_puts_the_capture_on_the_bus(small_capture, bus_spec):
    path, chunk = small_capture
    received, th = _receive(bus_spec, len(chunk))
    res = subprocess.run([sys.executable, "-m", "stand", "replay", str(path), "--bus", bus_spec, "--speed", "50"],
                         capture_output=True, text=True, timeout=60)
    th.join(20)
    assert res.returncode == 0, res.stderr
    assert f"replayed {len(chunk):,} of {len(chunk):,} frames" in res.stdout
    assert_received(received, chunk)


def test_force_trace_holds_the_answer_to_every_sync(tmp_path):
    run = synthetic_run(500, seed=9)
    write_candump(tmp_path / "c.log", stand_frames(run))
    trace = force_trace(tmp_path / "c.log")
    assert np.array_equal(trace.counts, run.y_counts), "the run's last SYNC is answered too"
    assert trace.period_s == 0.002 and len(trace) == 501


@pytest.mark.e2e
@pytest.mark.slow
def test_replayed_plant_gives_the_gateway_the_recorded_force(bus_spec, channel, start_emulator, tmp_path):
    """Record on the (emulated) bench, then run the gateway against the recording: the new run
    reads the recorded force sequence, cycle for cycle — also after a change of the experiment."""
    emu = start_emulator(plant({"g": 120.0, "tau": 0.05, "delta": 8.0}), lockstep=True, seed=7)
    with Gateway(GatewayConfig(bus=bus_spec, lockstep=True)) as gw:
        bench = gw.run(Meander(amplitude_pct=5, period_s=1, cycles=2), tmp_path / "bench", progress=False)
    emu.stop()
    recorded = load_run(bench.path)
    replay_bus = f"udp_loopback:{channel}-replay"
    with ReplayProcess(replay_bus, bench.path / "capture.log") as proc:
        with Gateway(GatewayConfig(bus=replay_bus, lockstep=True)) as gw:
            same = gw.run(Meander(amplitude_pct=5, period_s=1, cycles=2), tmp_path / "same", progress=False)
            changed = gw.run(Meander(amplitude_pct=8, period_s=0.5, cycles=3), tmp_path / "changed", progress=False)
    assert "replaying" in proc.output[0]
    a = load_run(same.path)
    assert same.status == "complete" and len(a) == len(recorded)
    assert np.array_equal(a.y_counts, recorded.y_counts) and np.array_equal(a.y, recorded.y)
    assert np.array_equal(a.u, recorded.u), "same gateway, same force: same commands"
    b = load_run(changed.path)
    n = min(len(b), len(recorded))
    assert np.array_equal(b.y_counts[:n], recorded.y_counts[:n]), "the sequence restarts with each run"
    assert not np.array_equal(b.u[:n], recorded.u[:n])
    # the replayed run's own capture decodes to the recorded force as well
    assert np.array_equal(decode_capture(same.path / "capture.log").signals[0]["y_counts"], recorded.y_counts)
