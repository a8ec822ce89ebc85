"""Runs INSIDE user-mode Linux (see tests/test_vcan_uml.py): the emulator and the gateway over
real SocketCAN ``vcan0`` in lockstep, while can-utils' ``candump -L vcan0`` — a peer we did not
write — captures each run. Writes everything under the output directory given as argv[1]; the
host-side test does the checking.
"""
from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

from gateway import Gateway, GatewayConfig, SafetyLimits
from gateway.experiments import EXPERIMENTS
from core.durable import write_json
from devices import load_device_set
from gateway.runs import TRUTH_FILE
from plant.config import load_plant_config
from plant_emulator.process import EmulatorProcess

BUS = "socketcan:vcan0"
ROOT = Path(__file__).resolve().parents[1]
TRUTH = {"g": 120.0, "tau": 0.05, "delta": 8.0}


def experiments():
    return {"meander": EXPERIMENTS["meander"](amplitude_pct=5.0, period_s=2.0, cycles=2),
            "relay": EXPERIMENTS["relay"](amplitude_pct=10.0, reference_kgf=0.0, duration_s=3.0)}


def main(out: Path) -> int:
    out.mkdir(parents=True, exist_ok=True)
    config = load_plant_config(None, "base", TRUTH)
    done = {}
    # heartbeats and SDO answers are wall-clock; inside UML (one slow CPU) allow them more slack
    gw_config = GatewayConfig(bus=BUS, lockstep=True, sdo_timeout_s=3.0,
                              limits=SafetyLimits(heartbeat_timeout_s=3.0))
    with EmulatorProcess(BUS, config, lockstep=True, seed=4, ready_timeout_s=120):
        with Gateway(gw_config) as gw:
            for name, experiment in experiments().items():
                done[name] = run_with_candump(gw, name, experiment, out, config)
    # another maker's devices: node guarding (remote frames on real SocketCAN), static PDOs,
    # the force as REAL32 in kN (examples/devices/hydronix)
    devices = load_device_set(ROOT / "examples" / "devices" / "hydronix" / "devices.toml")
    with EmulatorProcess(BUS, config, lockstep=True, seed=4, ready_timeout_s=120, devices=devices):
        with Gateway(dataclasses.replace(gw_config, devices=devices)) as gw:
            meander = EXPERIMENTS["meander"](amplitude_pct=5.0, period_s=2.0, cycles=2)
            done["hydronix"] = run_with_candump(gw, "hydronix", meander, out, config)
    (out / "result.json").write_text(json.dumps(done, indent=2))
    return 0


def run_with_candump(gw: Gateway, name: str, experiment, out: Path, config) -> dict:
    """One run while can-utils' candump captures the bus."""
    capture = out / f"candump-{name}.log"
    with capture.open("w") as fh:
        dump = subprocess.Popen(["candump", "-L", "vcan0"], stdout=fh)
        time.sleep(0.5)  # candump is listening
        result = gw.run(experiment, out / name, progress=False)
        time.sleep(0.5)
        dump.send_signal(signal.SIGINT)
        dump.wait(10)
    write_json(result.path / TRUTH_FILE, config.to_dict())
    return {"run": str(result.path), "candump": str(capture), "status": result.status,
            "reason": result.reason, "cycles": result.outcome.stats.cycles}


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
