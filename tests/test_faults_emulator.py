"""The emulated nodes' own protection (what a real CiA 408 valve / CiA 404 transducer does),
in-process on python-can's ``virtual`` bus: EMCY on over range and its recovery EMCY, the
acceptance filter, PDO length errors, and the RPDO timeout."""
from __future__ import annotations

import struct
import time
import uuid

import can
import pytest

from dbc import profile as P
from plant.params import ModelError
from plant_emulator import EmulatedStand, EmulatorOptions
from tests.support.stand import plant


class ScriptedForce(EmulatedStand):
    """The dynamometer reads a scripted force (the measure_force hook)."""

    readings: list[float] = []

    def measure_force(self):
        y = self.readings.pop(0) if self.readings else 0.0
        return y, abs(y) > 3000.0


@pytest.fixture
def emulator():
    channel = f"emu-{uuid.uuid4().hex[:8]}"
    started = []

    def start(klass=EmulatedStand, lockstep=True):
        bus = can.Bus(interface="virtual", channel=channel)
        stand = klass(bus, plant(), EmulatorOptions(lockstep=lockstep, seed=1))
        stand.start()
        master = can.Bus(interface="virtual", channel=channel)
        started.append((stand, bus, master))
        time.sleep(0.05)
        while master.recv(0) is not None:
            pass
        return stand, master

    yield start
    for stand, bus, master in started:
        stand.stop()
        bus.shutdown()
        master.shutdown()


def send(bus, can_id, data, **kw):
    bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=kw.pop("ext", False), **kw))


def collect(bus, seconds, until=None):
    """The frames received within ``seconds``, or up to and including the first for which
    ``until(frame)`` is true."""
    out, deadline = [], time.monotonic() + seconds
    while time.monotonic() < deadline:
        m = bus.recv(0.01)
        if m is not None:
            out.append(m)
            if until is not None and until(m):
                break
    return out


def emcy_codes(frames, node):
    return [struct.unpack_from("<H", bytes(f.data))[0] for f in frames if f.arbitration_id == 0x80 + node]


def test_over_range_emcy_once_and_recovery_emcy_when_it_clears(emulator):
    stand, master = emulator(ScriptedForce)
    stand.readings[:] = [100.0, 3500.0, 3600.0, 3700.0, 2000.0, 1000.0, 4000.0]
    send(master, 0x000, b"\x01\x00")                   # NMT start all
    time.sleep(0.05)
    frames = []
    for k in range(7):
        send(master, 0x080, bytes([k + 1]))
        frames += collect(master, 0.03)
    assert emcy_codes(frames, 2) == [P.EMCY_FORCE_OVER_RANGE, P.EMCY_NO_ERROR, P.EMCY_FORCE_OVER_RANGE]
    assert stand.dynamometer.over_range_events == 2
    # a reset with the force still beyond the range: signalled again as soon as it can be
    stand.readings[:] = [4000.0]
    send(master, 0x000, b"\x81\x02")
    time.sleep(0.05)
    send(master, 0x080, b"\x01")
    assert emcy_codes(collect(master, 0.1), 2) == [P.EMCY_FORCE_OVER_RANGE]


def test_malformed_nmt_and_sync_frames_are_ignored_and_counted(emulator):
    stand, master = emulator()
    send(master, 0x000, b"\x01\x00")
    time.sleep(0.05)
    assert stand.valve.operational
    syncs = stand._syncs
    send(master, 0x000, b"\x02\x00\x00")                # STOP with a wrong length
    send(master, 0x080, b"\x01\x02")                    # SYNC with 2 bytes
    send(master, 0x080, b"\x01", ext=True)              # extended id
    send(master, 0x080, b"", is_remote_frame=True)      # remote frame
    send(master, 0x601, b"\x40\x41\x60")                # SDO request, 3 bytes
    frames = collect(master, 0.1)
    assert stand.valve.operational and stand._syncs == syncs
    assert not [f for f in frames if f.arbitration_id in (0x181, 0x182, 0x581)]
    assert stand.frame_filter.wrong_dlc == 3 and stand.frame_filter.not_classic == 2
    send(master, 0x080, b"\x05")
    assert {f.arbitration_id for f in collect(master, 0.1)} >= {0x181, 0x182}, "a good SYNC still works"


def test_rpdo_with_a_wrong_length_is_reported_and_not_applied(emulator):
    stand, master = emulator()
    # The subject is the length error, not the watchdog: switch the RPDO event timer off
    # (0x1400:05 = 0, as a master would by SDO) so a loaded machine's slow 100 ms cannot add
    # an RPDO timeout EMCY to the frames collected below.
    send(master, 0x601, b"\x2b\x00\x14\x05\x00\x00\x00\x00")
    assert [bytes(f.data[:4]) for f in collect(master, 0.05) if f.arbitration_id == 0x581] == [b"\x60\x00\x14\x05"]
    send(master, 0x000, b"\x01\x01")
    send(master, 0x201, struct.pack("<Hh", int(P.CW_ACTIVE), 1000))
    time.sleep(0.05)
    assert stand.valve.state is P.ValveState.ACTIVE and stand.valve.setpoint_counts == 1000
    send(master, 0x201, b"\x0b\x00\xff\x7f\x00")         # HOLD + full command, 5 bytes
    frames = collect(master, 0.05)
    assert emcy_codes(frames, 1) == [0x8210]
    assert stand.valve.state is P.ValveState.ACTIVE and stand.valve.setpoint_counts == 1000
    assert stand.valve.rpdo_length_errors == 1


@pytest.mark.serial
def test_rpdo_timeout_from_operational_without_any_command(emulator):
    """A master that starts the node and dies before its first command: fault within the event
    timer (0x1400:05 = 100 ms from the EDS), EMCY 0x8250, zero flow."""
    stand, master = emulator(lockstep=False)
    t0 = time.monotonic()
    send(master, 0x000, b"\x01\x01")
    frames = collect(master, 0.3)
    codes = emcy_codes(frames, 1)
    assert codes == [P.EMCY_RPDO_TIMEOUT]
    assert stand.valve.state is P.ValveState.FAULT_HOLD and stand.valve.spool_command_percent() == 0.0
    emcy_time = next(f.timestamp for f in frames if f.arbitration_id == 0x81)
    assert 0.1 <= emcy_time - (time.time() - (time.monotonic() - t0)) <= 0.1 + 0.2
    # a reset-fault edge brings it back to DISABLED with the recovery EMCY
    # (looked at as soon as the recovery EMCY is in: 100 ms on, with no command since, the
    # watchdog faults the node again, which a slow machine's wait must not reach)
    send(master, 0x201, struct.pack("<Hh", int(P.ControlBit.RESET_FAULT), 0))
    frames = collect(master, 0.05, until=lambda f: f.arbitration_id == 0x81)
    assert stand.valve.state is P.ValveState.DISABLED
    assert emcy_codes(frames, 1) == [P.EMCY_NO_ERROR]


def test_in_lockstep_the_rpdo_timeout_counts_the_stands_time_not_the_wall_clock(emulator):
    """Lockstep: the stand's time moves one period (0x1006 = 2 ms) per SYNC, and the valve's
    RPDO timeout (100 ms) counts it. A host stall with no SYNC (0.3 s of wall clock here) is no
    fault, the stand did not move; SYNCs with a command each never fault; SYNCs without a
    command fault on the first SYNC that ends more than 100 ms of stand time after the last one
    (the 51st period), with EMCY 0x8250 and zero flow."""
    stand, master = emulator(lockstep=True)
    send(master, 0x000, b"\x01\x01")
    send(master, 0x201, struct.pack("<Hh", int(P.CW_ACTIVE), 1000))
    collect(master, 0.3)                                # no SYNC for 3x the timeout
    assert stand.valve.state is P.ValveState.ACTIVE and stand.valve.faults == 0
    for k in range(120):                                # 240 ms of stand time, a command each
        send(master, 0x080, b"")
        send(master, 0x201, struct.pack("<Hh", int(P.CW_ACTIVE), 1000))
    collect(master, 0.2)
    assert stand.valve.state is P.ValveState.ACTIVE and stand.valve.faults == 0
    syncs = stand._syncs
    for k in range(50):                                 # exactly 100 ms without a command
        send(master, 0x080, b"")
    frames = collect(master, 0.2)
    assert stand._syncs == syncs + 50
    assert stand.valve.state is P.ValveState.ACTIVE and not emcy_codes(frames, 1)
    send(master, 0x080, b"")                            # 102 ms
    frames = collect(master, 0.2, until=lambda f: f.arbitration_id == 0x81)
    assert emcy_codes(frames, 1) == [P.EMCY_RPDO_TIMEOUT]
    assert stand.valve.state is P.ValveState.FAULT_HOLD and stand.valve.spool_command_percent() == 0.0


def test_the_emulator_refuses_a_config_it_cannot_run():
    config = plant()
    config.initial_force_kgf = float("nan")
    with pytest.raises(ModelError, match="initial.force_kgf must be finite"):
        config.validate()


def test_a_state_change_is_announced_by_a_heartbeat_at_once(emulator):
    """With a 1 s heartbeat period the master would wait up to 1 s to see OPERATIONAL; the node
    sends one heartbeat right at the change (CANopenNode behaviour)."""
    stand, master = emulator()
    for node in (P.VALVE_NODE_ID, P.DYNAMOMETER_NODE_ID):   # heartbeat period 1000 ms by SDO
        send(master, 0x600 + node, bytes((0x2B, 0x17, 0x10, 0x00)) + struct.pack("<H", 1000) + bytes(2))
    collect(master, 0.1)
    send(master, 0x000, bytes((0x01, 0)))                   # NMT start all
    frames = collect(master, 0.15)
    beats = {f.arbitration_id - 0x700: f.data[0] for f in frames if 0x700 < f.arbitration_id < 0x780}
    assert beats == {P.VALVE_NODE_ID: 5, P.DYNAMOMETER_NODE_ID: 5}
    send(master, 0x000, bytes((0x01, 0)))                   # no change: no extra heartbeat
    assert not [f for f in collect(master, 0.15) if 0x700 < f.arbitration_id < 0x780]


def test_sdo_written_limits_reach_the_spool_at_the_next_command(emulator):
    """The valve reads its limits from a cache of the object dictionary: an SDO write must
    take effect, not the value cached before it."""
    stand, master = emulator()
    valve = stand.valve
    valve.state = P.ValveState.ACTIVE
    valve.setpoint_counts = P.percent_to_counts(50.0)
    assert stand.valve.spool_command_percent() == pytest.approx(50.0, abs=0.01)  # caches the limit
    limit = P.percent_to_counts(20.0)
    send(master, 0x600 + P.VALVE_NODE_ID,
         bytes((0x2B,)) + struct.pack("<HB", P.UPPER_LIMIT, 0) + struct.pack("<h", limit) + bytes(2))
    reply = [f for f in collect(master, 0.2) if f.arbitration_id == 0x580 + P.VALVE_NODE_ID]
    assert reply and reply[0].data[0] == 0x60, "the SDO write was refused"
    assert stand.valve.spool_command_percent() == pytest.approx(20.0, abs=0.01)
    assert stand.valve.limit_reached
