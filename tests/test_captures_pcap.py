"""Captures as pcaps of SocketCAN frames (captures/pcap.py, ``stand pcap``): the bytes are the
frames Linux hands a CAN socket (linux/can.h), every capture format gives the same pcap, and
tshark — a reader we did not write — reads each frame kind back as it was."""
from __future__ import annotations

import struct
import subprocess

import can
import numpy as np
import pytest

from captures import CaptureError, FrameChunk, open_capture
from captures.pcap import LINKTYPE_CAN_SOCKETCAN, capture_to_pcap
from captures.synthetic import stand_frames, synthetic_run
from captures.writers import to_messages, write_candump
from stand.cli import main as stand
from tests.support.wire_check import tshark_missing_reason, tshark_path

#: every kind of frame a candump log holds: (line, can_id word, len, FD flags, data)
KINDS = [
    ("182#A0860100FF", 0x182, 5, 0, "A0860100FF"),
    ("201#07003303 T", 0x201, 4, 0, "07003303"),
    ("080#", 0x080, 0, 0, ""),
    ("1ABCDEF0#1122", 0x80000000 | 0x1ABCDEF0, 2, 0, "1122"),
    ("701#R", 0x40000000 | 0x701, 0, 0, ""),
    ("123#R4", 0x40000000 | 0x123, 4, 0, ""),
    ("20000080#0000000000000000", 0x20000080, 8, 0, "0000000000000000"),
    ("123##1AABBCCDDEEFF001122334455", 0x123, 12, 0x04 | 0x01, "AABBCCDDEEFF001122334455"),
    ("1FFFFFFF##3" + "5A" * 64, 0x80000000 | 0x1FFFFFFF, 64, 0x04 | 0x01 | 0x02, "5A" * 64),
    ("124##0", 0x124, 0, 0x04, ""),
    ("581#4F00210001000000", 0x581, 8, 0, "4F00210001000000"),
]


def kinds_log(tmp_path, channel: str = "can0"):
    path = tmp_path / "kinds.log"
    path.write_text("".join(f"({1_700_000_000 + i * 0.001:.6f}) {channel} {line}\n"
                            for i, (line, *_) in enumerate(KINDS)))
    return path


def pcap_frames(path) -> tuple[tuple, list[tuple]]:
    """The file header and every record (sec, usec, captured bytes) of a pcap, read by hand."""
    raw = path.read_bytes()
    header = struct.unpack("<IHHiIII", raw[:24])
    out, pos = [], 24
    while pos < len(raw):
        sec, usec, incl, orig = struct.unpack("<IIII", raw[pos:pos + 16])
        assert incl == orig
        out.append((sec, usec, raw[pos + 16:pos + 16 + incl]))
        pos += 16 + incl
    assert pos == len(raw)
    return header, out


def test_each_frame_is_the_socketcan_frame_linux_hands_a_socket(tmp_path):
    result = capture_to_pcap(kinds_log(tmp_path), tmp_path / "kinds.pcap")
    assert (result.frames, result.fd_frames, result.remote_frames, result.error_frames) == (11, 3, 2, 1)
    header, records = pcap_frames(tmp_path / "kinds.pcap")
    assert header == (0xA1B2C3D4, 2, 4, 0, 0, 65535, LINKTYPE_CAN_SOCKETCAN)
    for i, ((line, word, length, fd_flags, data), (sec, usec, frame)) in enumerate(zip(KINDS, records)):
        assert (sec, usec) == (1_700_000_000, i * 1000), line
        # struct can_frame (CAN_MTU 16) / struct canfd_frame (CANFD_MTU 72), the id big-endian
        assert len(frame) == (72 if fd_flags else 16), line
        assert struct.unpack(">I", frame[:4])[0] == word, line
        assert (frame[4], frame[5], frame[6], frame[7]) == (length, fd_flags, 0, 0), line
        payload = bytes.fromhex(data)
        assert frame[8:8 + len(payload)] == payload and not any(frame[8 + len(payload):]), line


@pytest.mark.skipif(tshark_path() is None, reason=str(tshark_missing_reason()))
def test_tshark_reads_every_kind_back_as_it_was(tmp_path):
    capture_to_pcap(kinds_log(tmp_path), tmp_path / "kinds.pcap")
    fields = ["can.id", "can.len", "can.flags.xtd", "can.flags.rtr", "can.flags.err",
              "canfd.flags.brs", "canfd.flags.esi", "data.data"]
    res = subprocess.run([tshark_path(), "-n", "-r", str(tmp_path / "kinds.pcap"), "-T", "fields",
                          *[a for f in fields for a in ("-e", f)]], capture_output=True, text=True, check=True)
    rows = [dict(zip(fields, line.split("\t"))) for line in res.stdout.splitlines()]
    assert len(rows) == len(KINDS)
    flag = lambda text: text in ("1", "True")            # noqa: E731 (tshark 4.0 prints 1, 4.2 True)
    for (line, word, length, fd_flags, data), row in zip(KINDS, rows):
        fd = bool(fd_flags)
        assert (row["canfd.flags.brs"] != "") == fd, line         # read as CAN FD (its flags shown)
        if word & 0x20000000:
            assert flag(row["can.flags.err"]), line
            continue
        assert int(row["can.id"]) == word & 0x1FFFFFFF and int(row["can.len"]) == length, line
        assert flag(row["can.flags.xtd"]) == bool(word & 0x80000000), line
        if fd:
            assert (flag(row["canfd.flags.brs"]), flag(row["canfd.flags.esi"])) == (bool(fd_flags & 1),
                                                                                   bool(fd_flags & 2)), line
        else:
            assert flag(row["can.flags.rtr"]) == bool(word & 0x40000000), line
        remote = word & 0x40000000 and not fd        # its DLC names bytes it does not carry: zeros
        assert row["data.data"].replace(":", "").upper() == ("00" * length if remote else data), line


def test_every_capture_format_gives_the_same_pcap(tmp_path):
    """The stand's traffic written as candump, BLF, ASC, TRC and MF4 (python-can's writers):
    the same SocketCAN frames in the pcap, at the same times (to the µs each format keeps)."""
    chunk = FrameChunk.concat(list(stand_frames(synthetic_run(300, seed=2))))
    write_candump(tmp_path / "stand.log", [chunk])
    reference = pcap_frames(capture_to_pcap(tmp_path / "stand.log", tmp_path / "log.pcap").path)[1]
    assert len(reference) == len(chunk)
    suffixes = [".blf", ".asc", ".trc"]
    try:
        import asammdf  # noqa: F401
        suffixes.append(".mf4")
    except ImportError:
        pass
    for suffix in suffixes:
        path = tmp_path / f"stand{suffix}"
        with can.Logger(str(path)) as writer:
            for m in to_messages(chunk):
                writer.on_message_received(m)
        records = pcap_frames(capture_to_pcap(path, tmp_path / f"{suffix[1:]}.pcap").path)[1]
        assert [r[2] for r in records] == [r[2] for r in reference], suffix
        t = np.array([s + u / 1e6 for s, u, _ in records])
        t_ref = np.array([s + u / 1e6 for s, u, _ in reference])
        offset = t[0] - t_ref[0]        # ASC and TRC keep times from the file's start
        assert np.abs(t - t_ref - offset).max() < 2e-6, suffix


def test_a_capture_of_several_buses_is_written_one_channel_at_a_time(tmp_path):
    a, b = kinds_log(tmp_path, "can0").read_text(), kinds_log(tmp_path, "can1").read_text()
    both = tmp_path / "both.log"
    both.write_text(a + b)
    with pytest.raises(CaptureError, match=r"several bus channels \(can0, can1\).*--channel"):
        capture_to_pcap(both, tmp_path / "both.pcap")
    assert not (tmp_path / "both.pcap").exists() and not list(tmp_path.glob(".both.pcap*"))
    result = capture_to_pcap(both, tmp_path / "both.pcap", channel="can1")
    assert result.frames == len(KINDS) and result.other_channels == {"can0": len(KINDS)}
    with pytest.raises(CaptureError, match="no frames of channel can9; its channels: can0, can1"):
        capture_to_pcap(both, tmp_path / "none.pcap", channel="can9")


def test_a_damaged_capture_is_written_up_to_the_damage_and_says_where(tmp_path, capsys):
    log = kinds_log(tmp_path)
    log.write_text(log.read_text() + "(1700000001.000000) can0 181#0F00\n(1700000001.1")
    assert stand(["pcap", str(log)]) == 1
    out, err = capsys.readouterr()
    assert "12 frames" in out and "kinds.log: line 13" in err and "everything before it" in err
    assert len(pcap_frames(tmp_path / "kinds.pcap")[1]) == 12
    assert len(list(open_capture(log))[0]) == 12


def test_stand_pcap_takes_a_run_directory_and_says_how_to_open_it(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text('{"format": "hydrostand-run/1"}')
    write_candump(run / "capture.log", stand_frames(synthetic_run(50, seed=1)))
    assert stand(["pcap", str(run)]) == 0
    out = capsys.readouterr().out
    assert f"-> {run / 'capture.pcap'}  (tshark -r {run / 'capture.pcap'} -d can.subdissector,canopen)" in out
    assert stand(["pcap", str(run / "capture.log"), "-o", str(run / "capture.log")]) == 2
    assert "that is the capture itself" in capsys.readouterr().err
