"""The emulator impersonates any device file as CiA 301 says a device behaves: SDO aborts for
wrong accesses, a PDO's configuration refused where CiA 301 forbids it, PDOs silent outside
OPERATIONAL, EMCY with the error register on faults, node guarding with life guarding, and a
valve that takes the bus setpoint only in its device mode 1. In-process, on python-can's
``virtual`` bus, a canopen client as the master."""
from __future__ import annotations

import struct
import time
import uuid
from pathlib import Path

import can
import canopen
import pytest
from canopen.sdo import SdoAbortedError

from core.errors import NodeError
from devices import load_device_set
from gateway import Gateway, GatewayConfig
from gateway.experiments import Meander
from plant_emulator import EmulatedStand, EmulatorOptions
from standbus import open_bus
from tests.support.stand import plant

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "devices"


@pytest.fixture
def emulated():
    """``start(name)``: the example device set ``name`` emulated as a stand (valve 1,
    dynamometer 2); returns (stand, client network, raw bus of the master's side)."""
    made = []

    def start(name: str, lockstep: bool = True):
        channel = f"dev-{uuid.uuid4().hex[:8]}"
        devices = load_device_set(EXAMPLES / name / "devices.toml")
        bus = can.Bus(interface="virtual", channel=channel)
        stand = EmulatedStand(bus, plant(), EmulatorOptions(lockstep=lockstep, seed=1, devices=devices))
        stand.start()
        raw = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        net = canopen.Network(can.Bus(interface="virtual", channel=channel))
        net.connect()
        valve = net.add_node(1, str(devices.valve.eds))
        dyn = net.add_node(2, str(devices.dynamometer.eds))
        for node in (valve, dyn):
            node.sdo.RESPONSE_TIMEOUT = 1.0
        made.append((stand, bus, raw, net))
        time.sleep(0.05)
        while raw.recv(0) is not None:
            pass
        return stand, valve, dyn, raw

    yield start
    for stand, bus, raw, net in made:
        stand.stop()
        net.disconnect()
        raw.shutdown()
        bus.shutdown()


def abort_of(action) -> int:
    with pytest.raises(SdoAbortedError) as err:
        action()
    return err.value.code


def collect(bus, seconds: float) -> list[can.Message]:
    out, deadline = [], time.monotonic() + seconds
    while time.monotonic() < deadline:
        m = bus.recv(0.01)
        if m is not None:
            out.append(m)
    return out


def test_wrong_sdo_accesses_are_aborted_with_cia_301_codes(emulated):
    stand, valve, dyn, raw = emulated("fluxa")
    sdo = valve.sdo
    assert abort_of(lambda: sdo.upload(0x6999, 0)) == 0x06020000          # no such object
    assert abort_of(lambda: sdo.upload(0x6300, 9)) == 0x06090011          # no such sub-index
    assert abort_of(lambda: sdo.download(0x6041, 0, b"\x00\x00")) == 0x06010002   # read-only
    assert abort_of(lambda: sdo.upload(0x2000, 0)) == 0x06010001          # write-only
    assert abort_of(lambda: sdo.download(0x6040, 0, b"\x01\x00\x00\x00")) == 0x06070010  # length
    sdo.download(0x2000, 0, b"\x01")                                      # a write-only write: fine


def test_a_pdo_configuration_cia_301_forbids_is_refused(emulated):
    stand, valve, dyn, raw = emulated("fluxa")
    sdo = valve.sdo
    entry = lambda v: struct.pack("<I", v)                                  # noqa: E731
    sdo.download(0x1402, 1, entry(0x401))                                 # RPDO3 valid at 0x401
    assert abort_of(lambda: sdo.download(0x1402, 1, entry(0x402))) == 0x06090030  # id of a valid PDO
    assert abort_of(lambda: sdo.download(0x1402, 2, b"\xF5")) == 0x06090030       # reserved type 245
    sdo.download(0x1602, 0, b"\x00")
    assert abort_of(lambda: sdo.download(0x1602, 1, entry(0x60420008))) == 0x06040041  # not mappable
    assert abort_of(lambda: sdo.download(0x1602, 1, entry(0x60400020))) == 0x06040041  # wrong length
    assert abort_of(lambda: sdo.download(0x1602, 1, entry(0x60410010))) == 0x06040041  # ro, in an RPDO
    assert abort_of(lambda: sdo.download(0x1A03, 1, entry(0x65000110))) == 0x06020000  # no such object
    sdo.download(0x1602, 1, entry(0x63000110))
    sdo.download(0x1602, 0, b"\x01")
    assert abort_of(lambda: sdo.download(0x1602, 2, entry(0x60400010))) == 0x08000022  # count not 0
    assert int.from_bytes(sdo.upload(0x1602, 1), "little") == 0x63000110    # nothing refused was kept


def test_a_pdo_longer_than_64_bits_is_refused(emulated):
    stand, valve, dyn, raw = emulated("servotek")
    sdo = dyn.sdo
    sdo.download(0x1A02, 0, b"\x00")
    for sub in (1, 2, 3):
        sdo.download(0x1A02, sub, struct.pack("<I", 0x91300120))
    assert abort_of(lambda: sdo.download(0x1A02, 0, b"\x03")) == 0x06040042
    sdo.download(0x1A02, 0, b"\x02")


def test_a_static_mapping_cannot_be_written(emulated):
    stand, valve, dyn, raw = emulated("hydronix")
    assert abort_of(lambda: valve.sdo.download(0x1A00, 0, b"\x00")) == 0x06010002


def test_pdos_are_silent_outside_operational(emulated):
    stand, valve, dyn, raw = emulated("hydronix")
    raw.send(can.Message(arbitration_id=0x080, data=b"\x01", is_extended_id=False))
    quiet = collect(raw, 0.2)
    assert not [m for m in quiet if m.arbitration_id in (0x181, 0x282)]
    raw.send(can.Message(arbitration_id=0x000, data=b"\x01\x00", is_extended_id=False))
    time.sleep(0.05)
    raw.send(can.Message(arbitration_id=0x080, data=b"\x02", is_extended_id=False))
    answers = {m.arbitration_id: m for m in collect(raw, 0.3)}
    assert 0x181 in answers and 0x282 in answers
    assert len(answers[0x282].data) == 4                     # REAL32 in kN, static TPDO2
    assert 0x182 not in answers                              # TPDO1 (status) is event-driven, not on SYNC


def test_node_guarding_answers_with_a_toggle_and_life_guarding_makes_the_valve_safe(emulated):
    stand, valve, dyn, raw = emulated("hydronix")
    valve.sdo.download(0x100C, 0, struct.pack("<H", 50))
    valve.sdo.download(0x100D, 0, b"\x02")                    # life time 100 ms
    answers = []
    for _ in range(3):
        raw.send(can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1, is_extended_id=False))
        answers += [m for m in collect(raw, 0.04) if m.arbitration_id == 0x701]
    assert [m.data[0] for m in answers] == [0x7F, 0xFF, 0x7F]    # PRE-OPERATIONAL, toggling
    frames = collect(raw, 0.5)                                  # the master stops asking
    emcy = [m for m in frames if m.arbitration_id == 0x081]
    assert emcy and struct.unpack_from("<H", bytes(emcy[0].data))[0] == 0x8130
    assert emcy[0].data[2] & 0x01                               # the error register
    assert stand.valve.state.is_fault


def test_the_valve_takes_the_bus_setpoint_only_in_device_mode_1(emulated):
    stand, valve, dyn, raw = emulated("servotek")              # boots in device mode 2
    plan_rpdo = [(0x1401, 1, 0x80000301), (0x1601, 0, 0), (0x1601, 1, 0x60400010),
                 (0x1601, 2, 0x63000110), (0x1601, 0, 2), (0x1401, 1, 0x301)]
    for index, sub, value in plan_rpdo:
        size = 1 if (index, sub) == (0x1601, 0) else 4
        valve.sdo.download(index, sub, value.to_bytes(size, "little"))
    raw.send(can.Message(arbitration_id=0x000, data=b"\x01\x01", is_extended_id=False))
    time.sleep(0.05)
    command = struct.pack("<Hh", 7, 8192)                      # ACTIVE, 50 %
    raw.send(can.Message(arbitration_id=0x301, data=command, is_extended_id=False))
    time.sleep(0.05)
    assert stand.channel.command == 0.0                        # the analog input's mode: no bus setpoint
    valve.sdo.download(0x6042, 0, b"\x01")
    raw.send(can.Message(arbitration_id=0x301, data=struct.pack("<Hh", 7, 8190), is_extended_id=False))
    time.sleep(0.05)
    assert stand.channel.command == pytest.approx(8190 * 100 / 16384)


def test_an_rpdo_timeout_is_an_emcy_with_the_error_register_set(emulated):
    stand, valve, dyn, raw = emulated("fluxa", lockstep=False)
    for index, sub, value, size in [(0x1402, 1, 0x80000401, 4), (0x1402, 5, 50, 2), (0x1602, 0, 0, 1),
                                    (0x1602, 1, 0x60400010, 4), (0x1602, 2, 0x63000110, 4),
                                    (0x1602, 0, 2, 1), (0x1402, 1, 0x401, 4)]:
        valve.sdo.download(index, sub, value.to_bytes(size, "little"))
    raw.send(can.Message(arbitration_id=0x000, data=b"\x01\x01", is_extended_id=False))
    frames = collect(raw, 0.4)
    emcy = [m for m in frames if m.arbitration_id == 0x081]
    assert emcy, "no EMCY after the RPDO timeout"
    assert struct.unpack_from("<H", bytes(emcy[0].data))[0] == 0x8250 and emcy[0].data[2] & 0x01


def test_a_device_that_never_leaves_pre_operational_stops_the_run_before_anything_moves(tmp_path):
    """An amplifier that ignores the master's NMT start: the run is refused with the node, its
    device and what to look at; the valve never got an ACTIVE command."""
    devices = load_device_set(EXAMPLES / "servotek" / "devices.toml")
    spec = f"udp_loopback:preop-{uuid.uuid4().hex[:8]}"
    bus = open_bus(spec)
    stand = EmulatedStand(bus, plant(), EmulatorOptions(lockstep=True, seed=1, devices=devices))
    net, dyn = stand.network, stand.dynamometer
    net.unsubscribe(0, dyn._on_nmt)

    def stubborn(can_id, data, timestamp):
        if data[:1] != b"\x01":                  # every NMT command but start
            dyn._on_nmt(can_id, data, timestamp)
    net.subscribe(0, stubborn)
    stand.start()
    try:
        with Gateway(GatewayConfig(bus=spec, lockstep=True, devices=devices)) as gw:
            with pytest.raises(NodeError) as err:
                gw.run(Meander(5.0, 2.0, 1), tmp_path / "run", progress=False)
        text = str(err.value)
        assert "dynamometer node 2 (Servotek LCA-4, " in text and "devices.toml [dynamometer]" in text
        assert "did not report OPERATIONAL" in text and "PRE-OPERATIONAL" in text
        assert "look for its EMCY" in text
        assert stand.channel.command == 0.0 and stand.valve.state.name != "ACTIVE"
    finally:
        stand.stop()
        bus.shutdown()
