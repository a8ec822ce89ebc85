"""Vectorized reader for candump logs (``candump -L``, python-can's ``CanutilsLogWriter``).

One line per frame, exactly as can-utils writes it::

    (1700000000.123456) vcan0 182#A0860100FF
    (1700000000.123456) vcan0 182#A0860100FF R      <- optional direction flag (python-can, newer can-utils)
    (1700000000.124000)  can1 12345678#1122         <- 8 hex digits: extended id; names padded when several
    (1700000000.125000) can0 123#R                   <- remote frame (also R<dlc>)
    (1700000000.126000) can0 123##1AABBCC            <- CAN FD: '##', flags nibble, data
    (1700000000.127000) can0 20000080#0000000000000000   <- error frame (CAN_ERR_FLAG in the id)

How it is fast: a block of a few MB is one numpy byte array; the positions of every newline,
space, '#' and '.' are found with one comparison each; timestamps, ids and data bytes are then
parsed for all lines of the block at once (digit/hex look-up tables over fixed-width windows).
Lines the vectorized grammar does not cover (CAN FD, remote frames, odd spacing) are parsed one by
one by :func:`parse_line`, which follows python-can's ``CanutilsLogReader``; a line neither can
parse is *damaged*.

Timestamps are exactly python-can's (``float(text)``): the digits are read as one integer N and
divided once by 10^d (both exact in float64 when N < 2^53), which is the correctly rounded value.

Damage: a line that is not a frame, or a last line without its newline (a capture cut short),
stops the reader (``on_damage="stop"``, the default: everything before it is yielded and
:attr:`ReadStats.damage` names the line and byte) or is counted and skipped (``"skip"``).
"""
from __future__ import annotations

import gzip
import io
from pathlib import Path
from typing import Iterator

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from .frames import (BRS, CAN_ERR_FLAG, ERROR, ESI, EXTENDED, FD, REMOTE, TX, CaptureError, Damage,
                     FrameChunk, ReadStats)

DEFAULT_CHUNK_BYTES = 1 << 20
MAX_LINE = 1 << 16              #: longer "lines" mean this is not a text capture
_PAD = 48
_TS_WIDTH = 24
_ID_WIDTH = 8
_CHAN_WIDTH = 32
_TWO53 = 2 ** 53

_HEX = np.full(256, 255, np.uint8)
for _i, _c in enumerate(b"0123456789ABCDEF"):
    _HEX[_c] = _i
for _i, _c in enumerate(b"abcdef"):
    _HEX[_c] = 10 + _i
_POW10 = 10.0 ** np.arange(24)
#: two hex characters (as a little-endian uint16: first char in the low byte) -> byte, or 0xFFFF
_HEX2 = np.where((_HEX[np.arange(65536) & 0xFF] <= 15) & (_HEX[np.arange(65536) >> 8] <= 15),
                 (_HEX[np.arange(65536) & 0xFF].astype(np.uint16) << 4) | _HEX[np.arange(65536) >> 8],
                 0xFFFF).astype(np.uint16)


def open_binary(path: Path) -> io.BufferedIOBase:
    """Open a capture for binary reading; ``.gz`` files are decompressed on the fly."""
    try:
        if path.suffix.lower() == ".gz":
            return gzip.open(path, "rb")
        return open(path, "rb")
    except OSError as exc:
        raise CaptureError(f"cannot read {path}: {exc}") from None


class CandumpReader:
    """Stream a candump log as :class:`FrameChunk` s of about ``chunk_bytes`` of text each."""

    def __init__(self, path: str | Path, chunk_bytes: int = DEFAULT_CHUNK_BYTES,
                 on_damage: str = "stop") -> None:
        if on_damage not in ("stop", "skip"):
            raise CaptureError(f"on_damage must be 'stop' or 'skip', not {on_damage!r}")
        self.path = Path(path)
        self.chunk_bytes = max(int(chunk_bytes), 1024)
        self.on_damage = on_damage
        self.stats = ReadStats()

    def __iter__(self) -> Iterator[FrameChunk]:
        stats = self.stats
        carry = b""
        line0 = 0          # lines before the current block
        byte0 = 0          # file offset of the current block
        with open_binary(self.path) as fh:
            while True:
                try:
                    raw = fh.read(self.chunk_bytes)
                except (OSError, EOFError, gzip.BadGzipFile) as exc:
                    stats.damage = Damage(str(self.path), byte0 + len(carry),
                                          f"the file cannot be read further ({exc})", line0 + 1)
                    raw = b""
                    carry = b""      # the partial line before a read error is not trusted
                    eof = True
                else:
                    eof = not raw
                stats.bytes_read += len(raw)
                block = carry + raw
                cut = block.rfind(b"\n") + 1
                if eof:
                    if cut < len(block) and stats.damage is None:
                        stats.damage = Damage(str(self.path), byte0 + cut,
                                              "the file ends in the middle of a line (truncated "
                                              "capture?); that line is not decoded",
                                              line0 + block.count(b"\n", 0, cut) + 1)
                    block, carry = block[:cut], b""
                else:
                    block, carry = block[:cut], block[cut:]
                    if len(carry) > MAX_LINE:
                        stats.damage = Damage(str(self.path), byte0 + cut,
                                              f"no line break within {MAX_LINE} bytes: not a "
                                              "candump log, or corrupted", line0 + block.count(b"\n") + 1)
                        eof = True
                        carry = b""
                if block:
                    chunk, n_lines, damage = parse_block(block, line0, byte0, str(self.path),
                                                         self.on_damage, stats)
                    line0 += n_lines
                    byte0 += len(block)
                    if len(chunk):
                        stats.frames += len(chunk)
                        yield chunk
                    if damage is not None:
                        stats.damage = damage
                        return
                if eof or stats.damage is not None:
                    return


def parse_block(block: bytes, line0: int, byte0: int, path: str, on_damage: str,
                stats: ReadStats) -> tuple[FrameChunk, int, Damage | None]:
    """Parse whole lines (``block`` ends with a newline). Returns the frames, the number of
    lines in the block and the damage that stops reading (``on_damage="stop"``) if any."""
    b = np.frombuffer(block, np.uint8)
    nl = np.flatnonzero(b == 10)
    n_lines = len(nl)
    starts = np.empty(n_lines, np.int64)
    starts[0] = 0
    starts[1:] = nl[:-1] + 1
    ends = nl.astype(np.int64)
    cr = (ends > starts) & (b[ends - 1] == 13)
    ends = ends - cr
    length = ends - starts
    empty = length == 0
    bp = np.frombuffer(block + bytes(_PAD), np.uint8)

    ok, cols = _template_parse(block, bp, starts, ends, length, empty)
    rest = ~ok & ~empty
    if rest.any():
        ok_g, cols_g = _fast_parse(b, bp, nl, starts, ends, length)
        take = rest & ok_g
        if take.any():
            ok = ok | take
            names_t, chan_t = cols["channels"], cols["chan"]
            names_g, chan_g = _channels(bp, cols_g, np.flatnonzero(take))
            merged = list(names_t)
            remap = np.array([_index(merged, n) for n in names_g] or [0], np.int16)
            chan_t = chan_t.copy()
            chan_t[take] = remap[chan_g]
            for key in ("ts", "can_id", "flags", "dlc", "data"):
                cols[key] = np.where(take[:, None] if key == "data" else take, cols_g[key], cols[key])
            cols["channels"], cols["chan"] = merged, chan_t
    fast = ok & ~empty
    todo = np.flatnonzero(~ok & ~empty)

    # lines for the one-by-one parser
    slow_rows: list[tuple[int, tuple]] = []
    bad: list[tuple[int, str]] = []
    for i in todo:
        line = block[starts[i]:ends[i]]
        try:
            parsed = parse_line(line)
        except ValueError as exc:
            bad.append((int(i), str(exc)))
            continue
        if parsed is None:
            empty[i] = True
        else:
            slow_rows.append((int(i), parsed))
    stats.slow_path_lines += len(slow_rows)
    damage = None
    limit = n_lines
    if bad:
        first, reason = bad[0]
        where = Damage(path, byte0 + int(starts[first]), f"not a candump frame: {reason}",
                       line0 + first + 1)
        if on_damage == "stop":
            damage = where
            limit = first
            slow_rows = [r for r in slow_rows if r[0] < first]
            bad = bad[:1]
        else:
            if stats.first_damage is None:
                stats.first_damage = where
            stats.damaged += len(bad)
    stats.skipped_lines += int(empty[:limit].sum())

    sel = np.flatnonzero(fast[:limit])
    n = len(sel) + len(slow_rows)
    width = 64 if any(len(r[1][5]) > 8 for r in slow_rows) else 8
    ts = np.empty(n, np.float64)
    can_id = np.empty(n, np.uint32)
    flags = np.empty(n, np.uint8)
    dlc = np.empty(n, np.uint8)
    data = np.zeros((n, width), np.uint8)
    chan = np.zeros(n, np.int16)
    names, fast_chan = list(cols["channels"]), cols["chan"][sel]
    if slow_rows:
        slow_idx = np.array([r[0] for r in slow_rows], np.int64)
        every = np.sort(np.concatenate([sel, slow_idx]))
        order = np.searchsorted(every, sel)
        slow_pos = np.searchsorted(every, slow_idx)
    else:
        order = np.arange(len(sel))
        slow_pos = np.empty(0, np.int64)
    ts[order] = cols["ts"][sel]
    can_id[order] = cols["can_id"][sel]
    flags[order] = cols["flags"][sel]
    dlc[order] = cols["dlc"][sel]
    data[order, :8] = cols["data"][sel]
    chan[order] = fast_chan
    for pos, (_, (t, cid, fl, channel, n_dlc, payload)) in zip(slow_pos, slow_rows):
        ts[pos] = t
        can_id[pos] = cid
        flags[pos] = fl
        dlc[pos] = n_dlc
        data[pos, :len(payload)] = np.frombuffer(payload, np.uint8)
        if channel not in names:
            names.append(channel)
        chan[pos] = names.index(channel)
    return FrameChunk(ts, can_id, flags, dlc, data, chan, names), n_lines, damage


def _template(block: bytes, starts: np.ndarray, ends: np.ndarray, empty: np.ndarray):
    """Layout of the first frame line: timestamp width, dot offset, channel bytes."""
    for i in np.flatnonzero(~empty)[:1]:
        line = block[starts[i]:ends[i]]
        close = line.find(b") ")
        if not line.startswith(b"(") or close < 3:
            return None
        dot = line.find(b".", 0, close)
        chan_end = line.find(b" ", close + 2)
        if dot < 2 or chan_end <= close + 2 or close - 1 > _TS_WIDTH or close - 2 > 18:
            return None
        return close - 1, dot - 1, line[close + 2:chan_end]
    return None


def _rows_all(mask: np.ndarray) -> np.ndarray:
    """``mask.all(axis=1)`` for a 2-D boolean array, fast for short rows: 8 flags per 64-bit
    word, words OR-ed column by column (numpy's reduction over a short axis is slow)."""
    w = mask.shape[1]
    pad = (-w) % 8
    m = np.ascontiguousarray(mask, dtype=np.uint8) ^ np.uint8(1)
    if pad:
        m = np.hstack([m, np.zeros((len(m), pad), np.uint8)])
    words = m.view(np.uint64)
    bad = words[:, 0].copy()
    for c in range(1, words.shape[1]):
        bad |= words[:, c]
    return bad == 0


def _template_parse(block, bp, starts, ends, length, empty):
    """The common case, all lines laid out like the first one (same timestamp width, same
    channel): every field sits at a fixed offset from the line start, so each is one gather;
    hex digits are decoded two at a time (a 64 K-entry table of character pairs)."""
    n_lines = len(starts)
    tmpl = _template(block, starts, ends, empty)
    ok = np.zeros(n_lines, bool)
    cols = {"ts": np.zeros(n_lines), "can_id": np.zeros(n_lines, np.uint32),
            "flags": np.zeros(n_lines, np.uint8), "dlc": np.zeros(n_lines, np.uint8),
            "data": np.zeros((n_lines, 8), np.uint8), "chan": np.zeros(n_lines, np.int16),
            "channels": []}
    if tmpl is None:
        return ok, cols
    nt, ni, chan = tmpl
    cl = len(chan)
    id0 = nt + 4 + cl                      # "(" ts ") " chan " "
    ok = (length >= id0 + 4) & (length <= id0 + 8 + 1 + 16 + 2)
    s = np.where(ok, starts, 0)
    head = sliding_window_view(bp, id0 + 9)[s]          # up to the '#' of an extended id
    sep = np.frombuffer(b"(" + b"0" * nt + b") " + chan + b" ", np.uint8)
    fixed = np.zeros(id0, bool)
    fixed[[0, nt + 1, nt + 2, id0 - 1]] = True
    fixed[nt + 3:nt + 3 + cl] = True
    ok &= _rows_all(head[:, :id0][:, fixed] == sep[fixed])
    ok &= head[:, 1 + ni] == 46
    # timestamp digits: one integer, then one correctly rounded division
    digit_cols = np.array([c for c in range(1, nt + 1) if c != 1 + ni])
    digits = head[:, digit_cols] - np.uint8(48)
    ok &= _rows_all(digits <= 9)
    weights = 10.0 ** np.arange(len(digit_cols) - 1, -1, -1)
    total = digits.astype(np.float64) @ weights
    nf = nt - ni - 1
    ts = total / 10.0 ** nf
    if len(digit_cols) > 15:
        big = total >= _TWO53
        for i in np.flatnonzero(big & ok):
            ts[i] = float(block[starts[i] + 1:starts[i] + 1 + nt])
    # id: 3 (standard) or 8 (extended) hex digits, then '#'
    ext = head[:, id0 + 8] == 35
    std = head[:, id0 + 3] == 35
    ok &= ext ^ std
    pairs = _HEX2[np.ascontiguousarray(head[:, id0:id0 + 8]).view("<u2")]       # (n, 4) bytes
    first = _HEX[head[:, id0]].astype(np.uint32)
    id_std = (first << 8) | _HEX2[np.ascontiguousarray(head[:, id0 + 1:id0 + 3]).view("<u2")[:, 0]]
    id_ext = ((pairs[:, 0].astype(np.uint32) << 24) | (pairs[:, 1].astype(np.uint32) << 16)
              | (pairs[:, 2].astype(np.uint32) << 8) | pairs[:, 3])
    ok &= np.where(ext, _rows_all(pairs <= 255), (first <= 15) & (id_std <= 0xFFF))
    ident = np.where(ext, id_ext, id_std).astype(np.uint32)
    error = ext & ((ident & CAN_ERR_FLAG) != 0)
    # data up to the end of the line or the direction flag
    last = bp[np.maximum(ends - 1, 0)]
    has_flag = (bp[np.maximum(ends - 2, 0)] == 32) & ((last == 82) | (last == 84) | (last == 114) | (last == 116))
    hash_pos = s + np.where(ext, id0 + 8, id0 + 3)
    dlen = ends - 2 * has_flag - (hash_pos + 1)
    ok &= (dlen >= 0) & (dlen <= 16) & (dlen % 2 == 0)
    window = sliding_window_view(bp, 16)[np.where(ok, hash_pos + 1, 0)]
    values = _HEX2[window.view("<u2")]                                           # (n, 8)
    inside = np.arange(8)[None, :] < (dlen // 2)[:, None]
    ok &= _rows_all((values <= 255) | ~inside)
    cols["data"] = np.where(inside, values, 0).astype(np.uint8)
    cols["ts"] = ts
    cols["can_id"] = ident & 0x1FFFFFFF
    cols["flags"] = (EXTENDED * ext | ERROR * error
                     | TX * (has_flag & ((last == 84) | (last == 116)))).astype(np.uint8)
    cols["dlc"] = (dlen // 2).astype(np.uint8)
    cols["channels"] = [chan.decode("latin-1")]
    return ok, cols


def _first_per_line(positions: np.ndarray, nl: np.ndarray, n_lines: int):
    """For byte ``positions`` of one character: count per line and the first position per line
    (-1 where none)."""
    line = np.searchsorted(nl, positions)
    count = np.bincount(line, minlength=n_lines)
    first_idx = np.cumsum(count) - count
    first = np.full(n_lines, -1, np.int64)
    has = count > 0
    first[has] = positions[first_idx[has]]
    return count, first, first_idx


def _fast_parse(b, bp, nl, starts, ends, length):
    """The vectorized grammar: ``(DIGITS.DIGITS) CHANNEL HEXID#HEXDATA[ R| T]``."""
    n_lines = len(nl)
    sp = np.flatnonzero(b == 32)
    hs = np.flatnonzero(b == 35)
    dots = np.flatnonzero(b == 46)
    nsp, sp1, fsp = _first_per_line(sp, nl, n_lines)
    nh, h1, _ = _first_per_line(hs, nl, n_lines)
    nd, d1, fd = _first_per_line(dots, nl, n_lines)

    ok = (nh == 1) & (nsp >= 2) & (nd >= 1) & (length >= 8)
    # second dot (if any) must be beyond the timestamp
    nxt = np.minimum(fd + 1, max(len(dots) - 1, 0))
    if len(dots):
        ok &= (nd == 1) | (dots[nxt] > sp1)
    ok &= (b[starts] == 40) & (sp1 > starts + 3) & (b[np.maximum(sp1 - 1, 0)] == 41)
    ok &= (d1 > starts + 1) & (d1 < sp1 - 1)
    # the space just before the id, the direction flag at the end
    k = np.searchsorted(sp, h1) - 1
    spid = sp[np.clip(k, 0, max(len(sp) - 1, 0))] if len(sp) else np.zeros(n_lines, np.int64)
    ok &= (h1 > 0) & (k >= fsp) & (spid > sp1)
    last = b[np.maximum(ends - 1, 0)]
    has_flag = (length >= 2) & (b[np.maximum(ends - 2, 0)] == 32) & np.isin(last, (82, 84, 114, 116))
    data_end = ends - 2 * has_flag
    spaces_after_hash = fsp + nsp - (k + 1)
    ok &= spaces_after_hash == has_flag

    # timestamp: digits without the dot as one integer, divided by 10^(fraction digits)
    nt = sp1 - 1 - (starts + 1)
    ni = d1 - (starts + 1)
    nf = nt - ni - 1
    ok &= (nt >= 1) & (nt <= _TS_WIDTH) & (nf <= 18) & (nt - 1 <= 18)
    win = sliding_window_view(bp, _TS_WIDTH)[np.where(ok, starts + 1, 0)]
    digits = win - np.uint8(48)
    total = np.zeros(n_lines, np.int64)
    for c in range(int(np.clip(nt.max(initial=0), 0, _TS_WIDTH))):
        use = (c < nt) & (c != ni)
        dc = digits[:, c]
        ok &= ~use | (dc <= 9)
        total = np.where(use, total * 10 + dc, total)
    nf_c = np.clip(nf, 0, 23)
    ts = total / _POW10[nf_c]
    big = ok & (total >= _TWO53)
    for i in np.flatnonzero(big):     # > 15 significant digits: rare (nanosecond logs)
        ts[i] = float(bytes(bp[starts[i] + 1:sp1[i] - 1]))

    # id: 1..8 hex digits; more than 3 means extended (python-can's rule; candump writes 3 or 8)
    idlen = h1 - (spid + 1)
    ok &= (idlen >= 1) & (idlen <= _ID_WIDTH)
    win = _HEX[sliding_window_view(bp, _ID_WIDTH)[np.where(ok, spid + 1, 0)]]
    ident = np.zeros(n_lines, np.int64)
    for c in range(_ID_WIDTH):
        use = c < idlen
        dc = win[:, c]
        ok &= ~use | (dc <= 15)
        ident = np.where(use, (ident << 4) | dc, ident)
    extended = idlen > 3
    error = extended & ((ident & CAN_ERR_FLAG) != 0)

    # data: 0..16 hex digits, even
    dlen = data_end - (h1 + 1)
    ok &= (dlen >= 0) & (dlen <= 16) & (dlen % 2 == 0)
    nib = _HEX[sliding_window_view(bp, 16)[np.where(ok, h1 + 1, 0)]]
    col = np.arange(16)
    inside = col[None, :] < dlen[:, None]
    ok &= ((nib <= 15) | ~inside).all(axis=1)
    nib = np.where(inside, nib, 0).astype(np.uint8)
    data = (nib[:, 0::2] << 4) | nib[:, 1::2]

    chan_len = spid - sp1 - 1
    ok &= (chan_len >= 1) & (chan_len <= _CHAN_WIDTH)

    flags = (EXTENDED * extended | ERROR * error
             | TX * (has_flag & ((last == 84) | (last == 116)))).astype(np.uint8)
    cols = {"ts": ts, "can_id": (ident & 0x1FFFFFFF).astype(np.uint32), "flags": flags,
            "dlc": (dlen // 2).astype(np.uint8), "data": data, "chan_start": sp1 + 1,
            "chan_len": chan_len}
    return ok, cols


def _channels(bp: np.ndarray, cols: dict, sel: np.ndarray) -> tuple[list[str], np.ndarray]:
    """Channel names (candump pads them with leading spaces when several interfaces are
    dumped) and each selected line's index into them."""
    if len(sel) == 0:
        return [], np.zeros(0, np.int16)
    start = cols["chan_start"][sel]
    clen = cols["chan_len"][sel]
    win = sliding_window_view(bp, _CHAN_WIDTH)[start]
    win = np.where(np.arange(_CHAN_WIDTH)[None, :] < clen[:, None], win, 0)
    same = (win == win[0]).all(axis=1)
    if same.all():
        return [bytes(win[0, :clen[0]]).decode("latin-1").strip()], np.zeros(len(sel), np.int16)
    uniq, inverse = np.unique(win, axis=0, return_inverse=True)
    names = [bytes(u).rstrip(b"\0").decode("latin-1").strip() for u in uniq]
    merged: list[str] = []
    remap = np.array([_index(merged, n) for n in names], np.int16)
    return merged, remap[inverse.ravel()]


def _index(names: list[str], name: str) -> int:
    if name not in names:
        names.append(name)
    return names.index(name)


def parse_line(line: bytes) -> tuple | None:
    """One candump line → ``(ts, can_id, flags, channel, dlc, payload)``; None for a blank line.

    Follows python-can's ``CanutilsLogReader`` (FD '##', remote 'R[dlc]', direction flag),
    plus can-utils' '_<dlc>' suffix for classic frames with a DLC code above 8.
    Raises ValueError naming what is wrong."""
    text = line.decode("ascii", errors="strict").strip() if line.isascii() else None
    if text is None:
        raise ValueError("non-ASCII bytes in the line")
    if not text:
        return None
    parts = text.split()
    flags = 0
    if len(parts) == 4 and parts[3].lower() in ("r", "t"):
        if parts[3].lower() == "t":
            flags |= TX
        parts = parts[:3]
    if len(parts) != 3:
        raise ValueError(f"expected '(timestamp) channel id#data', got {text[:60]!r}")
    stamp, channel, frame = parts
    if not (stamp.startswith("(") and stamp.endswith(")")):
        raise ValueError(f"timestamp {stamp[:30]!r} is not in parentheses")
    try:
        ts = float(stamp[1:-1])
    except ValueError:
        raise ValueError(f"timestamp {stamp[:30]!r} is not a number") from None
    id_text, sep, data = frame.partition("#")
    if not sep or not 1 <= len(id_text) <= 8:
        raise ValueError(f"frame {frame[:40]!r} is not 'ID#DATA'")
    try:
        ident = int(id_text, 16)
    except ValueError:
        raise ValueError(f"id {id_text!r} is not hexadecimal") from None
    if len(id_text) > 3:
        flags |= EXTENDED
        if ident & CAN_ERR_FLAG:
            flags |= ERROR
    if data.startswith("#"):
        if len(data) < 2 or data[1] not in "0123456789ABCDEFabcdef":
            raise ValueError(f"CAN FD frame {frame[:40]!r} lacks its flags digit")
        fd_flags = int(data[1], 16)          # CANFD_BRS 1, CANFD_ESI 2 (linux/can.h)
        flags |= FD | BRS * bool(fd_flags & 1) | ESI * bool(fd_flags & 2)
        data = data[2:]
    payload = b""
    if data[:1] in ("R", "r"):
        flags |= REMOTE
        dlc = int(data[1:], 16) if len(data) > 1 and data[1:].isalnum() else 0
        if dlc > 8:
            raise ValueError(f"remote frame DLC {data[1:]!r} out of range")
    else:
        data, _, dlc_code = data.partition("_")
        if len(data) % 2:
            raise ValueError(f"data {data[:40]!r} has an odd number of hex digits")
        try:
            payload = bytes.fromhex(data)
        except ValueError:
            raise ValueError(f"data {data[:40]!r} is not hexadecimal") from None
        if len(payload) > (64 if flags & FD else 8):
            raise ValueError(f"{len(payload)} data bytes is too many for this frame type")
        if dlc_code and not (len(payload) == 8 and dlc_code in "9ABCDEFabcdef" and len(dlc_code) == 1):
            raise ValueError(f"DLC suffix _{dlc_code} is only valid after 8 data bytes")
        dlc = len(payload)
    return ts, ident & 0x1FFFFFFF, flags, channel, dlc, payload
