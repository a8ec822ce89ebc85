"""Other makers' devices end to end: the emulator impersonates each example device set as a
separate process on the loopback bus, the gateway configures it from the same device file, and
a run of it estimates the plant as a run of the emulated pair does. What a device refuses,
lacks or cannot be is one clear error, before anything moves."""
from __future__ import annotations

import json
import os
import re
import shutil
import uuid
from pathlib import Path

import numpy as np
import pytest

from analysis import estimate_meander, read_run
from captures.decode import decode_capture
from core.errors import NodeError
from devices import load_device_set
from gateway import Gateway, GatewayConfig
from gateway.experiments import Meander
from gateway.runs import load_run
from plant_emulator.process import EmulatorProcess

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "devices"
SETS = (None, "servotek", "hydronix", "fluxa")

pytestmark = pytest.mark.e2e


def device_file(name: str | None) -> Path | None:
    return None if name is None else EXAMPLES / name / "devices.toml"


@pytest.fixture(scope="module")
def meander_runs(tmp_path_factory):
    """One meander run of each device set (the emulated pair first), emulated in lockstep with
    the same plant and noise seed."""
    out = {}
    root = tmp_path_factory.mktemp("device-runs")
    for name in SETS:
        devices = load_device_set(device_file(name)) if name else None
        bus = f"udp_loopback:t{os.getpid()}-dev-{uuid.uuid4().hex[:6]}"
        with EmulatorProcess(bus, None, lockstep=True, seed=3, devices=devices):
            with Gateway(GatewayConfig(bus=bus, lockstep=True, devices=devices)) as gw:
                out[name] = gw.run(Meander(5.0, 4.0, 5), root / (name or "default"), progress=False)
    return out


@pytest.mark.slow
def test_every_device_set_estimates_the_plant_as_the_emulated_pair_does(meander_runs):
    estimates = {name: estimate_meander(read_run(r.path)) for name, r in meander_runs.items()}
    base = estimates[None]
    for name, est in estimates.items():
        assert meander_runs[name].status == "complete", name
        assert est.g_ci[0] <= base.g <= est.g_ci[1] and base.g_ci[0] <= est.g <= base.g_ci[1], \
            f"{name}: g {est.g:.2f} {est.g_ci} against the emulated pair's {base.g:.2f} {base.g_ci}"
        assert abs(est.g - 120.0) < 3.0


@pytest.mark.slow
def test_a_run_says_which_devices_it_had_and_what_they_lack(meander_runs):
    meta = json.loads((meander_runs["hydronix"].path / "run.json").read_text())
    valve = meta["devices"]["valve"]
    assert valve["name"] == "Hydronix HV-2" and valve["error_control"] == "guarding"
    assert valve["configuration"]["pdos"][1] == {
        "pdo": "TPDO1", "cob_id": 0x181, "transmission_type": 1, "mapping": "static",
        "objects": ["0x6041"], "event_timer_ms": None}
    assert any("spool position is not recorded" in n for n in meta["device_notes"])
    spool = load_run(meander_runs["hydronix"].path).signals["spool"]
    assert np.isnan(spool).all()
    assert not np.isnan(load_run(meander_runs["fluxa"].path).signals["spool"]).any()


@pytest.mark.slow
@pytest.mark.parametrize("name", SETS)
def test_the_capture_begins_with_the_start_up_and_decodes_to_the_run(meander_runs, name):
    run = meander_runs[name].path
    meta = json.loads((run / "run.json").read_text())
    lines = (run / "capture.log").read_text().splitlines()
    startup = lines[:meta["startup"]["frames"]]
    assert re.search(r" 000#8101 T$", startup[0])                     # NMT reset of the valve
    assert any(" 701#00 R" in l for l in startup)                      # its boot-up
    assert any(re.search(r" 601#4018100100000000 T$", l) for l in startup)  # identity read
    assert (run / "stand.dbc").exists() == (name is not None)
    decoded = decode_capture(run / "capture.log")
    signals = decoded.signals[0]
    recorded = load_run(run).signals
    np.testing.assert_array_equal(signals["y"], recorded["y"])
    np.testing.assert_array_equal(signals["u"], recorded["u"])


def test_a_device_other_than_its_file_is_refused_naming_it(start_emulator, bus_spec):
    start_emulator(None, lockstep=True)                                  # the emulated pair
    devices = load_device_set(device_file("servotek"))
    with pytest.raises(NodeError) as err:
        with Gateway(GatewayConfig(bus=bus_spec, lockstep=True, devices=devices)):
            pass
    text = str(err.value)
    assert "node 1 is not the expected valve" in text and "Servotek SVD-40" in text
    assert "devices.toml [valve]" in text


def test_a_revision_outside_the_files_range_is_refused(start_emulator, bus_spec, tmp_path):
    shutil.copytree(EXAMPLES / "servotek", tmp_path / "s")
    path = tmp_path / "s" / "devices.toml"
    path.write_text(path.read_text().replace('revision = "2.0-2.9"', 'revision = "3.0-3.9"'))
    start_emulator(None, lockstep=True, extra_args=["--devices", str(device_file("servotek"))])
    with pytest.raises(NodeError, match=r"valve node 1 \(Servotek SVD-40, .*\): revision 2.3 is "
                                        r"outside the revisions 3.0-3.9"):
        with Gateway(GatewayConfig(bus=bus_spec, lockstep=True, devices=load_device_set(path))):
            pass


def test_a_mapping_the_device_refuses_is_named_with_its_abort_code(start_emulator, bus_spec, tmp_path):
    """The device's own EDS says its spool position cannot be mapped; the file the master
    has says it can: the device refuses the master's mapping, which says so and stops."""
    shutil.copytree(EXAMPLES / "servotek", tmp_path / "device")
    eds = tmp_path / "device" / "svd40.eds"
    text = eds.read_text()
    start = text.index("[6301sub1]")
    end = text.index("[6301sub2]")
    eds.write_text(text[:start] + text[start:end].replace("PDOMapping=1", "PDOMapping=0") + text[end:])
    start_emulator(None, lockstep=True, extra_args=["--devices", str(tmp_path / "device" / "devices.toml")])
    with pytest.raises(NodeError) as err:
        with Gateway(GatewayConfig(bus=bus_spec, lockstep=True,
                                   devices=load_device_set(device_file("servotek")))):
            pass
    text = str(err.value)
    assert "the device refused 0x1A01:02 = 0x63010110 (TPDO2 mapping entry 2: 0x6301:01)" in text
    assert "SDO abort 0x06040041" in text and "cannot map this object" in text


@pytest.mark.slow
def test_the_pdo_set_up_is_on_the_wire_as_wireshark_reads_it(meander_runs):
    """Wireshark's CANopen dissector (tshark) reads, in the capture's start-up, every SDO write
    of the PDO set-up the plan made, in its order, each one complete, none aborted."""
    from devices import plan_node
    from tests.support.wire_check import check_captures, tshark_missing_reason
    reason = tshark_missing_reason()
    if reason:
        pytest.skip(reason)
    run = meander_runs["servotek"].path
    figures = check_captures([run / "capture.log"])[0]
    assert figures.malformed == 0 and not figures.sdo_aborted and not figures.sdo_open
    devices = load_device_set(device_file("servotek"))
    for device, node in ((devices.valve, 1), (devices.dynamometer, 2)):
        plan = plan_node(device, node, period_s=0.002, heartbeat_ms=100,
                         rpdo_timeout_ms=100 if device is devices.valve else 0)
        wanted = [(w.index, w.sub) for w in plan.writes() if 0x1400 <= w.index <= 0x1BFF]
        seen = [(t.index, t.subindex) for t in figures.downloads(0x1400, 0x1BFF) if t.node == node]
        assert seen == wanted, (node, seen, wanted)
