"""Any capture as a pcap of SocketCAN frames, so Wireshark's and tshark's dissectors read it.

A pcap file (libpcap 2.4, microsecond timestamps, little-endian headers) of link type
``LINKTYPE_CAN_SOCKETCAN`` (227). Each packet is the frame as Linux's SocketCAN hands it to a
socket (``struct can_frame`` / ``struct canfd_frame`` of ``linux/can.h``), which is what
tcpdump.org's definition of the link type describes, with the id in network byte order:

======  =====  ==============================================================================
offset  bytes  field
======  =====  ==============================================================================
0       4      ``can_id``, big-endian: 11- or 29-bit id | ``CAN_EFF_FLAG`` 0x80000000 (29-bit)
               | ``CAN_RTR_FLAG`` 0x40000000 (remote) | ``CAN_ERR_FLAG`` 0x20000000 (error frame)
4       1      payload length (classic: 0-8, a remote frame's requested DLC; FD: 0-64)
5       1      FD flags: ``CANFD_FDF`` 0x04 (this is a CAN FD frame) | ``CANFD_BRS`` 0x01 |
               ``CANFD_ESI`` 0x02; 0 on a classic frame
6       2      reserved, 0
8       8/64   data, zero-padded: 8 bytes (``CAN_MTU`` = 16) or 64 (``CANFD_MTU`` = 72)
======  =====  ==============================================================================

Wireshark (3.6 and later) tells an FD frame from a classic one by ``CANFD_FDF`` with the two
reserved bytes 0; older versions by the packet length 72, so FD frames are written whole.

An error frame is written as SocketCAN reports one: ``CAN_ERR_FLAG`` with the error classes in
the id bits and 8 data bytes. A candump log's error frames carry those classes (``20000080#...``);
other formats' error frames do not, and are written with none.

A pcap has one link per file and no bus names, so a capture of several buses is written one
channel at a time (``channel=``).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .frames import BRS, ERROR, ESI, EXTENDED, FD, REMOTE, CaptureError, Damage, FrameChunk, ReadStats

LINKTYPE_CAN_SOCKETCAN = 227
CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
CANFD_BRS, CANFD_ESI, CANFD_FDF = 0x01, 0x02, 0x04
CAN_MTU, CANFD_MTU = 16, 72
SNAPLEN = 65535

#: pcap file header: magic, version 2.4, GMT offset, accuracy, snapshot length, link type
FILE_HEADER = np.array([(0xA1B2C3D4, 2, 4, 0, 0, SNAPLEN, LINKTYPE_CAN_SOCKETCAN)],
                       np.dtype([("magic", "<u4"), ("major", "<u2"), ("minor", "<u2"), ("zone", "<i4"),
                                 ("sigfigs", "<u4"), ("snaplen", "<u4"), ("linktype", "<u4")])).tobytes()


def _frame_dtype(width: int) -> np.dtype:
    """One SocketCAN frame of ``width`` data bytes (``struct can_frame`` / ``canfd_frame``)."""
    return np.dtype([("can_id", ">u4"), ("len", "u1"), ("fd_flags", "u1"), ("reserved", "<u2"),
                     ("data", "u1", (width,))])


#: a pcap record header
_RECORD = np.dtype([("sec", "<u4"), ("usec", "<u4"), ("incl_len", "<u4"), ("orig_len", "<u4")])


def socketcan_frames(chunk: FrameChunk, error_classes: bool = True) -> np.ndarray:
    """Every frame of ``chunk`` as Linux's SocketCAN frame (a structured array: ``can_id``,
    ``len``, ``fd_flags``, ``reserved``, ``data`` of 8 bytes, or 64 where the chunk holds CAN FD
    frames; a classic frame among FD ones is its first :data:`CAN_MTU` bytes).

    ``error_classes``: the id bits of an error frame are SocketCAN's error classes (candump), so
    they are kept; otherwise an error frame is written without classes."""
    fd = (chunk.flags & FD) != 0
    error = (chunk.flags & ERROR) != 0
    remote = (chunk.flags & REMOTE) != 0
    width = 64 if fd.any() else 8
    out = np.zeros(len(chunk), _frame_dtype(width))
    ident = chunk.can_id.astype(np.uint32) & np.uint32(0x1FFFFFFF)
    out["can_id"] = np.where(error, (ident if error_classes else 0) | CAN_ERR_FLAG,
                             ident | np.where((chunk.flags & EXTENDED) != 0, CAN_EFF_FLAG, 0)
                             | np.where(remote & ~fd, CAN_RTR_FLAG, 0))
    out["len"] = np.where(error, 8, chunk.dlc)
    out["fd_flags"] = np.where(fd, CANFD_FDF | np.where((chunk.flags & BRS) != 0, CANFD_BRS, 0)
                               | np.where((chunk.flags & ESI) != 0, CANFD_ESI, 0), 0)
    length = np.where(error, np.minimum(chunk.dlc, 8), np.where(remote, 0, chunk.dlc))
    data = chunk.data[:, :width]
    if data.shape[1] < width:
        data = np.pad(data, ((0, 0), (0, width - data.shape[1])))
    out["data"] = np.where(np.arange(width)[None, :] < length[:, None], data, 0)
    return out


def pcap_records(chunk: FrameChunk, error_classes: bool = True, frames: np.ndarray | None = None) -> bytes:
    """The pcap records (record header + SocketCAN frame) of every frame of ``chunk``, in order
    (``frames``: its :func:`socketcan_frames`, if made already)."""
    n = len(chunk)
    if n == 0:
        return b""
    if not np.all(np.isfinite(chunk.ts)) or chunk.ts.min() < 0:
        raise CaptureError("a frame's timestamp is negative or not a number: a pcap cannot hold it")
    if frames is None:
        frames = socketcan_frames(chunk, error_classes)
    fd = (chunk.flags & FD) != 0
    rec = np.zeros(n, np.dtype([("head", _RECORD), ("frame", frames.dtype)]))
    us = np.round(chunk.ts * 1e6).astype(np.int64)
    rec["head"]["sec"], rec["head"]["usec"] = np.divmod(us, 1_000_000)
    size = np.where(fd, CANFD_MTU, CAN_MTU).astype(np.uint32)
    rec["head"]["incl_len"] = rec["head"]["orig_len"] = size
    rec["frame"] = frames
    if not fd.any() or fd.all():
        return rec.tobytes()
    # classic frames among FD ones: each record keeps only its own length (header 16 + frame)
    raw = rec.view(np.uint8).reshape(n, rec.dtype.itemsize)
    return raw[np.arange(rec.dtype.itemsize)[None, :] < (16 + size)[:, None]].tobytes()


@dataclass
class PcapResult:
    """What :func:`capture_to_pcap` wrote."""

    path: Path
    frames: int = 0                 #: frames written
    fd_frames: int = 0
    remote_frames: int = 0
    error_frames: int = 0
    channel: str | None = None      #: the bus channel written (as the capture names it)
    other_channels: dict[str, int] = field(default_factory=dict)   #: frames of other channels, skipped
    read: ReadStats = field(default_factory=ReadStats)

    @property
    def damage(self) -> Damage | None:
        return self.read.damage

    def summary(self) -> str:
        kinds = [f"{v:,} {k}" for k, v in (("CAN FD", self.fd_frames), ("remote", self.remote_frames),
                                            ("error", self.error_frames)) if v]
        text = f"{self.path}: {self.frames:,} frames" + (f" ({', '.join(kinds)})" if kinds else "")
        if self.channel is not None:
            text += f" of channel {self.channel}"
        if self.other_channels:
            text += "; skipped " + ", ".join(f"{n:,} of {c}" for c, n in sorted(self.other_channels.items()))
        return text


def capture_to_pcap(capture: str | Path, out: str | Path, channel: str | None = None,
                    on_damage: str = "stop") -> PcapResult:
    """Write ``capture`` (any format :func:`captures.open_capture` reads) as a SocketCAN pcap.

    ``channel``: only this bus channel's frames (as the capture names it, e.g. ``can0``); needed
    when the capture holds several. A damaged capture is written up to the damage (or past it,
    ``on_damage="skip"``) and the result's :attr:`~PcapResult.damage` says where. The file is
    written beside ``out`` and renamed onto it at the end: ``out`` is never left half-written."""
    from .readers import capture_format, open_capture
    out = Path(out)
    if out.is_dir():
        raise CaptureError(f"{out} is a directory: give the pcap file to write, e.g. {out / 'capture.pcap'}")
    if not out.parent.is_dir():
        raise CaptureError(f"{out.parent} does not exist: create it or write the pcap elsewhere")
    reader = open_capture(capture, on_damage=on_damage)
    error_classes = capture_format(capture) == "candump"
    result = PcapResult(out, channel=channel, read=reader.stats)
    tmp = out.parent / f".{out.name}.{os.getpid()}.tmp"
    try:
        with open(tmp, "wb") as fh:
            fh.write(FILE_HEADER)
            for chunk in reader:
                chunk = _one_channel(chunk, result, capture, chosen=channel is not None)
                fh.write(pcap_records(chunk, error_classes))
                result.frames += len(chunk)
                result.fd_frames += int(np.count_nonzero(chunk.flags & FD))
                result.remote_frames += int(np.count_nonzero((chunk.flags & (REMOTE | ERROR)) == REMOTE))
                result.error_frames += int(np.count_nonzero(chunk.flags & ERROR))
            if channel is not None and result.frames == 0 and result.other_channels:
                raise CaptureError(f"{capture} has no frames of channel {channel}; its channels: "
                                   f"{', '.join(sorted(result.other_channels))}")
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return result


def _one_channel(chunk: FrameChunk, result: PcapResult, capture, chosen: bool) -> FrameChunk:
    """The chunk's frames of the one channel written; the others counted, or an error when the
    capture has several and none was ``chosen``."""
    names = chunk.channels or [""]
    present = sorted({names[i] for i in np.unique(chunk.channel)})
    if not chosen and present:
        seen = present if result.channel is None else sorted({result.channel, *present})
        if len(seen) > 1:
            raise CaptureError(f"{capture}: the capture holds several bus channels "
                               f"({', '.join(seen)}); a pcap holds one: give --channel NAME")
        result.channel = present[0]
    if present == [result.channel]:
        return chunk
    mine = np.array([n == result.channel for n in names])[chunk.channel]
    for i in np.unique(chunk.channel[~mine]):
        result.other_channels[names[i]] = result.other_channels.get(names[i], 0) + int(np.count_nonzero(chunk.channel == i))
    return chunk.take(mine)
