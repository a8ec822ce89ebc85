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
use a byte window per signal.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cantools
import numpy as np

from dbc.profile import SYNC_COB_ID

from .frames import ERROR, EXTENDED, REMOTE, CaptureError, FrameChunk

#: frame id -> a shorter length that is the same message too. CiA 301's SYNC carries a 1-byte
#: counter only when the producer's counter overflow value (0x1019) is set; the default, and
#: what most masters send, is a SYNC of DLC 0. Its counter decodes as 0, a value the counter
#: never takes (it runs from 1).
SHORTER_FORMS = {SYNC_COB_ID: 0}

DEFAULT_DBC = Path(__file__).resolve().parent.parent / "dbc" / "stand.dbc"


def load_dbc(dbc: str | Path | cantools.database.can.Database | None = None):
    """A cantools database (default: the stand's ``dbc/stand.dbc``)."""
    if dbc is None:
        dbc = DEFAULT_DBC
    if isinstance(dbc, cantools.database.can.Database):
        return dbc
    try:
        return cantools.database.load_file(str(dbc))
    except FileNotFoundError:
        raise CaptureError(f"DBC file {dbc} does not exist") from None
    except Exception as exc:  # cantools raises many parser-specific errors
        raise CaptureError(f"cannot read DBC file {dbc}: {exc}") from None


@dataclass(frozen=True)
class SignalCodec:
    """How to pull one signal out of a frame's payload."""

    name: str
    byte0: int          #: first byte of the 8-byte window holding the signal
    shift: int          #: right shift of the window word
    big_endian: bool
    length: int
    signed: bool
    is_float: bool
    scale: float
    offset: float
    mux_ids: tuple[int, ...] | None
    integer: bool       #: physical value is an integer (scale 1, offset 0, not float)

    @classmethod
    def from_cantools(cls, sig, message_length: int) -> "SignalCodec":
        length = sig.length
        if sig.byte_order == "little_endian":
            first = sig.start // 8
            last = (sig.start + length - 1) // 8
            byte0 = first if message_length > 8 else 0
            shift = sig.start - 8 * byte0
        else:
            msb = 8 * (sig.start // 8) + 7 - sig.start % 8
            first, last = msb // 8, (msb + length - 1) // 8
            byte0 = first if message_length > 8 else 0
            shift = 64 - (msb - 8 * byte0) - length
        if last - byte0 >= 8 or shift < 0:
            raise CaptureError(f"signal {sig.name} spans more than 8 bytes; not supported")
        integer = (not sig.is_float and sig.scale == 1 and sig.offset == 0
                   and not (length == 64 and not sig.is_signed))
        mux = tuple(sig.multiplexer_ids) if sig.multiplexer_ids else None
        return cls(sig.name, byte0, shift, sig.byte_order == "big_endian", length, sig.is_signed,
                   sig.is_float, sig.scale, sig.offset, mux, integer)

    def raw(self, words: dict) -> np.ndarray:
        """Raw value (uint64 bit pattern, or int64 when signed) from the window words."""
        word = words[(self.byte0, self.big_endian)]
        raw = word >> np.uint64(self.shift) if self.shift else word
        if self.length < 64:
            raw = raw & np.uint64((1 << self.length) - 1)
        if self.signed and not self.is_float:
            if self.length < 64:
                s = 64 - self.length
                return (raw << np.uint64(s)).view(np.int64) >> np.int64(s)
            return raw.view(np.int64)
        return raw

    def physical(self, raw: np.ndarray) -> np.ndarray:
        if self.is_float:
            with np.errstate(invalid="ignore", over="ignore"):   # NaN/inf payloads stay NaN/inf
                value = (raw.astype(np.uint32).view(np.float32).astype(np.float64) if self.length == 32
                         else raw.view(np.float64))
                return value * self.scale + self.offset
        if self.integer:
            return raw.astype(np.int64)
        return raw.astype(np.float64) * self.scale + self.offset


@dataclass
class MessageCodec:
    name: str
    frame_id: int
    extended: bool
    length: int
    signals: list[SignalCodec]
    multiplexer: str | None = None

    @classmethod
    def from_cantools(cls, msg) -> "MessageCodec":
        sigs = [SignalCodec.from_cantools(s, msg.length) for s in msg.signals]
        mux = next((s.name for s in msg.signals if s.is_multiplexer), None)
        return cls(msg.name, msg.frame_id, bool(msg.is_extended_frame), msg.length, sigs, mux)

    def signal(self, name: str) -> SignalCodec:
        for s in self.signals:
            if s.name == name:
                return s
        raise KeyError(f"message {self.name} has no signal {name}")

    def words(self, data: np.ndarray) -> dict:
        """The 64-bit window words every signal of this message needs."""
        out = {}
        width = data.shape[1]
        for s in self.signals:
            key = (s.byte0, s.big_endian)
            if key in out:
                continue
            if s.byte0 + 8 <= width:
                win = data[:, s.byte0:s.byte0 + 8]
            else:
                win = np.zeros((len(data), 8), np.uint8)
                win[:, :width - s.byte0] = data[:, s.byte0:]
            win = np.ascontiguousarray(win)
            out[key] = win.view(">u8" if s.big_endian else "<u8").ravel().astype(np.uint64)
        return out

    def decode(self, data: np.ndarray, names: list[str] | None = None) -> tuple[dict, dict]:
        """(raw, physical) arrays per signal for payload rows ``data`` (m, w)."""
        words = self.words(data)
        raw = {}
        phys = {}
        for s in self.signals:
            if names is not None and s.name not in names and s.name != self.multiplexer:
                continue
            raw[s.name] = r = s.raw(words)
            phys[s.name] = s.physical(r)
        if self.multiplexer is not None:
            mux = raw[self.multiplexer].astype(np.int64)
            for s in self.signals:
                if s.mux_ids is not None and s.name in phys:
                    keep = np.isin(mux, s.mux_ids)
                    phys[s.name] = np.where(keep, phys[s.name].astype(np.float64), np.nan)
        return raw, phys


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


class FrameDecoder:
    """Decode chunks with a DBC: ``decode(chunk) -> {message name: DecodedMessage}``."""

    def __init__(self, dbc=None, messages: list[str] | None = None, channel: str | None = None) -> None:
        self.db = load_dbc(dbc)
        self.codecs: list[MessageCodec] = []
        self._fallback: dict[int, object] = {}
        for msg in self.db.messages:
            try:
                self.codecs.append(MessageCodec.from_cantools(msg))
            except CaptureError:
                self.codecs.append(None)
                self._fallback[len(self.codecs) - 1] = msg
        self.wanted = None if messages is None else set(messages)
        self._std = np.full(2048, -1, np.int32)
        ext_ids, ext_idx = [], []
        for i, msg in enumerate(self.db.messages):
            if msg.is_extended_frame:
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
        for c, msg in zip(self.codecs, self.db.messages):
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
            msg = self.db.messages[m]
            codec = self.codecs[m]
            st.per_message[msg.name] = st.per_message.get(msg.name, 0) + count
            good = chunk.dlc[rows] == msg.length
            if msg.frame_id in SHORTER_FORMS and not msg.is_extended_frame:
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
                out[msg.name] = self._decode_slow(msg, chunk, rows)
                continue
            raw, phys = codec.decode(chunk.data[rows], None if signals is None else signals[msg.name])
            out[msg.name] = DecodedMessage(codec, rows, chunk.ts[rows], raw, phys)
        return out

    def _decode_slow(self, msg, chunk: FrameChunk, rows: np.ndarray) -> DecodedMessage:
        """Per-frame cantools decoding for the rare layouts the vectorized path cannot do."""
        values = [msg.decode(chunk.payload(i), decode_choices=False) for i in rows]
        phys = {s.name: np.array([v.get(s.name, np.nan) for v in values], np.float64) for s in msg.signals}
        return DecodedMessage(None, rows, chunk.ts[rows], dict(phys), phys)
