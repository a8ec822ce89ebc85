"""The wire read by a CANopen implementation no one here wrote: Wireshark's dissector (tshark).

Every capture (any format :mod:`captures` reads; each bus channel in it apart) is turned into
SocketCAN frames (:func:`captures.pcap.socketcan_frames`), each distinct frame goes once into
one pcap per call, and one ``tshark`` decodes them all with its CANopen dissector (``-d
can.subdissector,canopen``), printing chosen fields per frame (``-T fields``; the names are
checked by tshark itself, which refuses an unknown one). From those fields, not from our own
decoders, :func:`check_captures` counts:

* frames, malformed frames (``_ws.malformed``: the dissector ran out of bytes, e.g. an SDO
  shorter than 8 bytes) and expert infos of severity error or warning (``_ws.expert``);
* frames by CANopen function as the dissector classifies them (from the function code and node
  id it decoded): NMT, SYNC, EMCY, PDO, SDO, NMT error control (boot-up, heartbeat, guarding
  answer), LSS, TIME; and what it does not take: remote frames (a node-guarding request is
  one), error frames, 29-bit ids;
* SDO transfers on the default SDO channels (0x600+n requests, 0x580+n answers), followed
  through CiA 301's protocol from the command specifiers, toggle bits and "no more segments"
  flags tshark decoded: begun, completed, aborted (by whom, with the abort code), cut off, and
  any answer that fits no open transfer, toggle out of step or index that differs from its
  request. Block transfers are counted but not followed (neither side here uses them).

:func:`wire_problems` turns the figures into the list of what a test did not expect
(:class:`WireExpectation`): by default 0 malformed frames, 0 expert errors, every SDO transfer
complete, no abort, no protocol fault. tests/support/wire_plugin.py applies it to every
capture an end-to-end test leaves; ``@pytest.mark.wire(...)`` says what a test provokes instead.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from collections import Counter
from dataclasses import dataclass, field
from fnmatch import fnmatch
from pathlib import Path

import numpy as np

#: the fields asked of tshark, in this order (tshark 4.0's names: ``tshark -G fields``)
FIELDS = ("can.id", "can.len", "can.flags.xtd", "can.flags.rtr", "can.flags.err",
          "canopen.function_code", "canopen.node_id", "canopen.nmt_ctrl.cd", "canopen.em.err_code",
          "canopen.nmt_guard.state", "canopen.sdo.ccs", "canopen.sdo.scs", "canopen.sdo.e",
          "canopen.sdo.c", "canopen.sdo.toggle", "canopen.sdo.main_idx", "canopen.sdo.sub_idx",
          "canopen.sdo.abort_code", "_ws.malformed", "_ws.expert.severity", "_ws.expert.message")
_F = {name: i for i, name in enumerate(FIELDS)}
_SEP = "\x1f"                      #: between occurrences of one field (expert infos can be several)
PI_WARN, PI_ERROR = 0x00600000, 0x00800000     #: epan/proto.h severities
FUNCTIONS = ("NMT", "SYNC", "EMCY", "PDO", "SDO", "NMT error control", "LSS", "TIME")
NMT_COMMANDS = {1: "start", 2: "stop", 0x80: "enter pre-operational", 0x81: "reset node",
                0x82: "reset communication"}
NMT_STATES = {0: "boot-up", 4: "stopped", 5: "operational", 0x7F: "pre-operational"}
#: the SDO channels tshark decodes: its function codes for server → client and client → server
FC_SDO_TX, FC_SDO_RX = 0xB, 0xC


def tshark_path() -> str | None:
    return shutil.which("tshark")


def tshark_missing_reason() -> str | None:
    """Why the wire cannot be checked here, or None."""
    if tshark_path() is None:
        return "tshark not installed (bash scripts/setup as root installs Debian's tshark)"
    return None


@dataclass
class SdoTransfer:
    """One SDO transfer as the frames on the wire show it."""

    node: int
    direction: str              #: "download" (client writes), "upload" (client reads), "?" (a stray abort)
    index: int | None           #: None: the frame was too short to name it
    subindex: int | None
    first_frame: int            #: frame number in its capture (1-based, as Wireshark counts)
    mode: str = "?"             #: "expedited", "segmented", "block"
    outcome: str = "open"       #: "complete", "aborted", "open" (cut off: never finished)
    abort_code: int | None = None
    aborted_by: str | None = None   #: "client" or "server"
    abort_names: str | None = None  #: the object an abort frame names where it is not the transfer's
    segments: int = 0
    last_frame: int = 0
    # protocol state: what the next frame of this transfer must be
    _await: str = "initiate response"
    _toggle: int = 0
    _last: bool = False

    def __str__(self) -> str:
        what = (f"node {self.node} {self.direction} {_od(self.index, self.subindex)} "
                f"({self.mode}, frame {self.first_frame})")
        if self.outcome == "aborted":
            code = "?" if self.abort_code is None else f"0x{self.abort_code:08X}"   # ?: too short to hold one
            other = f" (the abort names {self.abort_names})" if self.abort_names else ""
            return f"{what}: aborted by the {self.aborted_by}, code {code}{other}"
        return f"{what}: {self.outcome}"


@dataclass
class WireFigures:
    """What tshark read in one bus channel of one capture."""

    capture: str
    channel: str
    frames: int = 0
    malformed: int = 0
    expert_errors: int = 0          #: of severity error, besides the "Malformed Packet" of each malformed frame
    expert_warnings: int = 0
    expert_messages: Counter = field(default_factory=Counter)   #: message → frames (errors, warnings)
    functions: Counter = field(default_factory=Counter)         #: FUNCTIONS and the non-CANopen kinds
    nmt_commands: Counter = field(default_factory=Counter)
    nmt_states: Counter = field(default_factory=Counter)        #: NMT error control: state → frames
    emcy_codes: Counter = field(default_factory=Counter)
    sdo: list[SdoTransfer] = field(default_factory=list)
    sdo_faults: list[str] = field(default_factory=list)         #: frames that break the SDO protocol
    first_malformed: list[str] = field(default_factory=list)    #: "frame N id 0x..." of the first few

    @property
    def sdo_complete(self) -> int:
        return sum(t.outcome == "complete" for t in self.sdo)

    @property
    def sdo_aborted(self) -> list[SdoTransfer]:
        return [t for t in self.sdo if t.outcome == "aborted"]

    @property
    def sdo_open(self) -> list[SdoTransfer]:
        return [t for t in self.sdo if t.outcome == "open"]

    def downloads(self, first: int, last: int) -> list[SdoTransfer]:
        """The completed downloads to objects ``first``..``last`` (e.g. 0x1400-0x1BFF: the PDO set-up)."""
        return [t for t in self.sdo if t.direction == "download" and t.outcome == "complete"
                and t.index is not None and first <= t.index <= last]

    def as_dict(self) -> dict:
        hex_or_none = lambda v, digits: "(none)" if v is None else f"0x{v:0{digits}X}"   # noqa: E731
        return {"capture": self.capture, "channel": self.channel, "frames": self.frames,
                "malformed": self.malformed, "expert_errors": self.expert_errors,
                "expert_warnings": self.expert_warnings, "expert_messages": dict(self.expert_messages),
                "functions": dict(self.functions), "nmt_commands": dict(self.nmt_commands),
                "nmt_states": dict(self.nmt_states),
                "emcy_codes": {hex_or_none(k, 4): v for k, v in self.emcy_codes.items()},
                "sdo_begun": len(self.sdo), "sdo_complete": self.sdo_complete,
                "sdo_expedited": sum(t.mode == "expedited" for t in self.sdo),
                "sdo_segmented": sum(t.mode == "segmented" for t in self.sdo),
                "sdo_aborted": [str(t) for t in self.sdo_aborted],
                "sdo_abort_codes": [hex_or_none(t.abort_code, 8) for t in self.sdo_aborted],
                "sdo_open": [str(t) for t in self.sdo_open], "sdo_faults": list(self.sdo_faults)}

    def summary(self) -> str:
        kinds = ", ".join(f"{k} {v}" for k, v in sorted(self.functions.items(), key=lambda kv: -kv[1]))
        return (f"{self.capture} [{self.channel}]: {self.frames} frames ({kinds}); "
                f"{self.malformed} malformed, {self.expert_errors} expert errors; SDO {len(self.sdo)} begun, "
                f"{self.sdo_complete} complete, {len(self.sdo_aborted)} aborted, {len(self.sdo_open)} cut off")


@dataclass(frozen=True)
class WireExpectation:
    """What a test provokes on the wire (the default: nothing).

    ``sdo_aborts``: the abort codes the test provokes (or ``"any"``); ``cut_off``: a process is
    killed, so an SDO transfer may be left open and the capture's last line be partial;
    ``malformed``: the test sends frames the dissector must call malformed (a wrong DLC);
    ``garbage``: another sender floods the bus with random frames on every id
    (``standbus.faults``), which make malformed frames, aborts and SDO frames out of step of
    their own: only that tshark reads every frame is checked; ``skip``: the captures are not
    checked at all, and why; ``only``: all this holds for the test's captures whose path ends
    so (a glob, e.g. ``"noisy/capture.log"``), the others are held to the default."""

    sdo_aborts: frozenset[int] | str = frozenset()
    cut_off: bool = False
    malformed: bool = False
    garbage: bool = False
    skip: str | None = None
    only: str | None = None

    def of(self, capture) -> "WireExpectation":
        """What is expected of ``capture`` (a path): this, or the default where ``only`` leaves it out."""
        if self.only is None or fnmatch(str(capture), f"*/{self.only}"):
            return self
        return WireExpectation()

    @classmethod
    def from_marker(cls, marker) -> "WireExpectation":
        if marker is None:
            return cls()
        if marker.args:
            raise TypeError("@pytest.mark.wire takes keywords only: sdo_aborts=, cut_off=, malformed=, "
                            "garbage=, skip=, only=")
        kw = dict(marker.kwargs)
        aborts = kw.pop("sdo_aborts", frozenset())
        if aborts != "any":
            aborts = frozenset(int(code) for code in aborts)
        return cls(sdo_aborts=aborts, **kw)


def wire_problems(figures: list[WireFigures], expect: WireExpectation = WireExpectation()) -> list[str]:
    """Everything in ``figures`` that ``expect`` does not allow, one line each."""
    out: list[str] = []
    if expect.garbage:
        return out
    for f in figures:
        where = f"{f.capture} [{f.channel}]"
        if f.malformed and not expect.malformed:
            out.append(f"{where}: {f.malformed} malformed frames ({'; '.join(f.first_malformed)})")
        if f.expert_errors:
            out.append(f"{where}: {f.expert_errors} expert errors: {dict(f.expert_messages)}")
        for t in f.sdo_aborted:
            if expect.sdo_aborts != "any" and t.abort_code not in expect.sdo_aborts:
                out.append(f"{where}: SDO {t}")
        if not expect.cut_off:
            out += [f"{where}: SDO {t} (never finished)" for t in f.sdo_open]
        out += [f"{where}: {fault}" for fault in f.sdo_faults]
    return out


# -- reading ----------------------------------------------------------------------------------

@dataclass
class _Segment:
    capture: str
    channel: str
    words: np.ndarray    #: its SocketCAN frames in order, each as 2 (classic) or 9 (CAN FD) 64-bit words


def check_captures(paths, on_damage: str = "stop", distinct: bool = True) -> list[WireFigures]:
    """Decode the captures at ``paths`` with tshark's CANopen dissector (one tshark for all):
    the figures of each bus channel of each capture, in order. A capture that cannot be read or
    is damaged raises :class:`captures.CaptureError` (``on_damage="skip"`` reads past damage).

    ``distinct``: tshark reads each distinct frame once (byte for byte: id word, length, flags,
    data) and its reading is given to every frame alike. Wireshark's SocketCAN and CANopen
    dissectors keep no state from frame to frame, so a frame's reading depends on its bytes
    alone (tests/test_wire_check.py compares with ``distinct=False``, every frame read); a
    stand's traffic repeats itself (SYNC counters, heartbeats, a held command), so tshark
    reads 5-15 times fewer frames."""
    from captures.pcap import CAN_MTU, CANFD_FDF, CANFD_MTU, FILE_HEADER
    tshark = tshark_path()
    if tshark is None:
        raise RuntimeError(tshark_missing_reason())
    segments = [_Segment(str(path), channel, words) for path in paths
                for channel, words in _channels(path, on_damage)]
    if not segments:
        return []
    width = max(s.words.shape[1] for s in segments)
    every = np.concatenate([np.pad(s.words, ((0, 0), (0, width - s.words.shape[1]))) for s in segments])
    keys, inverse = _distinct(every) if distinct else (every, np.arange(len(every)))
    rows: list[list[str]] = []
    if len(keys):
        raw = keys.view(np.uint8)
        size = np.where(raw[:, 5] & CANFD_FDF, CANFD_MTU, CAN_MTU).astype("<u4")
        head = np.zeros((len(keys), 4), "<u4")          # pcap record header: time 0, length
        head[:, 2] = head[:, 3] = size
        records = np.concatenate([head.view(np.uint8), raw], axis=1)
        keep = np.arange(records.shape[1])[None, :] < (16 + size)[:, None]
        with tempfile.TemporaryDirectory(prefix="wire-") as tmp:
            pcap = Path(tmp) / "frames.pcap"
            pcap.write_bytes(FILE_HEADER + records[keep].tobytes())
            rows = _tshark_rows(tshark, pcap, Path(tmp))
        if len(rows) != len(keys):
            raise RuntimeError(f"tshark printed {len(rows)} frames of the {len(keys)} written")
    readings = _Readings(rows)
    figures, first = [], 0
    for s in segments:
        figures.append(_figures(s, readings, inverse[first:first + len(s.words)]))
        first += len(s.words)
    return figures


def _distinct(words: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of ``words`` and, for each row, the index of its distinct row: by a
    64-bit hash of each row, checked (a collision falls back to comparing whole rows)."""
    h = np.zeros(len(words), np.uint64)
    for j in range(words.shape[1]):
        h = (h ^ words[:, j]) * np.uint64(0x9E3779B97F4A7C15)
        h ^= h >> np.uint64(29)
    _, first, inverse = np.unique(h, return_index=True, return_inverse=True)
    if np.array_equal(words[first][inverse], words):
        return words[first], inverse
    keys, inverse = np.unique(np.ascontiguousarray(words).view(np.dtype((np.void, 8 * words.shape[1]))).ravel(),
                              return_inverse=True)
    return keys.view("<u8").reshape(len(keys), words.shape[1]), inverse


def _channels(path, on_damage: str):
    """(channel, frames as 64-bit words) of each bus channel in the capture at ``path``."""
    from captures import CaptureDamaged, FrameChunk, capture_format, open_capture
    from captures.pcap import socketcan_frames
    reader = open_capture(path, on_damage=on_damage)
    per_channel: dict[str, list[FrameChunk]] = {}
    for chunk in reader:
        names = chunk.channels or [""]
        present = np.unique(chunk.channel)
        for i in present:
            part = chunk if len(present) == 1 else chunk.take(chunk.channel == i)
            per_channel.setdefault(names[i], []).append(part)
    if reader.stats.damage is not None:
        raise CaptureDamaged(reader.stats.damage)
    classes = capture_format(path) == "candump"
    for channel, chunks in per_channel.items():
        frames = socketcan_frames(FrameChunk.concat(chunks), classes)   # 16 or 72 bytes each
        yield channel, frames.view("<u8").reshape(len(frames), frames.dtype.itemsize // 8)


def _tshark_rows(tshark: str, pcap: Path, tmp: Path) -> list[list[str]]:
    args = [tshark, "-n", "-r", str(pcap), "-d", "can.subdissector,canopen", "-T", "fields",
            "-E", "separator=/t", "-E", "occurrence=a", "-E", f"aggregator={_SEP}"]
    for name in FIELDS:
        args += ["-e", name]
    # the user's Wireshark preferences (a decode-as, a disabled protocol) must not change the reading
    env = {**os.environ, "WIRESHARK_CONFIG_DIR": str(tmp)}
    res = subprocess.run(args, capture_output=True, text=True, env=env, timeout=600)
    if res.returncode != 0:
        raise RuntimeError(f"tshark failed (exit {res.returncode}): {res.stderr.strip()[-2000:]}")
    return [line.split("\t") for line in res.stdout.splitlines()]


def _int(text: str) -> int | None:
    text = text.split(_SEP)[0]
    if text == "":
        return None
    if text in ("True", "False"):
        return int(text == "True")
    return int(text, 0)


_KINDS = (*FUNCTIONS, "CANopen, unknown function", "remote", "error frame", "29-bit id", "not CANopen")


class _Readings:
    """tshark's reading of each distinct frame, as arrays over them."""

    def __init__(self, rows: list[list[str]]) -> None:
        self.rows = rows
        self.kind = np.array([_KINDS.index(_function(r)) for r in rows], np.int64)
        self.malformed = np.array([bool(r[_F["_ws.malformed"]]) for r in rows], bool)
        self.errors = np.zeros(len(rows), np.int64)
        self.warnings = np.zeros(len(rows), np.int64)
        self.messages: dict[int, list[str]] = {}
        for i, r in enumerate(rows):
            severities = [int(x) for x in r[_F["_ws.expert.severity"]].split(_SEP) if x]
            for severity, message in zip(severities, r[_F["_ws.expert.message"]].split(_SEP)):
                if severity >= PI_WARN and not message.startswith("Malformed Packet"):
                    self.errors[i] += severity >= PI_ERROR
                    self.warnings[i] += severity < PI_ERROR
                    self.messages.setdefault(i, []).append(message)


def _figures(seg: _Segment, readings: _Readings, inverse: np.ndarray) -> WireFigures:
    """The figures of one segment, whose frames are ``readings``' rows ``inverse``, in order."""
    f = WireFigures(seg.capture, seg.channel, frames=len(inverse))
    if not len(inverse):
        return f
    rows = readings.rows
    kinds = readings.kind[inverse]
    f.functions = Counter({_KINDS[k]: int(n) for k, n in enumerate(np.bincount(kinds, minlength=len(_KINDS))) if n})
    bad = np.flatnonzero(readings.malformed[inverse])
    f.malformed = len(bad)
    for i in bad[:3]:
        r = rows[inverse[i]]
        f.first_malformed.append(f"frame {i + 1} id 0x{_int(r[_F['can.id']]) or 0:X} DLC {r[_F['can.len']]}")
    f.expert_errors = int(readings.errors[inverse].sum())
    f.expert_warnings = int(readings.warnings[inverse].sum())
    for u, messages in readings.messages.items():
        n = int(np.count_nonzero(inverse == u))
        for message in messages:
            if n:
                f.expert_messages[message] += n
    for i in np.flatnonzero(kinds == _KINDS.index("NMT")):
        cs = _int(rows[inverse[i]][_F["canopen.nmt_ctrl.cd"]])     # None: too short to hold one
        f.nmt_commands["(none)" if cs is None else NMT_COMMANDS.get(cs, f"0x{cs:02X}")] += 1
    for i in np.flatnonzero(kinds == _KINDS.index("NMT error control")):
        st = _int(rows[inverse[i]][_F["canopen.nmt_guard.state"]])
        f.nmt_states["(none)" if st is None else NMT_STATES.get(st, f"0x{st:02X}")] += 1
    for i in np.flatnonzero(kinds == _KINDS.index("EMCY")):
        f.emcy_codes[_int(rows[inverse[i]][_F["canopen.em.err_code"]])] += 1
    sdo = _SdoFollower(f)
    for i in np.flatnonzero(kinds == _KINDS.index("SDO")):
        sdo.frame(int(i) + 1, rows[inverse[i]])
    return f


def _od(index: int | None, sub: int | None) -> str:
    """An object dictionary entry as CiA 301 writes it, ``0x1018:01`` (``?`` what a frame too
    short did not say)."""
    return ("?" if index is None else f"0x{index:04X}") + ":" + ("?" if sub is None else f"{sub:02X}")


def _function(row: list[str]) -> str:
    """The frame's CANopen function as the dissector classifies it (its function code and
    node id: canopen_detect_msg_type in packet-canopen.c), or what kind of frame it did not take."""
    fc = _int(row[_F["canopen.function_code"]])
    if fc is None:
        for name, kind in (("can.flags.err", "error frame"), ("can.flags.rtr", "remote"),
                           ("can.flags.xtd", "29-bit id")):
            if _int(row[_F[name]]):
                return kind
        return "not CANopen"
    node = _int(row[_F["canopen.node_id"]])
    if fc == 0:
        return "NMT"
    if fc == 1:
        return "SYNC" if node == 0 else "EMCY"
    if fc == 2:
        return "TIME"
    if 3 <= fc <= 10:
        return "PDO"
    if fc in (FC_SDO_TX, FC_SDO_RX):
        return "SDO"
    if fc == 0xE:
        return "NMT error control"
    if fc == 0xF and node in (0x64, 0x65):
        return "LSS"
    return "CANopen, unknown function"


class _SdoFollower:
    """CiA 301's SDO protocol (expedited and segmented) per node, from tshark's fields."""

    def __init__(self, figures: WireFigures) -> None:
        self.f = figures
        self.open: dict[int, SdoTransfer] = {}

    def frame(self, frame: int, row: list[str]) -> None:
        fc, node = _int(row[_F["canopen.function_code"]]), _int(row[_F["canopen.node_id"]])
        get = lambda name: _int(row[_F[name]])       # noqa: E731
        index, sub = get("canopen.sdo.main_idx"), get("canopen.sdo.sub_idx")
        t = self.open.get(node)
        if fc == FC_SDO_RX:
            ccs = get("canopen.sdo.ccs")
            if ccs in (1, 2, 5, 6):          # initiate download / upload, block upload / download
                if t is not None:
                    self.fault(frame, f"node {node}: a new transfer begins while {t} is open")
                    self.close(t, frame, "open")
                direction = "download" if ccs in (1, 6) else "upload"
                t = SdoTransfer(node, direction, index, sub, frame)
                if ccs == 1:
                    t.mode = "expedited" if get("canopen.sdo.e") else "segmented"
                elif ccs in (5, 6):
                    t.mode = "block"
                self.f.sdo.append(t)
                self.open[node] = t
            elif ccs == 4:
                self.abort(node, t, frame, index, sub, get("canopen.sdo.abort_code"), "client")
            elif ccs == 0 and self.expect(t, frame, node, "download", "segment"):
                self.check_toggle(t, frame, get("canopen.sdo.toggle"))
                t._last, t._await = bool(get("canopen.sdo.c")), "segment response"
                t.segments += 1
            elif ccs == 3 and self.expect(t, frame, node, "upload", "segment"):
                self.check_toggle(t, frame, get("canopen.sdo.toggle"))
                t._await = "segment response"
        elif fc == FC_SDO_TX:
            scs = get("canopen.sdo.scs")
            if scs == 4:
                self.abort(node, t, frame, index, sub, get("canopen.sdo.abort_code"), "server")
            elif scs in (2, 3) and self.expect(t, frame, node, "upload" if scs == 2 else "download",
                                               "initiate response"):
                if (index, sub) != (t.index, t.subindex):
                    self.fault(frame, f"node {node}: the answer names {_od(index, sub)}, "
                                      f"the request {_od(t.index, t.subindex)}")
                if scs == 2:
                    t.mode = "expedited" if get("canopen.sdo.e") else "segmented"
                if t.mode == "expedited":
                    self.close(t, frame, "complete")
                else:
                    t._await, t._toggle = "segment", 0
            elif scs == 1 and self.expect(t, frame, node, "download", "segment response"):
                self.check_toggle(t, frame, get("canopen.sdo.toggle"), flip=True)
                if t._last:
                    self.close(t, frame, "complete")
                else:
                    t._await = "segment"
            elif scs == 0 and self.expect(t, frame, node, "upload", "segment response"):
                self.check_toggle(t, frame, get("canopen.sdo.toggle"), flip=True)
                t.segments += 1
                if get("canopen.sdo.c"):
                    self.close(t, frame, "complete")
                else:
                    t._await = "segment"
            elif scs in (5, 6) and t is not None and t.mode == "block":
                pass                          # block transfers are counted, not followed
            elif scs not in (0, 1, 2, 3):
                self.fault(frame, f"node {node}: SDO answer with command specifier {scs}")

    def expect(self, t: SdoTransfer | None, frame: int, node: int, direction: str, step: str) -> bool:
        if t is None or t.direction != direction or t._await != step:
            now = "no transfer open" if t is None else f"{t} waits for its {t._await}"
            self.fault(frame, f"node {node}: an SDO {direction} {step} fits no open transfer ({now})")
            return False
        return True

    def check_toggle(self, t: SdoTransfer, frame: int, toggle: int | None, flip: bool = False) -> None:
        if toggle != t._toggle:
            self.fault(frame, f"node {t.node}: toggle bit {toggle}, expected {t._toggle} ({t})")
        if flip:
            t._toggle ^= 1

    def abort(self, node, t, frame, index, sub, code, by) -> None:
        if t is None:                         # an abort of nothing open: still an abort on the wire
            t = SdoTransfer(node, "?", index, sub, frame)
            self.f.sdo.append(t)
        elif (index, sub) != (t.index, t.subindex):
            # CiA 301 has the abort name the transfer's object; python canopen's client names 0000:00
            t.abort_names = _od(index, sub)
        t.abort_code, t.aborted_by = code, by
        self.close(t, frame, "aborted")

    def close(self, t: SdoTransfer, frame: int, outcome: str) -> None:
        t.outcome, t.last_frame = outcome, frame
        if self.open.get(t.node) is t:
            del self.open[t.node]

    def fault(self, frame: int, text: str) -> None:
        self.f.sdo_faults.append(f"frame {frame}: {text}")
