"""The wire check itself (tests/support/wire_check.py): tshark's CANopen dissector reads every
kind of frame, SDO transfers are followed through expedited and segmented transfers, aborts and
cut-off ones, faults of the protocol are named, and reading each distinct frame once gives what
reading every frame gives. Skipped, with the reason, where tshark is not installed."""
from __future__ import annotations

import time
import uuid
from pathlib import Path

import can
import canopen
import pytest

from tests.support.wire_check import (WireExpectation, check_captures, tshark_missing_reason,
                                      wire_problems)

pytestmark = pytest.mark.skipif(tshark_missing_reason() is not None, reason=str(tshark_missing_reason()))
EDS = Path(__file__).resolve().parents[1] / "dbc" / "servo_valve.eds"


def log(tmp_path, lines: list[str], name: str = "capture.log", channel: str = "can0") -> Path:
    path = tmp_path / name
    path.write_text("".join(f"({1_700_000_000 + i * 0.001:.6f}) {channel} {line}\n"
                            for i, line in enumerate(lines)))
    return path


def test_each_canopen_function_is_counted_as_the_dissector_classifies_it(tmp_path):
    f, = check_captures([log(tmp_path, [
        "000#8100", "000#0102",                    # NMT reset all, start node 2
        "701#00", "702#05", "701#7F",              # boot-up, heartbeats
        "080#", "080#01",                          # SYNC without and with its counter
        "081#0010010000000000", "081#0000000000000000",   # EMCY set, cleared
        "181#0F003303", "201#07000000", "281#", "4FF#0102030405060708",   # PDOs (one empty)
        "601#4018100100000000", "581#4318100134120000",   # an expedited upload
        "7E5#5A00000000000000", "7E4#5A00000000000000",   # LSS inquire vendor, its answer
        "701#R",                                   # a node-guarding request
        "20000080#0000000000000000",               # an error frame
        "1ABCDEF0#1122",                           # a 29-bit id
        "123##1AABBCCDDEEFF001122334455",          # CAN FD (function code 2 to the dissector)
    ])])
    assert dict(f.functions) == {"NMT": 2, "NMT error control": 3, "SYNC": 2, "EMCY": 2, "PDO": 4,
                                 "SDO": 2, "LSS": 2, "remote": 1, "error frame": 1, "29-bit id": 1,
                                 "TIME": 1}
    assert f.frames == 21 and f.malformed == 0 and f.expert_errors == 0
    assert dict(f.nmt_commands) == {"reset node": 1, "start": 1}
    assert dict(f.nmt_states) == {"boot-up": 1, "operational": 1, "pre-operational": 1}
    assert dict(f.emcy_codes) == {0x1000: 1, 0x0000: 1}
    assert [str(t) for t in f.sdo] == ["node 1 upload 0x1018:01 (expedited, frame 14): complete"]
    assert wire_problems([f]) == []


@pytest.fixture
def sdo_capture(tmp_path):
    """Real SDO transfers: python canopen's client against its LocalNode (the valve's EDS) on a
    virtual bus, captured by a third bus with python-can's logger (a candump log)."""
    channel = f"wire-{uuid.uuid4().hex[:8]}"
    path = tmp_path / "capture.log"
    server_net, client_net = canopen.Network(), canopen.Network()
    server_net.connect(interface="virtual", channel=channel)
    client_net.connect(interface="virtual", channel=channel)
    tap = can.Bus(interface="virtual", channel=channel)
    logger = can.Logger(str(path))
    notifier = can.Notifier(tap, [logger])
    server = canopen.LocalNode(1, str(EDS))
    server_net.add_node(server)
    client = client_net.add_node(1, str(EDS))
    client.sdo.RESPONSE_TIMEOUT = 1.0

    def done():
        time.sleep(0.2)
        notifier.stop()
        logger.stop()
        tap.shutdown()
        client_net.disconnect()
        server_net.disconnect()
        return path
    return client, done


def test_expedited_and_segmented_transfers_and_aborts_by_server_and_client_are_followed(sdo_capture):
    client, done = sdo_capture
    assert client.sdo.upload(0x1008, 0) == b"Servo-valve drive (CiA 408)"   # segmented upload
    client.sdo.download(0x1017, 0, b"\x64\x00")                             # expedited download
    client.sdo.download(0x1017, 0, b"\xc8\x00", force_segment=True)         # segmented download
    assert client.sdo.upload(0x1017, 0) == b"\xc8\x00"                      # expedited upload
    with pytest.raises(canopen.SdoAbortedError):
        client.sdo.upload(0x5FFF, 0)                                        # no such object
    silent = client.network.add_node(5, str(EDS))                           # no such node
    silent.sdo.RESPONSE_TIMEOUT = 0.1
    with pytest.raises(canopen.SdoCommunicationError):
        silent.sdo.upload(0x1018, 1)
    f, = check_captures([done()])
    assert [(t.direction, t.index, t.mode, t.outcome) for t in f.sdo] == [
        ("upload", 0x1008, "segmented", "complete"), ("download", 0x1017, "expedited", "complete"),
        ("download", 0x1017, "segmented", "complete"), ("upload", 0x1017, "expedited", "complete"),
        ("upload", 0x5FFF, "?", "aborted"), ("upload", 0x1018, "?", "aborted")]
    assert f.sdo[0].segments == 4 and f.sdo[2].segments == 1     # 27 bytes in 7-byte segments; 2 bytes
    assert (f.sdo[4].abort_code, f.sdo[4].aborted_by, f.sdo[4].abort_names) == (0x06020000, "server", None)
    # the client gives up after its timeout with an abort (0x05040000) that names 0000:00
    assert str(f.sdo[5]).endswith("aborted by the client, code 0x05040000 (the abort names 0x0000:00)")
    assert f.sdo_faults == [] and f.malformed == 0
    server, client_abort = wire_problems([f])
    assert "upload 0x5FFF:00" in server and "aborted by the server, code 0x06020000" in server
    assert wire_problems([f], WireExpectation(sdo_aborts=frozenset({0x06020000, 0x05040000}))) == []
    assert wire_problems([f], WireExpectation(sdo_aborts="any")) == []
    assert wire_problems([f], WireExpectation(sdo_aborts=frozenset({0x05040000}))) == [server]


def test_a_transfer_cut_off_and_a_broken_protocol_are_named(tmp_path):
    f, = check_captures([log(tmp_path, [
        "601#4008100000000000", "581#4108100012000000",    # segmented upload of 0x1008, 18 bytes
        "601#6000000000000000", "581#00536572766F2D76",    # segment, toggle 0
        "601#6000000000000000", "581#0061",                # toggle 0 again (should be 1); short answer
        "602#2B17100064000000",                            # a download node 2 never answers
        "581#6017100000000000",                            # an answer to nothing
        "603#2B17100064000000", "583#6018100000000000",    # the answer names another object
    ])])
    assert f.malformed == 1 and f.first_malformed == ["frame 6 id 0x581 DLC 2"]
    problems = wire_problems([f])
    text = "\n".join(problems)
    assert "1 malformed frames (frame 6 id 0x581 DLC 2)" in text
    assert "frame 5: node 1: toggle bit 0, expected 1" in text
    assert ("frame 8: node 1: an SDO download initiate response fits no open transfer (node 1 upload "
            "0x1008:00 (segmented, frame 1): open waits for its segment)") in text
    assert "frame 10: node 3: the answer names 0x1018:00, the request 0x1017:00" in text
    assert "node 2 download 0x1017:00 (expedited, frame 7): open (never finished)" in text
    assert "node 1 upload 0x1008:00 (segmented, frame 1): open (never finished)" in text
    allowed = wire_problems([f], WireExpectation(cut_off=True, malformed=True))
    assert not any("never finished" in p or "malformed" in p for p in allowed)
    assert any("toggle bit" in p for p in allowed)          # a fault of the protocol is never allowed


def test_frames_too_short_for_their_function_are_malformed_and_named(tmp_path):
    """What a flood of garbage puts on the bus: NMT, EMCY and SDO frames too short for what the
    dissector reads of them."""
    f, = check_captures([log(tmp_path, ["000#", "081#10", "601#40", "701#", "601#2017", "581#6018", "582#80"])])
    assert f.malformed == 6 and dict(f.functions) == {"NMT": 1, "EMCY": 1, "SDO": 4, "NMT error control": 1}
    assert dict(f.nmt_commands) == {"(none)": 1} and dict(f.nmt_states) == {"(none)": 1}
    assert f.as_dict()["emcy_codes"] == {"(none)": 1}
    assert wire_problems([f])[0].endswith("6 malformed frames (frame 1 id 0x0 DLC 0; frame 2 id 0x81 DLC 1; "
                                          "frame 3 id 0x601 DLC 1)")
    # an SDO request too short to name its object: the transfer is followed without one
    assert [str(t) for t in f.sdo] == ["node 1 upload ?:? (?, frame 3): open",
                                       "node 1 download ?:? (segmented, frame 5): open",
                                       "node 2 ? ?:? (?, frame 7): aborted by the server, code ?"]
    assert not any("malformed" in p for p in wire_problems([f], WireExpectation(malformed=True)))
    assert wire_problems([f], WireExpectation(garbage=True)) == []


def test_reading_each_distinct_frame_once_gives_what_reading_every_frame_gives(tmp_path):
    """The dissectors keep no state from frame to frame: the figures of a capture full of
    repeats are the same whether tshark reads every frame or each distinct one once."""
    from captures.synthetic import stand_frames, synthetic_run
    from captures.writers import write_candump
    stand = tmp_path / "capture-can0.log"
    write_candump(stand, stand_frames(synthetic_run(2000, seed=5)))
    odd = log(tmp_path, ["601#40181001", "581#4318100134120000", "000#0101", "701#05", "701#05",
                         "601#40181001", "081#1000010000000000", "181#0F003303"], "candump-x.log", "can1")
    every = check_captures([stand, odd], distinct=False)
    once = check_captures([stand, odd])
    assert [f.as_dict() for f in once] == [f.as_dict() for f in every]
    assert once[0].frames > 6000 and once[1].malformed == 2


def test_each_bus_of_a_capture_is_read_apart(tmp_path):
    """Node 1 of can0 and node 1 of can1 are different devices: a transfer on one bus is not
    answered by the other bus's frames."""
    path = tmp_path / "candump-rig.log"
    path.write_text("(1.000000) can0 601#4018100100000000\n"
                    "(1.000100) can1 601#4018100100000000\n"
                    "(1.000200) can1 581#4318100134120000\n"
                    "(1.000300) can0 581#4318100178560000\n")
    a, b = check_captures([path])
    assert (a.channel, b.channel) == ("can0", "can1")
    assert a.sdo_complete == 1 and b.sdo_complete == 1 and not a.sdo_faults and not b.sdo_faults


def test_the_marker_says_what_a_test_provokes():
    mark = pytest.mark.wire(sdo_aborts=[0x06020000], cut_off=True).mark
    assert WireExpectation.from_marker(mark) == WireExpectation(frozenset({0x06020000}), cut_off=True)
    assert WireExpectation.from_marker(None) == WireExpectation()
    flood = WireExpectation.from_marker(pytest.mark.wire(garbage=True, only="noisy/capture.log").mark)
    assert flood.of(Path("/tmp/t/noisy/capture.log")).garbage
    assert flood.of(Path("/tmp/t/quiet/capture.log")) == WireExpectation()
    with pytest.raises(TypeError, match="keywords only"):
        WireExpectation.from_marker(pytest.mark.wire("any").mark)
