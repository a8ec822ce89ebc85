"""Capture readers: candump .log and BLF read exactly what python-can reads, bad files stop
with the position named and everything before it decoded."""
from __future__ import annotations

import gzip

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from captures import CaptureDamaged, FrameChunk, open_capture
from captures.blf import BlfReader
from captures.candump import CandumpReader
from captures.frames import BRS, ERROR, ESI, EXTENDED, FD, REMOTE, TX
from captures.synthetic import stand_frames, synthetic_run
from captures.writers import FastBlfWriter, to_messages, write_blf, write_candump


def read_all(reader) -> FrameChunk:
    return FrameChunk.concat(list(reader))


def assert_same_as_python_can(chunk: FrameChunk, path) -> None:
    msgs = list(can.LogReader(str(path)))
    assert len(msgs) == len(chunk)
    assert np.array_equal(chunk.ts, [m.timestamp for m in msgs]), "timestamps bit for bit"
    for i, m in enumerate(msgs):
        fl = int(chunk.flags[i])
        assert bool(fl & ERROR) == m.is_error_frame, i
        if m.is_error_frame:
            continue
        assert int(chunk.can_id[i]) == m.arbitration_id, i
        assert bool(fl & EXTENDED) == m.is_extended_id, i
        assert bool(fl & REMOTE) == m.is_remote_frame, i
        assert bool(fl & FD) == m.is_fd, i
        assert bool(fl & TX) == (not m.is_rx), i
        assert bool(fl & BRS) == (m.is_fd and m.bitrate_switch), i
        assert bool(fl & ESI) == (m.is_fd and m.error_state_indicator), i
        if not m.is_remote_frame:
            assert chunk.payload(i) == bytes(m.data), i
        assert chunk.channels[chunk.channel[i]] == str(m.channel), i


@pytest.fixture(scope="module")
def stand_chunk() -> FrameChunk:
    return FrameChunk.concat(list(stand_frames(synthetic_run(3000, seed=4))))


# -- candump ----------------------------------------------------------------------------------

def test_candump_lines_as_can_utils_and_python_can_write_them(tmp_path):
    text = ("(1700000000.123456) vcan0 182#A0860100FF\n"
            "(1700000000.123457) vcan0 182#A0860100FF R\n"
            "(1700000000.123458) vcan0 201#07003303 T\n"
            "(1700000000.200000) vcan0 1ABCDEF0#1122\n"
            "(1700000000.300000) vcan0 123#R\n"
            "(1700000000.300001) vcan0 123#R4\n"
            "(1700000000.400000) vcan0 080#\n"
            "(1700000000.500000) vcan0 20000080#0000000000000000\n"
            "(1700000000.600000) vcan0 123##1AABBCCDDEEFF001122334455\n"
            "(1700000000.700000)  can1 701#05\n"          # candump pads names to the longest
            "\n"
            "(0.002000) can0 181#0F000000\r\n"             # python-can, relative time, CRLF
            "(0.003000) can0 124##2AABB\n")                 # CAN FD, ESI without BRS
    path = tmp_path / "mixed.log"
    path.write_text(text)
    chunk = read_all(CandumpReader(path))
    assert_same_as_python_can(chunk, path)
    assert chunk.ts[0] == 1700000000.123456 and chunk.can_id[0] == 0x182
    assert chunk.payload(0) == bytes.fromhex("A0860100FF") and chunk.dlc[0] == 5
    assert chunk.flags[2] & TX and not chunk.flags[1] & TX
    assert chunk.flags[3] & EXTENDED and chunk.can_id[3] == 0x1ABCDEF0
    assert chunk.flags[4] & REMOTE and chunk.dlc[5] == 4
    assert chunk.dlc[6] == 0
    assert chunk.flags[7] & ERROR
    assert chunk.flags[8] & FD and chunk.flags[8] & BRS and not chunk.flags[8] & ESI and chunk.dlc[8] == 12
    assert chunk.flags[11] & ESI and not chunk.flags[11] & BRS
    assert sorted(set(chunk.channels)) == ["can0", "can1", "vcan0"]


def test_candump_reader_equals_python_can_on_stand_traffic_and_any_chunk_size(tmp_path, stand_chunk):
    path = tmp_path / "stand.log"
    write_candump(path, [stand_chunk])
    whole = read_all(CandumpReader(path))
    assert_same_as_python_can(whole, path)
    pieces = read_all(CandumpReader(path, chunk_bytes=1500))   # lines split across blocks
    for name in ("ts", "can_id", "flags", "dlc", "data", "channel"):
        assert np.array_equal(getattr(whole, name), getattr(pieces, name)), name
    gz = tmp_path / "stand.log.gz"
    gz.write_bytes(gzip.compress(path.read_bytes()))
    assert np.array_equal(read_all(open_capture(gz)).data, whole.data)


frames = st.lists(st.tuples(
    st.floats(0, 2e9, allow_nan=False), st.booleans(), st.integers(0, 0x1FFFFFFF),
    st.binary(min_size=0, max_size=8), st.booleans(), st.booleans()), min_size=1, max_size=40)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames)
def test_candump_reader_matches_python_can_on_random_frames(tmp_path_factory, items):
    path = tmp_path_factory.mktemp("fuzz") / "f.log"
    w = can.CanutilsLogWriter(str(path))
    for ts, ext, ident, data, remote, rx in items:
        w.on_message_received(can.Message(
            timestamp=ts, arbitration_id=ident if ext else ident & 0x7FF, is_extended_id=ext,
            is_remote_frame=remote, data=None if remote else data, dlc=len(data), is_rx=rx, channel="can0"))
    w.stop()
    assert_same_as_python_can(read_all(CandumpReader(path)), path)


def test_truncated_candump_names_the_line_and_keeps_everything_before(tmp_path, stand_chunk):
    path = tmp_path / "cut.log"
    write_candump(path, [stand_chunk])
    data = path.read_bytes()
    cut = data[: len(data) // 2 + 7]                 # in the middle of a line
    path.write_bytes(cut)
    reader = CandumpReader(path, chunk_bytes=4096)
    chunk = read_all(reader)
    complete_lines = cut.count(b"\n")
    assert len(chunk) == complete_lines
    d = reader.stats.damage
    assert d is not None and d.line == complete_lines + 1 and d.byte == cut.rfind(b"\n") + 1
    assert "truncated" in d.reason and f"line {complete_lines + 1}" in d.position


def test_corrupted_candump_line_stops_there_or_is_skipped(tmp_path, stand_chunk):
    path = tmp_path / "bad.log"
    write_candump(path, [stand_chunk])
    lines = path.read_bytes().split(b"\n")
    bad_at = 5000
    lines[bad_at] = lines[bad_at][:12] + b"\x00\xff\x13garbage" + lines[bad_at][20:]
    path.write_bytes(b"\n".join(lines))
    reader = CandumpReader(path, chunk_bytes=8192)
    chunk = read_all(reader)
    assert len(chunk) == bad_at
    assert reader.stats.damage.line == bad_at + 1
    assert reader.stats.damage.byte == sum(len(x) + 1 for x in lines[:bad_at])
    with pytest.raises(CaptureDamaged, match=f"line {bad_at + 1}"):
        from captures import iter_frames
        list(iter_frames(path))
    skipping = CandumpReader(path, on_damage="skip")
    chunk = read_all(skipping)
    assert len(chunk) == len(stand_chunk) - 1
    assert skipping.stats.damaged == 1 and skipping.stats.first_damage.line == bad_at + 1
    assert skipping.stats.damage is None


def test_binary_garbage_is_not_a_candump_log(tmp_path):
    path = tmp_path / "noise.log"
    path.write_bytes(bytes(range(256)) * 1000)
    reader = CandumpReader(path)
    assert len(read_all(reader)) == 0
    assert reader.stats.damage is not None and reader.stats.damage.line == 1


# -- BLF --------------------------------------------------------------------------------------

def test_blf_reader_equals_python_can_for_every_frame_kind(tmp_path):
    msgs = [
        can.Message(timestamp=1_700_000_000.5, arbitration_id=0x182, data=b"\xa0\x86\x01\x00\xff", is_rx=True, channel=0),
        can.Message(timestamp=1_700_000_000.6, arbitration_id=0x1ABCDEF0, is_extended_id=True, data=b"\x11\x22", channel=1),
        can.Message(timestamp=1_700_000_000.7, arbitration_id=0x123, is_remote_frame=True, dlc=3, channel=0),
        can.Message(timestamp=1_700_000_000.8, arbitration_id=0x201, data=b"\x07\x00\x33\x03", is_rx=False, channel=0),
        can.Message(timestamp=1_700_000_000.9, arbitration_id=0x321, is_fd=True, data=bytes(range(24)), channel=0),
        can.Message(timestamp=1_700_000_000.95, arbitration_id=0x322, is_fd=True, bitrate_switch=True,
                    error_state_indicator=True, data=bytes(range(12)), channel=1),
        can.Message(timestamp=1_700_000_001.0, is_error_frame=True, channel=0),
    ]
    path = tmp_path / "kinds.blf"
    w = can.BLFWriter(str(path))
    for m in msgs * 3000:          # > 128 KiB: objects straddle log containers
        w.on_message_received(m)
    w.stop()
    chunk = read_all(BlfReader(path, chunk_bytes=50_000))
    assert_same_as_python_can(chunk, path)


def test_fast_blf_writer_writes_what_python_can_reads(tmp_path, stand_chunk):
    path = tmp_path / "stand.blf"
    write_blf(path, [stand_chunk])
    chunk = read_all(BlfReader(path))
    assert_same_as_python_can(chunk, path)
    assert np.array_equal(chunk.data, stand_chunk.data) and np.array_equal(chunk.can_id, stand_chunk.can_id)


def test_truncated_and_corrupted_blf_name_the_byte_and_keep_what_came_before(tmp_path, stand_chunk):
    path = tmp_path / "stand.blf"
    with FastBlfWriter(path) as w:
        w.write(stand_chunk)
    data = path.read_bytes()
    full = read_all(BlfReader(path))
    cut = tmp_path / "cut.blf"
    cut.write_bytes(data[: len(data) * 2 // 3])
    reader = BlfReader(cut)
    part = read_all(reader)
    assert 0 < len(part) < len(full)
    assert np.array_equal(part.data, full.data[: len(part)]) and np.array_equal(part.ts, full.ts[: len(part)])
    assert reader.stats.damage is not None and "truncated" in reader.stats.damage.reason
    assert reader.stats.damage.byte is not None and reader.stats.damage.byte < len(data) * 2 // 3
    # flip bytes inside the third container's compressed data
    offsets = [i for i in range(144, len(data) - 4) if data[i:i + 4] == b"LOBJ"]
    third = offsets[2]
    bad = bytearray(data)
    bad[third + 40:third + 60] = b"\xff" * 20
    broken = tmp_path / "broken.blf"
    broken.write_bytes(bytes(bad))
    reader = BlfReader(broken)
    part = read_all(reader)
    assert reader.stats.damage is not None and reader.stats.damage.byte == third
    assert np.array_equal(part.data, full.data[: len(part)]) and len(part) > 0


def _one_gap(part: FrameChunk, full: FrameChunk) -> tuple[int, int]:
    """``part`` is ``full`` with one contiguous run of frames missing: its [a, b)."""
    a = 0
    while a < len(part) and part.ts[a] == full.ts[a] and np.array_equal(part.data[a], full.data[a]):
        a += 1
    b = len(full) - (len(part) - a)
    assert np.array_equal(part.ts[a:], full.ts[b:]) and np.array_equal(part.data[a:], full.data[b:])
    assert np.array_equal(part.can_id[a:], full.can_id[b:])
    return a, b


def _containers(data: bytes) -> list[int]:
    """File offsets of the log containers of a BLF file we wrote (no other outer objects)."""
    out, pos = [], 144
    while pos < len(data):
        out.append(pos)
        size = int.from_bytes(data[pos + 8:pos + 12], "little")
        pos += size + size % 4
    return out


@pytest.mark.parametrize("where", ["inside the compressed data", "on the outer header"])
def test_skip_mode_reads_past_a_damaged_blf_container(tmp_path, stand_chunk, where):
    """``on_damage="skip"``: frames after the damage are read too; only the damaged container's
    frames (and one that straddled into it) are lost, and the damage is counted and named."""
    path = tmp_path / "stand.blf"
    write_blf(path, [stand_chunk])
    data = path.read_bytes()
    full = read_all(BlfReader(path))
    boxes = _containers(data)
    assert len(boxes) >= 5
    third = boxes[2]
    bad = bytearray(data)
    if where == "inside the compressed data":
        bad[third + 40:third + 60] = b"\xff" * 20
    else:
        bad[third:third + 16] = b"\x00JUNK\x00" + b"\xee" * 9
    broken = tmp_path / "broken.blf"
    broken.write_bytes(bytes(bad))
    stopping = BlfReader(broken)
    assert len(read_all(stopping)) < len(full) // 2 and stopping.stats.damage.byte == third
    reader = BlfReader(broken, on_damage="skip", chunk_bytes=50_000)
    part = read_all(reader)
    a, b = _one_gap(part, full)
    per_container = len(full) / len(boxes)
    assert 0 < b - a <= per_container * 1.2 + 2, (a, b, per_container)
    assert a > per_container and len(part) - a > per_container, "frames on both sides of it"
    assert reader.stats.damage is None and reader.stats.damaged >= 1
    assert reader.stats.first_damage.byte == third
    assert reader.stats.frames == len(part)


def test_skip_mode_passes_a_damaged_object_inside_a_container(tmp_path, stand_chunk):
    """A container that inflates but holds a damaged object: skip passes that object alone."""
    import zlib
    from can.io.blf import LOG_CONTAINER_STRUCT, ZLIB_DEFLATE
    path = tmp_path / "stand.blf"
    write_blf(path, [stand_chunk])
    data = path.read_bytes()
    full = read_all(BlfReader(path))
    second = _containers(data)[1]
    size = int.from_bytes(data[second + 8:second + 12], "little")
    head = second + 16 + LOG_CONTAINER_STRUCT.size
    inner = bytearray(zlib.decompress(data[head:second + size]))
    k = inner.find(b"LOBJ", 1000)
    inner[k:k + 4] = b"XXXX"                       # one object's signature destroyed
    payload = zlib.compress(bytes(inner))
    body = LOG_CONTAINER_STRUCT.pack(ZLIB_DEFLATE, len(inner)) + payload
    new_size = 16 + len(body)
    obj = b"LOBJ" + (16).to_bytes(2, "little") + (1).to_bytes(2, "little") \
        + new_size.to_bytes(4, "little") + (10).to_bytes(4, "little") + body + b"\x00" * (new_size % 4)
    broken = tmp_path / "inner.blf"
    broken.write_bytes(data[:second] + obj + data[second + size + size % 4:])
    reader = BlfReader(broken, on_damage="skip")
    part = read_all(reader)
    a, b = _one_gap(part, full)
    assert b - a == 1, "exactly the damaged object is lost"
    assert reader.stats.damaged == 1 and "inside the log container" in reader.stats.first_damage.reason
    stopping = BlfReader(broken)
    assert len(read_all(stopping)) == a and stopping.stats.damage is not None


def test_other_formats_go_through_python_can(tmp_path, stand_chunk):
    small = stand_chunk.take(slice(0, 500))
    path = tmp_path / "small.asc"
    w = can.ASCWriter(str(path))
    for m in to_messages(small):
        w.on_message_received(m)
    w.stop()
    chunk = read_all(open_capture(path))
    assert len(chunk) == 500 and np.array_equal(chunk.can_id, small.can_id)
    assert np.array_equal(chunk.data, small.data)


def test_mf4_captures_read_and_decode_like_candump(tmp_path, stand_chunk):
    """ASAM MDF 4 (python-can's MF4Writer/Reader, asammdf): the same frames, and the same
    stand signals after decoding as from the candump file of the same traffic."""
    pytest.importorskip("asammdf", reason="install hydrostand[mf4] to read .mf4 captures")
    from analysis import load_capture
    part = stand_chunk.take(slice(0, 3000))
    mf4, log = tmp_path / "stand.mf4", tmp_path / "stand.log"
    w = can.Logger(str(mf4))
    for m in to_messages(part):
        w.on_message_received(m)
    w.stop()
    write_candump(log, [part])
    chunk = read_all(open_capture(mf4))
    assert len(chunk) == len(part) and np.array_equal(chunk.can_id, part.can_id)
    assert np.array_equal(chunk.data, part.data)
    a, b = load_capture(mf4), load_capture(log)
    assert len(a) > 100 and np.array_equal(a.u, b.u) and np.array_equal(a.y, b.y)


def test_unknown_suffix_and_missing_files_are_clear_errors(tmp_path):
    from captures import CaptureError
    (tmp_path / "x.pcap").write_bytes(b"\xd4\xc3\xb2\xa1")
    with pytest.raises(CaptureError, match="unknown capture format"):
        open_capture(tmp_path / "x.pcap")
    with pytest.raises(CaptureError, match="does not exist"):
        open_capture(tmp_path / "x.log")


def test_an_absurd_outer_object_size_is_damage_not_a_gigabyte_read(tmp_path, stand_chunk):
    path = tmp_path / "stand.blf"
    write_blf(path, [stand_chunk])
    data = bytearray(path.read_bytes())
    full = read_all(BlfReader(path))
    second = _containers(bytes(data))[1]
    data[second + 8:second + 12] = (0xFFFFFFF0).to_bytes(4, "little")
    broken = tmp_path / "huge.blf"
    broken.write_bytes(bytes(data))
    stopping = BlfReader(broken)
    part = read_all(stopping)
    assert stopping.stats.damage.byte == second and "size" in stopping.stats.damage.reason
    assert 0 < len(part) < len(full)
    skipping = BlfReader(broken, on_damage="skip")
    a, b = _one_gap(read_all(skipping), full)
    assert a == len(part) or a == len(part) - 1
    assert b - a <= len(full) / len(_containers(path.read_bytes())) * 1.2 + 2
