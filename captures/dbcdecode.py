"""DBC-driven vectorized signal decoding: every frame of a message in one numpy expression.

For each signal cantools gives the start bit, length, byte order, sign, float flag, scale and
offset. The payloads of all frames of one message form an (m, 8) byte matrix; viewed as one
64-bit word per frame (little- or big-endian) a signal is a shift and a mask::

    Intel (little-endian):    raw = (word_le >> start) & (2^len − 1)
    Motorola (big-endian):    raw = (word_be >> (64 − msb − len)) & (2^len − 1),
                              msb = 8·(start // 8) + 7 − start % 8   (cantools' start = MSB)
    signed:                   two's complement sign extension from bit len−1
    physical:                 raw · scale + offset      (the same float64 operations as cantools)

so the decoded values equal cantools' ``decode_message`` bit for bit. Frames whose length differs
from the DBC's are counted, never decoded, except the shorter forms a protocol allows
(:data:`SHORTER_FORMS`: CiA 301's SYNC without its counter); unknown ids are counted per id. Multiplexed signals
are NaN in frames whose multiplexer selects another group. CAN FD messages longer than 8 bytes
use a byte window per signal. The per-signal arithmetic is in :mod:`captures.codecs`; the stand's
DBC comes precompiled (:mod:`captures.dbctable`), so decoding with it does not load cantools.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from dbc.profile import SYNC_COB_ID

from .codecs import MessageCodec, SignalCodec  # noqa: F401 (SignalCodec re-exported)
from .dbctable import load_dbc, precompiled_codecs
from .frames import ERROR, EXTENDED, REMOTE, CaptureError, FrameChunk

#: frame id -> a shorter length that is the same message too. CiA 301's SYNC carries a 1-byte
#: counter only when the producer's counter overflow value (0x1019) is set; the default, and
#: what most masters send, is a SYNC of DLC 0. Its counter decodes as 0, a value the counter
#: never takes (it runs from 1).
SHORTER_FORMS = {SYNC_COB_ID: 0}

@dataclass
class DecodedMessage:
    """All frames of one message in a chunk: positions in the chunk, timestamps, signals."""

    codec: MessageCodec
    index: np.ndarray
    ts: np.ndarray
    raw: dict
    phys: dict

    @property
    def name(self) -> str:
        return self.codec.name


@dataclass
class DecodeStats:
    """Counts over a whole capture (kept across chunks)."""

    frames: int = 0
    decoded: int = 0
    unknown: int = 0
    unknown_ids: dict = field(default_factory=dict)     #: "0x123" -> count (at most 50 ids kept)
    wrong_dlc: dict = field(default_factory=dict)       #: message -> count
    remote: int = 0
    error_frames: int = 0
    other_channel: int = 0
    #: the names of the channels whose frames were skipped
    other_channels: list = field(default_factory=list)
    #: the channel kept when none was given: the one of the stand's first SYNC
    channel_chosen: str | None = None
    out_of_order: int = 0
    max_backstep_s: float = 0.0
    first_ts: float | None = None
    last_ts: float | None = None
    per_message: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return dict(self.__dict__)


class _Message(NamedTuple):
    """What classifying a frame needs to know of a DBC message."""

    name: str
    frame_id: int
    extended: bool
    length: int


class FrameDecoder:
    """Decode chunks with a DBC: ``decode(chunk) -> {message name: DecodedMessage}``.

    ``dbc``: a DBC file (default: the stand's), or a cantools database. The stand's DBC is
    decoded from its precompiled codecs (:mod:`captures.dbctable`) without loading cantools;
    any other DBC is read with cantools."""

    def __init__(self, dbc=None, messages: list[str] | None = None, channel: str | None = None) -> None:
        #: per DBC message, in DBC order: its codec, or None where cantools decodes it (_fallback)
        self.codecs: list[MessageCodec | None] = []
        self._fallback: dict[int, Any] = {}
        self._messages: list[_Message] = []
        precompiled = precompiled_codecs(dbc)
        if precompiled is not None:
            self.codecs = list(precompiled)
            self._messages = [_Message(c.name, c.frame_id, c.extended, c.length) for c in precompiled]
        else:
            for msg in load_dbc(dbc).messages:
                try:
                    self.codecs.append(MessageCodec.from_cantools(msg))
                except CaptureError:
                    self.codecs.append(None)
                    self._fallback[len(self.codecs) - 1] = msg
                self._messages.append(_Message(msg.name, msg.frame_id, bool(msg.is_extended_frame),
                                               msg.length))
        self.wanted = None if messages is None else set(messages)
        self._std = np.full(2048, -1, np.int32)
        ext_ids, ext_idx = [], []
        for i, msg in enumerate(self._messages):
            if msg.extended:
                ext_ids.append(msg.frame_id)
                ext_idx.append(i)
            elif msg.frame_id < 2048:
                self._std[msg.frame_id] = i
        order = np.argsort(ext_ids)
        self._ext_ids = np.array(ext_ids, np.uint32)[order]
        self._ext_idx = np.array(ext_idx, np.int32)[order]
        self.channel = channel
        self.stats = DecodeStats()
        self._last_ts: float | None = None

    def message(self, name: str) -> MessageCodec:
        for c, msg in zip(self.codecs, self._messages):
            if msg.name == name:
                if c is None:
                    raise CaptureError(f"message {name} cannot be decoded vectorized")
                return c
        raise CaptureError(f"the DBC has no message {name}")

    def find_signal(self, signal: str) -> MessageCodec:
        """The message carrying ``signal`` (the first one, in DBC order)."""
        for c in self.codecs:
            if c is not None and any(s.name == signal for s in c.signals):
                return c
        raise CaptureError(f"no message in the DBC carries a signal named {signal!r}")

    def _timing(self, chunk: FrameChunk) -> None:
        st = self.stats
        ts = chunk.ts
        if not len(ts):
            return
        prev = ts[0] if self._last_ts is None else self._last_ts
        steps = np.diff(ts, prepend=prev)
        back = steps < 0
        if back.any():
            st.out_of_order += int(back.sum())
            st.max_backstep_s = max(st.max_backstep_s, float(-steps[back].min()))
        if st.first_ts is None:
            st.first_ts = float(ts[0])
        st.last_ts = float(ts[-1]) if st.last_ts is None else max(st.last_ts, float(ts.max()))
        self._last_ts = float(ts[-1])

    def classify(self, chunk: FrameChunk) -> np.ndarray:
        """Message index per frame (-1: unknown id or not a data frame; stats updated)."""
        st = self.stats
        st.frames += len(chunk)
        self._timing(chunk)
        flags = chunk.flags
        ext = (flags & EXTENDED) != 0
        idx = np.where(ext | (chunk.can_id >= 2048), -1, self._std[np.minimum(chunk.can_id, 2047)]).astype(np.int16)
        if ext.any() and len(self._ext_ids):
            pos = np.searchsorted(self._ext_ids, chunk.can_id[ext])
            pos = np.minimum(pos, len(self._ext_ids) - 1)
            hit = self._ext_ids[pos] == chunk.can_id[ext]
            idx[ext] = np.where(hit, self._ext_idx[pos], -1)
        remote = (flags & REMOTE) != 0
        error = (flags & ERROR) != 0
        st.remote += int(remote.sum())
        st.error_frames += int(error.sum())
        idx[remote | error] = -2
        if self.channel is not None and chunk.channels:
            if self.channel in chunk.channels:
                other = chunk.channel != chunk.channels.index(self.channel)
            else:
                other = np.ones(len(chunk), bool)
            skipped = other & (idx != -2)
            st.other_channel += int(skipped.sum())
            for i in np.unique(chunk.channel[skipped]).tolist():
                if chunk.channels[i] not in st.other_channels:
                    st.other_channels.append(chunk.channels[i])
            idx[other] = -2
        unknown = idx == -1
        n_unknown = int(unknown.sum())
        if n_unknown:
            st.unknown += n_unknown
            ids, counts = np.unique(chunk.can_id[unknown] | np.where(ext[unknown], 0x80000000, 0).astype(np.uint32),
                                    return_counts=True)
            book = st.unknown_ids
            for i, c in zip(ids.tolist(), counts.tolist()):
                key = f"0x{i & 0x1FFFFFFF:08X}" if i & 0x80000000 else f"0x{i:03X}"
                if key in book or len(book) < 50:
                    book[key] = book.get(key, 0) + c
        return idx

    def decode(self, chunk: FrameChunk, signals: dict[str, list[str]] | None = None) -> dict[str, DecodedMessage]:
        """Decode every known message in ``chunk`` (or only ``signals``: {message: [signal, ...]})."""
        idx = self.classify(chunk)
        st = self.stats
        out: dict[str, DecodedMessage] = {}
        known = idx >= 0
        if not known.any():
            return out
        order = np.argsort(idx, kind="stable")
        counts = np.bincount(idx[known], minlength=len(self.codecs))
        pos = int((idx < 0).sum())
        for m, count in enumerate(counts.tolist()):
            if not count:
                continue
            rows = order[pos:pos + count]
            pos += count
            msg = self._messages[m]
            codec = self.codecs[m]
            st.per_message[msg.name] = st.per_message.get(msg.name, 0) + count
            good = chunk.dlc[rows] == msg.length
            if msg.frame_id in SHORTER_FORMS and not msg.extended:
                good |= chunk.dlc[rows] == SHORTER_FORMS[msg.frame_id]
            if not good.all():
                bad = int((~good).sum())
                st.wrong_dlc[msg.name] = st.wrong_dlc.get(msg.name, 0) + bad
                rows = rows[good]
            st.decoded += len(rows)
            if signals is not None and msg.name not in signals:
                continue
            if self.wanted is not None and msg.name not in self.wanted:
                continue
            if not len(rows):
                continue
            if codec is None:
                out[msg.name] = self._decode_slow(self._fallback[m], chunk, rows)
                continue
            raw, phys = codec.decode(chunk.data[rows], None if signals is None else signals[msg.name])
            out[msg.name] = DecodedMessage(codec, rows, chunk.ts[rows], raw, phys)
        return out

    def _decode_slow(self, msg, chunk: FrameChunk, rows: np.ndarray) -> DecodedMessage:
        """Per-frame cantools decoding for the rare layouts the vectorized path cannot do."""
        values = [msg.decode(chunk.payload(i), decode_choices=False) for i in rows]
        phys = {s.name: np.array([v.get(s.name, np.nan) for v in values], np.float64) for s in msg.signals}
        return DecodedMessage(None, rows, chunk.ts[rows], dict(phys), phys)
