"""Runs INSIDE user-mode Linux (see tests/test_vcan_uml.py): the example rig (4 channels,
neighbours coupled 30 %) on two real SocketCAN buses, ``vcan0`` and ``vcan1``: ``stand emulate
--rig`` and ``stand run meander --rig ... --channel root --lockstep``, each its own process, as a
user types them, while can-utils' ``candump -L vcan0 vcan1`` (a peer we did not write) captures
both buses. Writes everything under the output directory given as argv[1]; the host-side test
does the checking. With ``--fd`` (argv[2]) both buses are CAN FD (1 Mbit/s nominal, 5 Mbit/s
data; python-can's socketcan opened with ``fd=True``): the cyclic frames go as FD frames.
"""
from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

from plant_emulator.process import RigEmulatorProcess
from rig.config import load_rig_file
from rig.emulated import rig_truth
from rig.files import rig_to_toml

ROOT = Path(__file__).resolve().parents[1]
BUSES = {"can0": "socketcan:vcan0", "can1": "socketcan:vcan1"}
DRIVEN = "root"


def main(out: Path, fd: bool = False) -> int:
    out.mkdir(parents=True, exist_ok=True)
    example = load_rig_file(ROOT / "examples" / "rig.toml")
    if fd:
        buses = [dataclasses.replace(b, spec=BUSES[b.name] + ",fd=True", fd=True, data_bitrate=5_000_000)
                 for b in example.buses]
    else:
        buses = [dataclasses.replace(b, spec=BUSES[b.name]) for b in example.buses]
    rig = dataclasses.replace(example, buses=buses)
    path = out / "rig.toml"
    path.write_text(rig_to_toml(rig, header="the example rig on vcan0 and vcan1 (inside UML)", path=path))
    run = out / "run"
    capture = out / "candump.log"
    with RigEmulatorProcess(path, lockstep=True, seed=5, ready_timeout_s=180):
        with capture.open("w") as fh:
            dump = subprocess.Popen(["candump", "-L", "vcan0", "vcan1"], stdout=fh)
            time.sleep(0.5)        # candump is listening
            # heartbeats and SDO answers are wall-clock; inside UML (one slow CPU) allow them
            # more slack
            done = subprocess.run([sys.executable, "-m", "stand", "run", "meander", "--rig", str(path),
                                   "--channel", DRIVEN, "--lockstep", "--amplitude-pct", "5",
                                   "--period-s", "4", "--cycles", "3", "--heartbeat-timeout", "3000",
                                   "--sdo-timeout", "3000",
                                   "--out", str(run)], capture_output=True, text=True, timeout=900)
            time.sleep(0.5)
            dump.send_signal(signal.SIGINT)
            dump.wait(10)
    (run / "truth.json").write_text(json.dumps(rig_truth(rig)))   # as stand demo --rig writes it
    (out / "result.json").write_text(json.dumps({
        "run": str(run), "candump": str(capture), "rig": str(path), "driven": DRIVEN,
        "returncode": done.returncode, "stdout": done.stdout[-3000:], "stderr": done.stderr[-3000:]},
        indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]), "--fd" in sys.argv[2:]))
