"""The paper's whole campaign in lockstep: stand time, wall time and the speed-up over a real bench.

A real bench runs the campaign in real time: its stand time. The emulator in lockstep (a separate
process, the real CANopen traffic on the loopback bus, every cycle recorded and captured) runs
it as fast as the bus allows. ``--quick``: the short plan of ``stand campaign --quick``.
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
import uuid

from gateway import Gateway, GatewayConfig
from gateway.campaign import CampaignPlan, run_campaign
from plant.config import load_plant_config
from plant_emulator.process import EmulatorProcess

from .table import Row, format_table

ORDER = 20


def measure(plan: CampaignPlan) -> dict:
    """Run ``plan`` against a lockstep emulator; stand and wall time of the campaign proper
    (without the emulator's start) and of everything."""
    bus = f"udp_loopback:bench-campaign-{os.getpid()}-{uuid.uuid4().hex[:6]}"
    config = load_plant_config()
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp, EmulatorProcess(bus, config, lockstep=True, seed=1):
        with Gateway(GatewayConfig(bus=bus, lockstep=True)) as gw:
            res = run_campaign(gw, plan, f"{tmp}/campaign", progress=False, truth=config.to_dict())
    return {"stand_s": res.stand_s, "wall_s": res.wall_s, "total_s": time.monotonic() - t0,
            "runs": len(res.runs), "cycles": sum(r.cycles for r in res.runs), "status": res.status}


def run(quick: bool) -> list[Row]:
    plan = CampaignPlan.quick() if quick else CampaignPlan.default()
    m = measure(plan)
    name = f"campaign ({'quick' if quick else 'default'} plan, lockstep emulator)"
    return [
        Row(name, f"{m['stand_s']:.0f} s stand time in {m['wall_s']:.0f} s wall",
            f"real bench: {m['stand_s']:.0f} s ({m['stand_s'] / 60:.1f} min) in real time",
            f"{m['stand_s'] / m['wall_s']:.1f}x real time",
            f"{m['runs']} runs, {m['cycles']:,} cycles ({m['cycles'] / m['wall_s']:,.0f}/s), "
            f"{m['total_s']:.0f} s with emulator start; {m['status']}"),
    ]


if __name__ == "__main__":
    print(format_table(run("--quick" in sys.argv[1:])))
