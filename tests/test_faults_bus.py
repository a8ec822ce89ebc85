"""The bus-level safety tools: acceptance filter, fault injection on udp_loopback, garbage."""
from __future__ import annotations

import random
import struct
import time

import can
import pytest

from tests.support.bus import recv_frames
from standbus import BusSpecError, open_bus
from standbus.faults import (ALL_LENGTHS, FaultInjector, FaultSpec, FrameFilter, canopen_protected,
                             garbage_frame, parse_id_range)
from standbus.loopback import LoopbackBus, _open_socket
from standbus import wire


# -- acceptance filter ----------------------------------------------------------------------------
def test_frame_filter_passes_only_classic_frames_with_the_declared_length():
    got = []
    flt = FrameFilter(got.append, strict=True)
    flt.expect(0x182, 5)
    flt.expect(0x702, 1)
    flt.expect(0x282, None)
    ok = can.Message(arbitration_id=0x182, data=bytes(5), is_extended_id=False)
    frames = [
        ok,
        can.Message(arbitration_id=0x182, data=bytes(4), is_extended_id=False),          # wrong DLC
        can.Message(arbitration_id=0x182, data=bytes(5), is_extended_id=True),           # IDE set
        can.Message(arbitration_id=0x182, is_remote_frame=True, dlc=5, is_extended_id=False),
        can.Message(arbitration_id=0x182, data=bytes(5), is_fd=True, is_extended_id=False),
        can.Message(is_error_frame=True, is_extended_id=False),
        can.Message(arbitration_id=0x183, data=bytes(5), is_extended_id=False),          # no rule
        can.Message(arbitration_id=0x702, data=b"\x05", is_extended_id=False),
        can.Message(arbitration_id=0x702, data=b"\x05", dlc=2, is_extended_id=False, check=False),
        can.Message(arbitration_id=0x282, data=bytes(7), is_extended_id=False),          # any length
    ]
    for f in frames:
        flt.on_message_received(f)
    assert [(m.arbitration_id, len(m.data)) for m in got] == [(0x182, 5), (0x702, 1), (0x282, 7)]
    assert flt.counts() == {"not_classic": 4, "unexpected_id": 1, "wrong_dlc": 2, "errors": 0}
    assert flt.dropped == 7


def test_frame_filter_survives_a_failing_consumer():
    def boom(msg):
        raise RuntimeError("consumer bug")
    flt = FrameFilter(boom)
    flt.on_message_received(can.Message(arbitration_id=0x1, data=b"", is_extended_id=False))
    assert flt.errors == 1


# -- fault injection -------------------------------------------------------------------------------
@pytest.mark.parametrize("options, message", [
    ({"drop": 1.5}, "drop=1.5 must be a number from 0 to 1"),
    ({"drop": float("nan")}, "drop=nan"),
    ({"delay_ms": float("inf")}, "delay="),
    ({"delay_ms": -1}, "delay="),
    ({"drop": "lots"}, "drop='lots'"),
    ({"drop": 0.1, "fault_ids": "0x500-0x100"}, "low <= high"),
    ({"drop": 0.1, "fault_ids": "zz"}, "write an id or a range"),
    ({"drop": 0.1, "seed": 1.5}, "seed=1.5 must be an integer"),
])
def test_fault_options_are_checked(options, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace("+", r"\+")):
        FaultSpec.from_options(**options)


def test_fault_options_from_a_bus_spec_and_clear_errors(channel):
    bus = open_bus(f"udp_loopback:{channel},drop=0.25,delay_ms=3,fault_ids=0x080-0x4FF,seed=7")
    try:
        assert bus.faults.spec == FaultSpec(drop=0.25, delay_s=0.003, ids=(0x80, 0x4FF), seed=7)
    finally:
        bus.shutdown()
    plain = open_bus(f"udp_loopback:{channel}")
    assert plain.faults is None
    plain.shutdown()
    with pytest.raises(BusSpecError, match="fault injection: drop=2"):
        open_bus(f"udp_loopback:{channel},drop=2")
    assert parse_id_range("0x181") == (0x181, 0x181) and parse_id_range(None) is None


def test_losses_follow_one_seeded_stream_per_id():
    """With a seed, whether the n-th frame of an id is lost does not depend on other ids'
    traffic, and the loss rate is the one asked for."""
    a = FaultInjector(FaultSpec(drop=0.1, seed=3))
    b = FaultInjector(FaultSpec(drop=0.1, seed=3))
    pattern_a = [a.lose(0x182) for _ in range(20000)]
    pattern_b = []
    for _ in range(20000):
        b.lose(0x701)                     # interleaved traffic on another id
        pattern_b.append(b.lose(0x182))
    assert pattern_a == pattern_b
    assert sum(pattern_a) / len(pattern_a) == pytest.approx(0.1, abs=0.01)
    assert FaultInjector(FaultSpec(drop=0.1, seed=4)).lose(0x182) in (True, False)


def test_loopback_drops_the_requested_share_only_on_the_chosen_ids(channel):
    rx = LoopbackBus(channel, drop=0.3, fault_ids="0x180-0x1FF", seed=1)
    tx = LoopbackBus(channel)
    try:
        for i in range(1000):
            tx.send(can.Message(arbitration_id=0x182, data=struct.pack("<I", i), is_extended_id=False))
            tx.send(can.Message(arbitration_id=0x702, data=b"\x05", is_extended_id=False))
        got = recv_frames(rx, 2000, timeout=3.0)
    finally:
        rx.shutdown(); tx.shutdown()
    pdo = [struct.unpack("<I", m.data)[0] for m in got if m.arbitration_id == 0x182]
    hb = [m for m in got if m.arbitration_id == 0x702]
    assert len(hb) == 1000, "frames outside fault_ids are never lost"
    assert 0.25 < 1 - len(pdo) / 1000 < 0.35
    assert pdo == sorted(pdo), "the survivors keep their order"
    assert rx.faults.dropped == 1000 - len(pdo)


@pytest.mark.serial
def test_loopback_delays_frames_and_keeps_their_order(channel):
    rx = LoopbackBus(channel, delay_ms=40)
    tx = LoopbackBus(channel)
    try:
        sent = []
        for i in range(50):
            sent.append(time.monotonic())
            tx.send(can.Message(arbitration_id=0x181, data=bytes([i]), is_extended_id=False))
        got, arrived = [], []
        deadline = time.monotonic() + 5
        while len(got) < 50 and time.monotonic() < deadline:
            m = rx.recv(0.5)
            if m is not None:
                got.append(m.data[0]); arrived.append(time.monotonic())
        assert rx.recv(0) is None
    finally:
        rx.shutdown(); tx.shutdown()
    assert got == list(range(50))
    lags = [a - s for a, s in zip(arrived, sent)]
    assert min(lags) >= 0.039, "no frame arrives before its delay"
    assert sorted(lags)[len(lags) // 2] < 0.2


def test_loopback_counts_classic_frames_longer_than_8_bytes_as_malformed(channel):
    rx = LoopbackBus(channel)
    try:
        group, port = resolve = (rx.group, rx.port)
        raw = _open_socket(group, port)
        bad = wire.pack(can.Message(arbitration_id=0x182, data=bytes(12), is_fd=True), 9, time.time())
        bad = bad[:3] + bytes([bad[3] & ~wire.FLAG_FD]) + bad[4:]          # FD flag cleared
        raw.sendto(bad, resolve)
        raw.sendto(b"\x00garbage", resolve)
        raw.close()
        time.sleep(0.1)
        assert rx.recv(0.2) is None
        assert rx.malformed_datagrams == 2
    finally:
        rx.shutdown()


# -- garbage ----------------------------------------------------------------------------------------
def test_garbage_never_forms_a_valid_frame_of_the_protected_set():
    protected = canopen_protected((1, 2), {0x181: 4, 0x182: 5})
    rng = random.Random(5)
    kinds = {"error": 0, "remote": 0, "extended": 0, "fd": 0, "classic": 0, "on_stand_ids": 0}
    for _ in range(20000):
        m = garbage_frame(rng, protected)
        if m.is_error_frame:
            kinds["error"] += 1
        elif m.is_remote_frame:
            kinds["remote"] += 1
        elif m.is_extended_id:
            kinds["extended"] += 1
        elif m.is_fd:
            kinds["fd"] += 1
        else:
            kinds["classic"] += 1
            assert len(m.data) not in protected.get(m.arbitration_id, ()), m
            assert m.arbitration_id <= 0x7FF and len(m.data) <= 8
            kinds["on_stand_ids"] += m.arbitration_id in protected
    assert all(v > 500 for v in kinds.values()), kinds
    assert protected[0x201] == ALL_LENGTHS and protected[0x000] == {2} and protected[0x080] == {0, 1}
