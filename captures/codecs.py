"""How to pull a DBC message's signals out of a block of payloads: one numpy expression per signal.

For each signal cantools gives the start bit, length, byte order, sign, float flag, scale and
offset (:meth:`SignalCodec.from_cantools`); a :class:`MessageCodec` holds them for one message.
Codecs are plain data: :meth:`MessageCodec.as_dict` / :meth:`MessageCodec.from_dict` store them
as JSON, which is how the stand's DBC is decoded without loading cantools
(:mod:`captures.dbctable`). The equations are in :mod:`captures.dbcdecode`.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .frames import CaptureError


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

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "SignalCodec":
        mux = d["mux_ids"]
        return cls(**{**d, "mux_ids": None if mux is None else tuple(mux)})

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
        """The codec of a cantools message (:class:`CaptureError` if a signal is not vectorizable)."""
        sigs = [SignalCodec.from_cantools(s, msg.length) for s in msg.signals]
        mux = next((s.name for s in msg.signals if s.is_multiplexer), None)
        return cls(msg.name, msg.frame_id, bool(msg.is_extended_frame), msg.length, sigs, mux)

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "frame_id": self.frame_id, "extended": self.extended,
                "length": self.length, "multiplexer": self.multiplexer,
                "signals": [s.as_dict() for s in self.signals]}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "MessageCodec":
        return cls(d["name"], d["frame_id"], d["extended"], d["length"],
                   [SignalCodec.from_dict(s) for s in d["signals"]], d["multiplexer"])

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
