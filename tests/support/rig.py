"""A rig for tests: the example rig on private loopback buses, and a minimal CANopen master
that drives an emulated rig frame by frame (NMT, SDO, SYNC, RPDOs; TPDOs and EMCYs read back).

The rig's gateway is written apart (branch rig-gateway); this master is only as much CANopen as
the emulator's tests need, from python-can and canopen directly.
"""
from __future__ import annotations

import struct
import time
from dataclasses import dataclass
from pathlib import Path

import can
import canopen

from dbc import profile as P
from rig.config import RigConfig, load_rig_file
from standbus import open_bus

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE_RIG = ROOT / "examples" / "rig.toml"
#: kgf per count of the dynamometer's process value (0.1 N, the EDS default)
FORCE_KGF_PER_COUNT = P.force_scale_kgf(P.UNIT_N_DEFAULT, 1)
VALVE_TPDO = struct.Struct("<Hh")        # status word 0x6041, actual spool 0x6301:01
FORCE_TPDO = struct.Struct("<iB")        # process value 0x9130:01 (0.1 N), AI status 0x6150:01
VALVE_RPDO = struct.Struct("<Hh")        # control word 0x6040, setpoint 0x6300:01


def example_rig_text(channel: str, quiet: bool = False) -> str:
    """``examples/rig.toml`` on the private loopback channels ``{channel}-can0``/``-can1``;
    ``quiet``: the dynamometers without noise and quantization (readings are the forces to
    0.1 N)."""
    text = EXAMPLE_RIG.read_text().replace("udp_loopback:rig-", f"udp_loopback:{channel}-")
    if quiet:
        for noise in ("noise_kgf = 2.0", "noise_kgf = 1.5"):
            text = text.replace(noise, "noise_kgf = 0.0\nresolution_kgf = 0.0")
    return text


def with_spare_bus(text: str, channel: str) -> str:
    """The rig ``text`` with one more bus, ``spare``, that carries no channel."""
    head, sep, rest = text.partition("[[channel]]")
    return (head + f'[[bus]]\nname = "spare"\nspec = "udp_loopback:{channel}-spare"\n\n'
            + sep + rest)


def write_rig(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@dataclass(frozen=True)
class Answer:
    """One channel's answer to a cycle's SYNC: the valve's and the dynamometer's TPDOs."""

    status: int                 #: the valve's status word 0x6041
    spool_pct: float            #: the valve's actual spool 0x6301:01, %
    force_kgf: float            #: the dynamometer's process value, kgf
    ai_status: int              #: the dynamometer's AI status

    @property
    def valve_state(self) -> P.ValveState:
        return P.ValveState(self.status & 0x0F)


class RigMaster:
    """A minimal master of every bus of a rig: one canopen network per bus (SDO), raw frames
    for NMT, SYNC and the valves' RPDOs, and every received frame in a buffer per bus."""

    def __init__(self, rig: RigConfig | Path | str) -> None:
        self.rig = rig if isinstance(rig, RigConfig) else load_rig_file(rig)
        self.networks: dict[str, canopen.Network] = {}
        self.readers: dict[str, can.BufferedReader] = {}
        #: (bus, node id, EMCY code) of every EMCY seen, in order
        self.emcys: list[tuple[str, int, int]] = []
        #: (bus, node id, first byte) of every heartbeat / boot-up seen
        self.heartbeats: list[tuple[str, int, int]] = []

    def __enter__(self) -> "RigMaster":
        for b in self.rig.buses:
            network = canopen.Network(open_bus(b.spec))
            reader = can.BufferedReader()
            network.listeners.append(reader)
            network.connect()
            self.networks[b.name] = network
            self.readers[b.name] = reader
        return self

    def __exit__(self, *exc) -> None:
        for network in self.networks.values():
            network.disconnect()

    # -- NMT and SDO -----------------------------------------------------------------------------
    def send(self, bus: str, can_id: int, data: bytes) -> None:
        self.networks[bus].send_message(can_id, data)

    def nmt_all(self, command: int) -> None:
        for bus in self.networks:
            self.send(bus, P.NMT_COB_ID, bytes((command, 0)))

    def reset_and_collect_boot_ups(self, wait_s: float = 1.0) -> dict[str, set[int]]:
        """NMT reset node to all on every bus; the node ids whose boot-up came, per bus."""
        self.drain()
        self.heartbeats.clear()
        self.nmt_all(P.NMT_RESET_NODE)
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:
            self.drain(0.02)
        return {bus: {nid for b, nid, state in self.heartbeats if b == bus and state == 0}
                for bus in self.networks}

    def sdo_upload(self, bus: str, node_id: int, index: int, sub: int,
                   timeout_s: float = 0.5) -> bytes:
        node = self.networks[bus].nodes.get(node_id)
        if node is None:
            node = self.networks[bus].add_node(canopen.RemoteNode(node_id, canopen.ObjectDictionary()))
        node.sdo.RESPONSE_TIMEOUT = timeout_s
        return node.sdo.upload(index, sub)

    def sdo_download_u32(self, bus: str, node_id: int, index: int, sub: int, value: int) -> None:
        node = self.networks[bus].nodes.get(node_id)
        if node is None:
            node = self.networks[bus].add_node(canopen.RemoteNode(node_id, canopen.ObjectDictionary()))
        node.sdo.download(index, sub, struct.pack("<I", value))

    def identity(self, bus: str, node_id: int) -> tuple[int, int]:
        """(vendor, product) of 0x1018 read over SDO."""
        vendor, product = (struct.unpack("<I", self.sdo_upload(bus, node_id, P.IDENTITY, s))[0]
                           for s in (1, 2))
        return vendor, product

    def start(self, period_s: float = 0.002) -> None:
        """Write the cycle period to every node, NMT start every bus, then a hold command to
        every valve (as a master does before its loop)."""
        for c in self.rig.channels:
            for nid in (c.valve_id, c.dynamometer_id):
                self.sdo_download_u32(c.bus, nid, P.COMM_CYCLE_PERIOD, 0, round(period_s * 1e6))
        self.nmt_all(P.NMT_START)
        time.sleep(0.05)
        self.command({c.name: 0.0 for c in self.rig.channels}, P.CW_HOLD)
        self.drain(0.05)

    # -- the cycle -------------------------------------------------------------------------------
    def sync(self, buses: list[str] | None = None) -> None:
        """A SYNC on each of ``buses`` (default: every bus with a channel), back to back."""
        for bus in buses or [b.name for b in self.rig.buses if self.rig.channels_on(b.name)]:
            self.send(bus, P.SYNC_COB_ID, b"")

    def command(self, commands_pct: dict[str, float], control_word: int = P.CW_ACTIVE) -> None:
        """One RPDO to each named channel's valve: ``control_word`` and the setpoint."""
        for c in self.rig.channels:
            if c.name in commands_pct:
                self.send(c.bus, P.RPDO_BASES[0] + c.valve_id,
                          VALVE_RPDO.pack(int(control_word), P.percent_to_counts(commands_pct[c.name])))

    def answers(self, timeout_s: float = 2.0, buses: list[str] | None = None) -> dict[str, Answer]:
        """Every channel's (on ``buses``, default all) two TPDOs of one cycle; the channels
        missing at the timeout are left out."""
        want = [c for c in self.rig.channels if buses is None or c.bus in buses]
        got: dict[tuple[str, int], bytes] = {}
        needed = {(c.bus, P.TPDO_BASES[0] + nid) for c in want for nid in (c.valve_id, c.dynamometer_id)}
        deadline = time.monotonic() + timeout_s
        while not needed <= set(got) and time.monotonic() < deadline:
            for bus, frame in self._frames(0.005):
                if P.TPDO_BASES[0] < frame.arbitration_id < P.TPDO_BASES[0] + 0x80:
                    got[bus, frame.arbitration_id] = bytes(frame.data)
        out = {}
        for c in want:
            v, f = got.get((c.bus, 0x180 + c.valve_id)), got.get((c.bus, 0x180 + c.dynamometer_id))
            if v is not None and f is not None:
                status, spool = VALVE_TPDO.unpack(v)
                counts, ai = FORCE_TPDO.unpack(f)
                out[c.name] = Answer(status, P.counts_to_percent(spool),
                                     counts * FORCE_KGF_PER_COUNT, ai)
        return out

    def cycle(self, commands_pct: dict[str, float], timeout_s: float = 2.0) -> dict[str, Answer]:
        """SYNC on every bus, back to back; every channel's answer; then the commands."""
        self.sync()
        out = self.answers(timeout_s)
        self.command(commands_pct)
        return out

    def drain(self, wait_s: float = 0.0) -> list[tuple[str, can.Message]]:
        """The frames received so far (waiting up to ``wait_s`` for the first), EMCYs and
        heartbeats noted."""
        return self._frames(wait_s)

    def _frames(self, wait_s: float) -> list[tuple[str, can.Message]]:
        out = []
        deadline = time.monotonic() + wait_s
        while True:
            for bus, reader in self.readers.items():
                while (m := reader.get_message(0)) is not None:
                    self._note(bus, m)
                    out.append((bus, m))
            if out or time.monotonic() >= deadline:
                return out
            time.sleep(0.0005)

    def _note(self, bus: str, m: can.Message) -> None:
        cid = m.arbitration_id
        if P.EMCY_BASE < cid < P.EMCY_BASE + 0x80 and len(m.data) == 8:
            self.emcys.append((bus, cid - P.EMCY_BASE, struct.unpack_from("<H", bytes(m.data))[0]))
        elif P.HEARTBEAT_BASE < cid < P.HEARTBEAT_BASE + 0x80 and len(m.data) == 1:
            self.heartbeats.append((bus, cid - P.HEARTBEAT_BASE, m.data[0]))
