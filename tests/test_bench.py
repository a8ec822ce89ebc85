"""Finding the devices of a bench and writing their configuration (``stand bench``): on an
emulated bus of six nodes of three makers, two of them fresh devices without a node id, the
scan lists every node, gives the fresh ones ids by LSS and writes a rig file that drives them;
each node's configuration written as a DCF is what the gateway sets."""
from __future__ import annotations

import re
from pathlib import Path

import canopen
import pytest

from devices import load_device_set, plan_node
from tests.support.cli import stand

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "devices"


def rig_text(channel: str) -> str:
    chans = [("a", 1, 2, None), ("b", 3, 4, "servotek"), ("c", 20, 21, "fluxa")]
    out = ['name = "bench of three"', "", "[[bus]]", 'name = "can0"',
           f'spec = "udp_loopback:{channel}-bench"']
    for name, v, d, devices in chans:
        out += ["", "[[channel]]", f'name = "{name}"', 'bus = "can0"', f"valve_id = {v}",
                f"dynamometer_id = {d}"]
        if devices:
            out.append(f'devices = "{EXAMPLES / devices / "devices.toml"}"')
        out += ["[channel.plant]", 'model = "base"']
    return "\n".join(out) + "\n"


@pytest.mark.e2e
def test_a_scan_finds_six_nodes_gives_two_fresh_ones_ids_and_drives_them(start_rig_emulator, channel,
                                                                        tmp_path):
    start_rig_emulator(rig_text(channel), lockstep=True, extra_args=["--unconfigured", "c"])
    skeleton = tmp_path / "bench.toml"
    res = stand("bench", "scan", "--bus", f"udp_loopback:{channel}-bench",
                "--devices", str(EXAMPLES / "servotek" / "devices.toml"),
                "--devices", str(EXAMPLES / "fluxa" / "devices.toml"), "--rig-out", str(skeleton))
    assert res.returncode == 0, res.stderr
    rows = [l for l in res.stdout.splitlines() if re.match(r"^\s+\d+  ", l)]
    assert [int(r.split()[0]) for r in rows] == [1, 2, 3, 4, 5, 6]
    fresh = [r for r in rows if "(node id given by LSS)" in r]
    assert len(fresh) == 2 and all("Fluxa FX-40" in r for r in fresh)
    assert "Servotek SVD-40 (valve)" in rows[2] and "CiA 408" in rows[2] and "2.3" in rows[2]
    assert "6 node(s), 2 given a node id by LSS" in res.stdout
    check = stand("rig", "check", str(skeleton))
    assert check.returncode == 0 and "problems: none" in check.stdout, check.stdout + check.stderr
    run = stand("run", "meander", "--rig", str(skeleton), "--channel", "ch3", "--lockstep",
                "--amplitude-pct", "5", "--period-s", "1", "--cycles", "1", "--out", str(tmp_path / "run"))
    assert run.returncode == 0, run.stderr


def test_each_nodes_dcf_is_the_configuration_the_gateway_sets(tmp_path):
    res = stand("bench", "dcf", "--devices", str(EXAMPLES / "hydronix" / "devices.toml"),
                "--valve-id", "7", "--dynamometer-id", "8", "--heartbeat-ms", "50", "-o", str(tmp_path))
    assert res.returncode == 0, res.stderr
    devices = load_device_set(EXAMPLES / "hydronix" / "devices.toml")
    for device, nid, name in ((devices.valve, 7, "stand-valve-7.dcf"),
                              (devices.dynamometer, 8, "stand-dynamometer-8.dcf")):
        od = canopen.import_od(str(tmp_path / name))
        assert od.node_id == nid and od.bitrate == 1_000_000
        plan = plan_node(device, nid, period_s=0.002, heartbeat_ms=50,
                         rpdo_timeout_ms=100 if device is devices.valve else 0)
        final = {}
        for w in plan.writes():
            final[w.index, w.sub] = w.value
        for (index, sub), value in final.items():
            obj = od[index]
            var = obj if isinstance(obj, canopen.objectdictionary.ODVariable) else obj[sub]
            assert var.value == value, f"0x{index:04X}:{sub:02X}"
        assert od[0x100C].value == 50
    assert (tmp_path / "stand.dbc").exists()
    assert "note: TPDO1's static mapping does not carry the actual spool position" in res.stdout
