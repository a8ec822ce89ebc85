"""The emulator's scheduled faults (``stand emulate --fault``, plant_emulator/scheduled_faults.py):
the form is checked before anything starts; on the real bus (the emulator its own process) a
spike at a stand time trips the gateway's force limit at that time, and a valve's heartbeat
silenced from a stand time trips the heartbeat consumer, the valve heartbeating again after."""
from __future__ import annotations

import re
import subprocess
import sys
import time

import numpy as np
import pytest

from gateway import Gateway, GatewayConfig, SafetyLimits, load_run
from plant.params import ModelError
from plant_emulator.scheduled_faults import FaultSchedule, ScheduledFault, parse_fault
from tests.support.faults import Const
from tests.support.stand import BASE, plant

NAMES = ["root", "inner", "stand"]


def test_a_fault_is_read_as_written_and_a_mistake_names_what_is_wrong():
    assert parse_fault("spike:inner:+6000@120", NAMES) == ScheduledFault("spike", 1, 120.0, value_kgf=6000.0)
    assert parse_fault(" heartbeat:stand@0.5+2 ", NAMES) == ScheduledFault("heartbeat", 2, 0.5, duration_s=2.0)
    for text, message in [("spike:root@1", "give the spike's size in kgf"),
                          ("spike:root:100@1+3", "a spike is one reading"),
                          ("heartbeat:root:5@1+3", "takes no value"),
                          ("heartbeat:root@1", "+D in s"),
                          ("heartbeat:root@1+0", "must last more than 0 s"),
                          ("spike:tip:100@1", "no channel 'tip'; the station has root, inner, stand"),
                          ("explode:root:1@1", "'explode' is not a fault"),
                          ("spike:root:0@1", "a spike of 0 kgf is none"),
                          ("spike:root:1@-2", "before the emulator started"),
                          ("spike:root:1@soon", "give the stand time T in s"),
                          ("root@1", "give it as spike:CHANNEL:KGF@T")]:
        with pytest.raises(ModelError, match=re.escape(message)):
            parse_fault(text, NAMES)


def test_each_fault_is_due_once_in_the_order_of_its_time():
    a, b = ScheduledFault("spike", 0, 2.0, 5.0), ScheduledFault("heartbeat", 1, 1.0, duration_s=1.0)
    s = FaultSchedule([a, b])
    assert s.due(0.999) == [] and s.due(1.0) == [b] and s.due(1.5) == [] and s.due(9.0) == [a] and s.due(99) == []


def test_the_command_line_refuses_a_fault_before_any_bus_opens():
    res = subprocess.run([sys.executable, "-m", "stand", "emulate", "--bus", "udp_loopback:never-opened",
                          "--fault", "spike:root:100@1"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "--fault 'spike:root:100@1': no channel 'root'; the station has stand" in res.stderr


@pytest.mark.e2e
def test_a_spike_at_a_stand_time_trips_the_force_limit_then(bus_spec, start_emulator, tmp_path):
    emu = start_emulator(plant(BASE, model="base"), lockstep=True, seed=2,
                         extra_args=["--fault", "spike:stand:3000@1.0"])
    assert "fault: stand's dynamometer reads +3000 kgf once at 1 s of stand time" in "\n".join(emu.output)
    with Gateway(GatewayConfig(bus=bus_spec, lockstep=True, limits=SafetyLimits(force_limit_kgf=2000.0))) as gw:
        result = gw.run(Const(1.0, 3.0), tmp_path / "run", progress=False)
    assert (result.status, result.reason) == ("stopped", "force_limit"), result.outcome.message
    run = load_run(result.path)
    over = np.flatnonzero(run.y > 2000.0)
    assert len(over) == 1 and run.y[over[0]] - run.y[over[0] - 1] > 2900     # one reading, +3000
    # the emulator counts its stand time from its first cycle; the run's first SYNC is a cycle
    # or two after it started answering
    assert 0.98 <= run.t[over[0]] <= 1.02, run.t[over[0]]


@pytest.mark.e2e
@pytest.mark.serial        # heartbeats are on the wall clock
def test_a_silenced_heartbeat_trips_the_heartbeat_consumer_and_comes_back(bus_spec, start_emulator, tmp_path):
    start_emulator(plant(BASE, model="base"), lockstep=True, seed=3, extra_args=["--fault", "heartbeat:stand@0.5+3"])
    with Gateway(GatewayConfig(bus=bus_spec, lockstep=True)) as gw:
        result = gw.run(Const(1.0, 60.0), tmp_path / "run", progress=False)
        assert (result.status, result.reason) == ("stopped", "heartbeat_lost"), result.outcome.message
        assert "valve" in result.outcome.message
        assert load_run(result.path).t[-1] >= 0.5
        time.sleep(3.5)                      # the silence is over: the valve heartbeats again
        again = gw.run(Const(1.0, 0.5), tmp_path / "again", progress=False, reset_faults=True)
    assert again.status == "complete", again.outcome.message
