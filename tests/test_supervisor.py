"""The supervisor's detectors, actions, command shaping and controlled unload.

Frames reach the supervisor the way they do on a bus: through the network's acceptance filter
and the canopen stack (no bus needed: ``TappedNetwork(None)`` with the layouts from the EDS).
The controlled unload is checked against the plant model itself (known g, τ)."""
from __future__ import annotations

import struct
import time

import can
import numpy as np
import pytest

from dbc import profile as P
from gateway.capture import TappedNetwork
from gateway.errors import ParameterError
from gateway.master import StandMaster
from gateway.session import GatewayConfig
from gateway.supervisor import SafetyLimits, Supervisor, Unloader
from plant.model import PlantModel

T = 0.002
ACTIVE = P.ValveState.ACTIVE.value


def frame(can_id: int, data: bytes, **kw) -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False, **kw)


def emcy(node: int, code: int) -> can.Message:
    return frame(0x80 + node, struct.pack("<HB5s", code, 1, b""))


@pytest.fixture
def stand():
    """(network, master, make_supervisor) with both nodes alive and OPERATIONAL."""
    net = TappedNetwork(None)
    master = StandMaster(net, 1, 2)
    master.configure_from_eds()

    def beat(state: int = 5) -> None:
        for nid in (1, 2):
            net.frame_filter.on_message_received(frame(0x700 + nid, bytes([state])))

    def make(**limits) -> Supervisor:
        sup = Supervisor(master, SafetyLimits(**limits), T)
        beat()
        return sup
    make.beat = beat
    return net, master, make


# -- configuration ----------------------------------------------------------------------------------
@pytest.mark.parametrize("field, value", [
    ("force_limit_kgf", float("nan")), ("force_limit_kgf", float("inf")), ("force_limit_kgf", -5),
    ("command_limit_pct", 150), ("slew_pct_per_s", 0.0), ("error_limit_kgf", float("nan")),
    ("heartbeat_timeout_s", 0), ("stale_cycles", 0), ("stale_cycles", 2.5),
    ("overrun_limit_s", float("inf")), ("unload_rate_kgf_per_s", float("nan")),
    ("force_action", "explode"), ("error_action", None),
])
def test_bad_limits_are_refused_with_their_name(field, value):
    with pytest.raises(ParameterError, match=field):
        SafetyLimits(**{field: value}).validate()
    with pytest.raises(ParameterError, match=field):
        GatewayConfig(limits=SafetyLimits(**{field: value})).validate()


def test_heartbeat_timeout_must_exceed_the_producer_time():
    SafetyLimits().validate()
    with pytest.raises(ParameterError, match="must exceed the nodes' heartbeat period"):
        GatewayConfig(heartbeat_ms=500, limits=SafetyLimits(heartbeat_timeout_s=0.4)).validate()


# -- command shaping -----------------------------------------------------------------------------------
def test_command_is_clamped_rate_limited_and_never_nan(stand):
    _, _, make = stand
    sup = make(command_limit_pct=20.0, slew_pct_per_s=1000.0)    # 2 % per 2 ms cycle
    out = [sup.shape_command(u) for u in (50.0, 50.0, float("nan"), float("inf"), -float("inf"), -50.0)]
    assert out == pytest.approx([2.0, 4.0, 2.0, 0.0, 0.0, -2.0])
    assert sup.clamped == 6
    sup = make(command_limit_pct=20.0)
    assert [sup.shape_command(u) for u in (50.0, -50.0, 7.5, float("nan"))] == [20.0, -20.0, 7.5, 0.0]


# -- force limit and its actions ------------------------------------------------------------------------
@pytest.mark.parametrize("action", ["hold", "unload", "zero"])
def test_force_limit_trips_with_the_chosen_action(stand, action):
    _, _, make = stand
    sup = make(force_limit_kgf=1000.0, force_action=action)
    assert sup.check(999.0, False, ACTIVE, 100.0) is None
    trip = sup.check(-1000.5, False, ACTIVE, 100.002)
    assert (trip.reason, trip.action, trip.onset_wall, trip.bound_s) == ("force_limit", action, 100.002, T)
    assert "-1000 kgf beyond the limit ±1000" in trip.message
    assert sup.check(float("nan"), False, ACTIVE, 1.0).reason == "force_limit"


def test_indicate_logs_each_excursion_once_and_goes_on(stand):
    _, _, make = stand
    sup = make(force_limit_kgf=1000.0, force_action="indicate")
    ys = [900, 1001, 1100, 990, 960, 940, 1005, 1010]
    assert all(sup.check(y, False, ACTIVE, float(i)) is None for i, y in enumerate(ys))
    assert [(e["reason"], e["time"]) for e in sup.events] == [("force_limit", 1.0), ("force_limit", 6.0)]


def test_a_stale_reading_is_never_checked_against_the_limit(stand):
    _, _, make = stand
    sup = make(force_limit_kgf=1000.0)
    assert sup.check(5000.0, True, ACTIVE, 0.0) is None


# -- error detector ------------------------------------------------------------------------------------
def test_error_detector_needs_the_error_for_the_stated_time(stand):
    _, _, make = stand
    sup = make(error_limit_kgf=100.0, error_time_s=0.01)          # 5 cycles of 2 ms
    sup.reset()
    hits = [sup.check_error(500.0, 0.0, False, float(k)) for k in range(5)]
    assert hits[:4] == [None] * 4 and hits[4].reason == "error_limit"
    assert hits[4].onset_wall == 0.0 and hits[4].bound_s == pytest.approx(6 * T)
    sup.reset()
    for k in range(4):
        assert sup.check_error(500.0, 0.0, False, k) is None
    assert sup.check_error(50.0, 0.0, False, 4) is None, "a good cycle restarts the count"
    assert sup.check_error(500.0, 0.0, True, 5) is None, "stale cycles do not count"
    assert all(sup.check_error(float("nan"), 1e9, False, k) is None for k in range(20)), "no reference"
    assert make(error_limit_kgf=None).check_error(1e9, 0.0, False, 0) is None


def test_error_detector_with_indicate_and_unload(stand):
    _, _, make = stand
    sup = make(error_limit_kgf=100.0, error_time_s=0.0, error_action="indicate")
    assert sup.check_error(500.0, 0.0, False, 3.0) is None and len(sup.events) == 1
    assert sup.check_error(500.0, 0.0, False, 4.0) is None and len(sup.events) == 1
    sup = make(error_limit_kgf=100.0, error_time_s=0.0, error_action="unload")
    assert sup.check_error(-500.0, 0.0, False, 3.0).action == "unload"


# -- communication -------------------------------------------------------------------------------------
def test_stale_force_trips_after_n_cycles_from_the_first_stale_one(stand):
    _, _, make = stand
    sup = make(stale_cycles=5)
    assert sup.check(10.0, True, ACTIVE, 7.0) is None
    assert sup.check(10.0, False, ACTIVE, 7.002) is None            # fresh again: count restarts
    trips = [sup.check(10.0, True, ACTIVE, 8.0 + k * T) for k in range(5)]
    assert trips[:4] == [None] * 4
    assert trips[4].reason == "force_pdo_stale" and trips[4].onset_wall == 8.0
    assert trips[4].bound_s == pytest.approx(6 * T)


def test_emcy_only_from_configured_nodes_with_the_right_length(stand):
    net, _, make = stand
    sup = make()
    flt = net.frame_filter
    before = flt.counts()
    flt.on_message_received(emcy(5, 0x8250))                          # node 5 is not ours
    flt.on_message_received(frame(0x82, struct.pack("<HB", 0xFF10, 1)))   # 3 bytes
    flt.on_message_received(emcy(2, 0x0000))                          # error reset: no fault
    assert sup.check(0.0, False, ACTIVE, 0.0) is None
    after = flt.counts()
    assert after["unexpected_id"] - before["unexpected_id"] == 1
    assert after["wrong_dlc"] - before["wrong_dlc"] == 1
    flt.on_message_received(emcy(2, P.EMCY_FORCE_OVER_RANGE))
    trip = sup.check(0.0, False, ACTIVE, 0.0)
    assert trip.reason == "emcy" and "0xFF10 from dynamometer node 2" in trip.message
    assert [e["code"] for e in sup.emcy_log] == [0x0000, 0xFF10]
    sup.reset()
    assert sup.check(0.0, False, ACTIVE, 0.0) is None, "a new run starts without old EMCYs"


def test_heartbeat_loss_and_nmt_state(stand):
    net, master, make = stand
    sup = make(heartbeat_timeout_s=0.05)
    assert sup.check_nodes() is None
    net.frame_filter.on_message_received(frame(0x701, b"\x7f\x00"))   # wrong DLC: ignored
    assert sup.check_nodes() is None
    net.frame_filter.on_message_received(frame(0x701, b"\x7f"))       # PRE-OPERATIONAL
    trip = sup.check_nodes()
    assert trip.reason == "nmt_state" and "valve node 1 left OPERATIONAL" in trip.message
    make.beat()
    time.sleep(0.08)
    trip = sup.check(0.0, False, ACTIVE, 0.0)
    assert trip.reason == "heartbeat_lost" and "timeout 50 ms" in trip.message
    assert time.time() - trip.onset_wall >= 0.05
    assert trip.bound_s == pytest.approx(0.05 + T + sup.wait_s)


def test_valve_state_from_its_status_word(stand):
    _, _, make = stand
    sup = make(stale_cycles=3)
    fault = P.ValveState.FAULT_HOLD.value | P.STATUS_LIMIT_REACHED
    assert sup.check(0.0, False, fault, 1.0).reason == "valve_fault"
    assert sup.check(0.0, False, 0, 1.0) is None, "no status received yet"
    hold = P.ValveState.HOLD.value
    assert [sup.check(0.0, False, hold, 1.0) for _ in range(2)] == [None, None]
    assert sup.check(0.0, False, hold, 1.0).reason == "valve_not_active"


def test_overrun_beyond_the_limit(stand):
    _, _, make = stand
    sup = make(overrun_limit_s=0.05)
    assert sup.overrun(0.049, 5.0) is None
    trip = sup.overrun(0.2, 5.0)
    assert trip.reason == "overrun" and "200 ms late" in trip.message and trip.onset_wall == 5.0


# -- controlled unload against the plant model ----------------------------------------------------------
def unload_sim(y0: float, model: PlantModel, limits: SafetyLimits, noise: float = 2.0, seed: int = 0,
               flip: bool = False):
    """Closed loop with the gateway's timing: y[k] read at t_k, u[k] held over one period."""
    rng = np.random.default_rng(seed)
    sub = 4
    dt = T / sub
    state = model.new_state(1, dt, y0=y0)
    un = Unloader(y0, limits, T)
    ys, us, rs = [], [], []
    u = 0.0
    while not un.done and len(ys) < 100000:
        model.advance(state, np.full((1, sub), -u if flip else u), dt)
        y = float(state.y[0]) + rng.normal(0, noise)
        u, r = un.step(y)
        ys.append(y); us.append(u); rs.append(r)
    return un, np.array(ys), np.array(us), np.array(rs)


@pytest.mark.parametrize("g, y0", [(120.0, 2000.0), (120.0, -3000.0), (480.0, 2000.0), (40.0, 1500.0)])
def test_controlled_unload_brings_the_force_to_about_zero(g, y0):
    limits = SafetyLimits(force_limit_kgf=abs(y0))
    model = PlantModel.from_spec("base+reversal", {"g": g, "tau": 0.05, "delta": 8.0})
    un, y, u, r = unload_sim(y0, model, limits)
    assert un.outcome == "unloaded"
    assert abs(y[-1]) <= limits.unload_tolerance_kgf
    assert np.abs(u).max() <= limits.unload_max_pct
    ramp = abs(y0) / limits.unload_rate_kgf_per_s
    assert ramp <= un.t < ramp + 5.0 / (limits.unload_gain_pct_per_kgf * g) + 0.5
    # gentle: no overshoot through zero, no oscillation (one sign change of the command at most)
    assert (-np.sign(y0) * y).max() < 3 * limits.unload_tolerance_kgf
    assert np.count_nonzero(np.diff(np.sign(u[u != 0])) != 0) <= 1
    assert r[0] == y0 and r[-1] == 0.0


def test_unload_gives_up_when_the_force_keeps_rising():
    """A plant that answers the wrong way (sign error in the valve wiring): hold after the grace."""
    limits = SafetyLimits(force_limit_kgf=2000.0)
    model = PlantModel.from_spec("base", {"g": 120.0, "tau": 0.05, "delta": 0.0})
    un, y, _, _ = unload_sim(2000.0, model, limits, flip=True)
    assert un.outcome == "force_rising" and un.t <= Unloader.GRACE_S + 0.2
    assert y.max() - 2000.0 < 0.1 * limits.force_limit_kgf + 50


def test_unload_times_out():
    limits = SafetyLimits(force_limit_kgf=2000.0, unload_timeout_s=0.5)
    model = PlantModel.from_spec("base", {"g": 120.0, "tau": 0.05, "delta": 0.0})
    un, _, _, _ = unload_sim(2000.0, model, limits)
    assert un.outcome == "timeout" and un.t == pytest.approx(0.5, abs=2 * T)


def test_the_experiments_declared_maximum_is_enforced_too(stand):
    _, _, make = stand
    sup = make(command_limit_pct=50.0)
    sup.reset(max_command_pct=5.0)
    assert [sup.shape_command(u) for u in (4.0, 7.0, -9.0)] == [4.0, 5.0, -5.0]
    sup.reset(max_command_pct=float("nan"))          # a broken declaration falls back to the limit
    assert sup.shape_command(70.0) == 50.0
