"""Load cases right by the third pass on rigs whose one channel carries an effect the
compensation was not built around and the catalogue lacks (each a plug-in only the emulator
runs), through the documented workflow, each step its own ``stand`` command against ``stand
emulate --rig --lockstep`` with the plug-in:

campaign --rig (per column, at 5 and 15 %) → estimate --save → diagnose --rig-model --stepwise
--save (without the plug-in: the nearest catalogue law) → design → load --rig --repeat 3.

* wing root (tests/support/rig_wing_root.toml): the rib's check valve sends a pulse of extra
  flow 0.15-0.4 s after each reversal of its own rod (tests/support/check_valve.py): an action
  local in time. The rib reverses at load cases 4, 6 and 8 and passes its level at the next
  one, 0.3 s later, while the spars turn there (at 9 nobody turns).
* fuselage frame (tests/support/rig_frame.toml): a second load path engages above 2500 kgf on
  the frame (tests/support/contact.py): a gain that depends on the force level. The frame
  passes near 2500 kgf at load cases where the floor beams turn.

The figures (issue 50): pass 1 worst p95 within 1 % of range (the feedforward from the
diagnosis's model), pass 3 worst p95 within 0.5 % and max within 1 %, the load cases'
distribution within 1 % by pass 3 with no case worse than in pass 2, no extra cycle in any
pass; the report says them per pass."""
from __future__ import annotations

import csv
import io
import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

SUPPORT = Path(__file__).resolve().parent / "support"

WING_ROOT_CASES = """case,spar_l,spar_r,rib
1,1000,1500,800
2,4500,4000,3200
3,4100,3600,2800
4,4800,3900,1200
5,4400,4400,1600
6,5500,2000,4200
7,5100,2300,3800
8,5600,1500,1000
9,5200,1900,1400
10,2500,5000,3600
11,2900,4600,3200
12,1200,4200,700
13,1600,1800,1100
14,1600,2200,2600
15,4000,2600,2300
16,3600,3000,4000
17,1000,800,1000
"""
FRAME_CASES = """case,floor_l,floor_r,frame
1,1000,1200,800
2,4500,3800,2400
3,2200,1800,2600
4,5000,4300,4800
5,4600,4700,2500
6,5200,2500,1500
7,4800,2900,2300
8,1500,3300,2750
9,1900,2600,3000
10,1200,3200,2200
11,3500,4000,1900
12,3100,4400,2550
13,3100,1500,2900
14,5000,1900,1000
15,800,1000,600
"""


@dataclass(frozen=True)
class UnseenRig:
    """A rig of the test, and where its one channel's effect acts."""

    file: str                  #: the rig file in tests/support
    prefix: str                #: its loopback buses' prefix, moved to a test's own
    plugin: str                #: the effect, a plug-in in tests/support
    channel: str               #: the channel that carries it
    candidates: str            #: what the diagnosis tries
    cases: str                 #: the load cases (CSV)
    moments: tuple[str, ...]   #: load cases where the channel passes its level while another leads


WING_ROOT = UnseenRig("rig_wing_root.toml", "wroot-", "check_valve.py", "rib",
                      "reversal,travel_reversal,command_reversal,stiction,backlash", WING_ROOT_CASES,
                      ("5", "7", "9"))
FRAME = UnseenRig("rig_frame.toml", "frame-", "contact.py", "frame",
                  "reversal,stiffness,load_pressure,leakage,asymmetry", FRAME_CASES, ("3", "5", "8", "12"))


def stand(*args, timeout: float = 1200) -> str:
    done = subprocess.run([sys.executable, "-m", "stand", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)
    assert done.returncode == 0, f"stand {' '.join(map(str, args))}:\n{done.stderr}\n{done.stdout}"
    return done.stdout


def kinds_at(cases: str) -> dict[str, dict[str, str]]:
    """Each channel's kind of turning point at each load case of a CSV (peak, valley, rising,
    falling), as the programme tells them."""
    from loading.programme import from_load_cases
    rows = list(csv.DictReader(io.StringIO(cases)))
    names = [n for n in rows[0] if n != "case"]
    p = from_load_cases([[float(r[n]) for r in rows] for n in names], names, 0.002, rate_kgf_s=2500,
                        labels=[r["case"] for r in rows])
    return {n: dict(zip(p.case_labels, k)) for n, k in zip(names, p.kinds())}


def test_the_rigs_lead_other_channels_at_the_effects_moments():
    """The load cases are what the test says: at each moment the channel passes its level
    while another channel turns (or, at the wing root's case 9, nobody turns), right after
    the channel's own reversal on the wing root."""
    for rig in (WING_ROOT, FRAME):
        kinds = kinds_at(rig.cases)
        for case in rig.moments:
            assert kinds[rig.channel][case] in ("rising", "falling"), (rig.file, case)
        turning = [c for c in rig.moments if any(kinds[n][c] in ("peak", "valley") for n in kinds)]
        assert len(turning) >= len(rig.moments) - 1, rig.file
    wing = kinds_at(WING_ROOT.cases)
    assert [wing["rib"][str(int(c) - 1)] for c in WING_ROOT.moments] == ["valley", "peak", "valley"]


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.parametrize("rig", [WING_ROOT, FRAME], ids=["wing_root", "frame"])
def test_every_load_case_is_right_by_the_third_pass(rig, tmp_path, channel, start_rig_emulator):
    plugin = SUPPORT / rig.plugin
    text = (SUPPORT / rig.file).read_text().replace(f"udp_loopback:{rig.prefix}", f"udp_loopback:{channel}-")
    path = start_rig_emulator(text, extra_args=["--effects", str(plugin)])
    campaigns = [tmp_path / f"campaign-{a}" for a in (5, 15)]
    for a, out in zip((5, 15), campaigns):
        stand("campaign", "--rig", path, "--lockstep", "--emulated", "--cycles", 2, "--amplitude-pct", a,
              "--effects", plugin, "--no-progress", "--out", out)
    stand("estimate", *campaigns, "--save", tmp_path / "rig-model.toml")
    diagnosed = json.loads(stand("diagnose", *campaigns, "--rig-model", tmp_path / "rig-model.toml", "--stepwise",
                                 "--json", "--candidates", rig.candidates, "--save", tmp_path / "model.toml",
                                 "--no-progress"))
    model = next(c for c in diagnosed["channels"] if c["channel"] == rig.channel)["model"]
    stand("design", tmp_path / "model.toml", "-o", tmp_path / "controller.toml")
    (tmp_path / "cases.csv").write_text(rig.cases)
    out = tmp_path / "load"
    report = json.loads(stand("load", tmp_path / "cases.csv", "--rig", path, "--controller",
                              tmp_path / "controller.toml", "--rate", 2500, "--repeat", 3, "--lockstep", "--json",
                              "--no-progress", "--out", out, "--effects", plugin))
    assert report["end_reason"] == "complete", report
    passes = report["passes"]
    first, second, third = passes
    figures = "; ".join(f"pass {i}: worst p95 {p['peak_valley_error_pct']['p95']:.3f} / max "
                        f"{p['peak_valley_error_pct']['max']:.3f} %, distribution {p['ratio_error_pct']:.3f} %"
                        for i, p in enumerate(passes, start=1))
    print(f"{rig.file}: {rig.channel} diagnosed {model}; {figures}")
    assert first["peak_valley_error_pct"]["p95"] <= 1.0, figures
    assert third["peak_valley_error_pct"]["p95"] <= 0.5 and third["peak_valley_error_pct"]["max"] <= 1.0, figures
    assert third["ratio_error_pct"] <= 1.0, figures
    assert third["cases_worse"] == [], (third["cases_worse"], figures)
    for i, p in enumerate(passes, start=1):
        extra = {n: c["extra_cycles"] for n, c in p["channels"].items()}
        assert not any(extra.values()), (i, extra)

    # the report: what the feedforward covers, every load case per pass, the channel judged
    # at the moments its effect acts
    covers = report["feedforward"][rig.channel]
    named = set(model.split("+")) - {"base"}
    assert named <= set(covers["inverts"]) | set(covers["does_not_invert"]), covers
    assert "G⁻¹" in covers["inverts"] and not set(covers["inverts"]) & set(covers["does_not_invert"])
    labels = [c["case"] for c in third["load_cases"]]
    assert set(rig.moments) <= set(labels) and len(labels) == len(rig.cases.split()) - 3
    assert all(rig.channel in c["error_pct"] for c in third["load_cases"])
    text = (out / "report.txt").read_text()
    assert "feedforward from the controller's model" in text and "pass 3:" in text
    assert "load cases: the largest deviation from the distribution" in text
    points = json.loads((out / "pass-3" / "tracking.json").read_text())["points"][rig.channel]
    judged = {str(p["case"] + 1): p["kind"] for p in points}
    assert all(judged[c] in ("rising", "falling") for c in rig.moments), judged
