"""Faster tests at the same accuracy: time scaling to the valve's limit, null pacing, the gain monitor.

On the lockstep emulator, each stand identified with the project's own workflow (meanders at 5,
10 and 20 % → ``stand diagnose --stepwise --save``, as ``scripts/bench loading`` does), the
controller designed from that model. The programme: a synthetic flight-by-flight sequence
(:func:`loading.programme.flight_by_flight`, 28 flights, seed 1: 1037 turning points,
ground-air-ground cycles and gust cycles). Per stand:

* the programme's time at today's 2500 kgf/s beside its valve-limited minimum (``--plan``), and
  one pass at 2500 kgf/s;
* the fastest fixed rate that holds the accuracy (p95 ≤ 0.5 %, max ≤ 1 % of the range, no
  extra cycle): fixed rates at 98, 90, 80, 70, 60 and 50 % of the valve's slower direction's
  largest rate, tried from the fastest down, one pass each, the first that holds it;
* ``--fastest`` at 0.5 % from 2500 kgf/s: every pass's time, its ratio to the minimum and its
  accuracy; the final schedule against the goal (≤ 1.5× the minimum, p95 ≤ 0.5 %, max ≤ 1 %,
  no extra cycle), and the speed-ups over 2500 kgf/s and over the fastest fixed rate;
* a production pass replaying the schedule with the gain monitor watching (5 s blocks).

Then null pacing on a stand whose valve is slower than the model says: the default stand's
identified model on an emulated stand with a 25 % flow limit the model lacks, 101 random
turning points at 5000 kgf/s, without pacing, static and dynamic: turning points missed (error
beyond 0.5 % of the range), pacing time. ``--quick`` (a smoke run): the default stand with its
own model (not identified), 12 turning points, no fixed-rate search, at most 3 passes, pacing on
8 turning points.
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np

from gateway import Gateway, GatewayConfig
from gateway.load import run_load
from loading.design import design
from loading.gain_monitor import MonitorOptions
from loading.minimum_time import programme_timing
from loading.pacing import PacingOptions
from loading.programme import flight_by_flight, from_levels, random_sequence
from loading.time_scaling import ScalingOptions, meets
from plant import PlantModel
from plant.config import load_model_file, load_plant_config
from plant_emulator.process import EmulatorProcess

from .loading import STANDS, identify
from .table import Row, format_table

ORDER = 36
T = 0.002
ACCURACY_PCT = 0.5
TODAY_KGF_S = 2500.0
FIXED_SHARES = (0.98, 0.9, 0.8, 0.7, 0.6, 0.5)


def _bus() -> str:
    return f"udp_loopback:bench-faster-{os.getpid()}-{uuid.uuid4().hex[:6]}"


def _acc(res) -> str:
    if not res.passes:
        return f"stopped ({res.end_reason})"
    pv = res.passes[-1].peak_valley_error_pct
    return f"p95 {pv['p95']:.3f} %, max {pv['max']:.3f} %, {res.passes[-1].extra_cycles:g} extra cycles"


def _log(text: str) -> None:
    print(f"  faster: {text}", file=sys.stderr, flush=True)


def measure(name: str, spec: str, values: dict, quick: bool) -> tuple[list[Row], PlantModel]:
    """The rows of one stand (module docstring) and the model the controller came from."""
    bus = _bus()
    rows = []
    levels = flight_by_flight(4 if quick else 28, seed=1)[: 12 if quick else None]
    plant = load_plant_config(None, spec, values)
    with tempfile.TemporaryDirectory() as tmp, EmulatorProcess(bus, plant, lockstep=True, seed=3):
        tmp = Path(tmp)
        with Gateway(GatewayConfig(bus=bus, lockstep=True)) as gw:
            model = plant.model if quick else load_model_file(identify(gw, tmp))
            ctl = design(model, T)
            rows.append(Row(f"faster, {name}: " + ("the stand's own model" if quick else "identified"), model.spec,
                            note=", ".join(f"{k} {v:.4g}" for k, v in model.params().items())))
            today = from_levels(levels, T, rate_kgf_s=TODAY_KGF_S)
            timing = programme_timing(today, model, ctl.command_limit_pct)
            minimum = timing.minimum_time_s
            rows.append(Row(f"faster, {name}: programme at {TODAY_KGF_S:g} kgf/s vs valve-limited minimum",
                            f"{today.duration_s:.1f} s vs {minimum:.1f} s", "",
                            f"{today.duration_s / minimum:.2f}x",
                            f"{len(levels)} turning points, range {today.range_kgf:.0f} kgf; "
                            f"{timing.limit.rates[0].text()}"))
            t0 = time.monotonic()
            res = run_load(gw, today, ctl, tmp / "today", progress=False)
            rows.append(Row(f"faster, {name}: one pass at {TODAY_KGF_S:g} kgf/s", _acc(res),
                            "p95 <= 0.5 %, max <= 1 %, 0 extra", "",
                            f"{today.duration_s:.1f} s programme, {time.monotonic() - t0:.0f} s wall"))
            _log(f"{name}: today's pass done")
            fixed = None
            if not quick:
                rates = timing.limit.rates[0]
                slowest = float(min(rates.up_kgf_s.min(), rates.down_kgf_s.min()))
                tried = []
                for share in FIXED_SHARES:
                    rate = round(share * slowest, -1)
                    p = from_levels(levels, T, rate_kgf_s=rate)
                    try:
                        r = run_load(gw, p, ctl, tmp / f"fixed-{rate:g}", progress=False)
                    except Exception as exc:         # refused before moving: the valve cannot
                        tried.append(f"{rate:g}: refused ({str(exc)[:60]})")
                        continue
                    ok = r.end_reason is None and meets(r.passes[-1], ACCURACY_PCT)
                    tried.append(f"{rate:g}: {_acc(r)}")
                    _log(f"{name}: fixed {rate:g} kgf/s: {_acc(r)}")
                    if ok:
                        fixed = (rate, p.duration_s, r)
                        break
                if fixed:
                    rows.append(Row(f"faster, {name}: fastest fixed rate holding {ACCURACY_PCT:g} %",
                                    f"{fixed[0]:g} kgf/s: {fixed[1]:.1f} s, {_acc(fixed[2])}", "",
                                    f"{fixed[1] / minimum:.2f}x the minimum", "; ".join(tried)))
                else:
                    rows.append(Row(f"faster, {name}: fastest fixed rate holding {ACCURACY_PCT:g} %",
                                    "none of the rates tried", note="; ".join(tried)))
            t0 = time.monotonic()
            res = run_load(gw, today, ctl, tmp / "fastest", repeat=3 if quick else 10, progress=False,
                           scaling=ScalingOptions(accuracy_pct=ACCURACY_PCT))
            wall = time.monotonic() - t0
            passes = "; ".join(
                f"{i}: {t.programme_time_s:.1f} s ({t.programme_time_s / t.minimum_time_s:.2f}x), "
                f"p95 {p.peak_valley_error_pct['p95']:.3f} / max {p.peak_valley_error_pct['max']:.3f} %, "
                f"{p.extra_cycles:g} extra, landed/held/missed {t.scaling.get('land')}/{t.scaling.get('hold')}/"
                f"{t.scaling.get('miss')}"
                for i, (p, t) in enumerate(zip(res.passes, res.timings), start=1))
            rows.append(Row(f"faster, {name}: --fastest at {ACCURACY_PCT:g} %, passes", f"{len(res.passes)} passes",
                            "", "", passes + f"; {wall:.0f} s wall" + (f"; stopped: {res.end_reason}" if res.end_reason else "")))
            s = res.schedule
            if s is None:
                rows.append(Row(f"faster, {name}: --fastest schedule", "no pass met the accuracy"))
            else:
                best = next(i for i, (t, rep) in enumerate(zip(res.timings, res.passes))
                            if abs(t.programme_time_s - s.time_s) < 1e-6 and meets(rep, ACCURACY_PCT))
                final = res.passes[best]
                pv = final.peak_valley_error_pct
                rows.append(Row(f"faster, {name}: --fastest schedule (verified pass {best + 1})",
                                f"{s.time_s:.1f} s = {s.time_s / s.minimum_time_s:.2f}x the minimum; p95 "
                                f"{pv['p95']:.3f} %, max {pv['max']:.3f} %, {final.extra_cycles:g} extra",
                                "<= 1.5x the minimum, p95 <= 0.5 %, max <= 1 %, 0 extra",
                                f"{today.duration_s / s.time_s:.2f}x faster than {TODAY_KGF_S:g} kgf/s"
                                + (f", {fixed[1] / s.time_s:.2f}x than {fixed[0]:g} kgf/s" if fixed else ""),
                                "converged" if res.converged else "not converged: the fastest pass that met it"))
                # a production run replaying it, the gain monitor watching
                mon = run_load(gw, today, ctl, tmp / "production", progress=False, schedule=s,
                               monitor=MonitorOptions(block_s=5.0, action="note"))
                watch = mon.monitor.channels[0] if mon.monitor else None
                est = [b for b in watch.blocks if b.g is not None] if watch else []
                spread = (f"g {min(b.g for b in est):.2f}-{max(b.g for b in est):.2f} "
                          f"(model {watch.g_ref:.2f}), median interval "
                          f"±{np.median([(b.high - b.low) / 2 for b in est]):.2f}") if est else "no estimate"
                rows.append(Row(f"faster, {name}: production pass replaying the schedule, gain watched",
                                _acc(mon), "", "",
                                f"{mon.timings[-1].programme_time_s:.1f} s; {len(est)} of "
                                f"{len(watch.blocks) if watch else 0} 5-s blocks estimated, {spread}; alarm "
                                f"{mon.monitor.alarm[0] if mon.monitor.alarm else 'none'}"))
            _log(f"{name}: --fastest done")
    return rows, model


def pacing_rows(model: PlantModel, quick: bool) -> list[Row]:
    """Null pacing on the default stand with a flow limit its model lacks."""
    bus = _bus()
    truth = {"g": 120.0, "tau": 0.05, "delta": 8.0, "reversal.boost": 2.0, "saturation.limit": 25.0}
    rows = []
    ctl = design(model, T)
    p = from_levels(random_sequence(8 if quick else 101, 400, 6200, seed=11), T, rate_kgf_s=5000)
    with tempfile.TemporaryDirectory() as tmp, \
            EmulatorProcess(bus, load_plant_config(None, "base+reversal+saturation", truth), lockstep=True, seed=3), \
            Gateway(GatewayConfig(bus=bus, lockstep=True)) as gw:
        for mode in ("off", "static", "dynamic"):
            res = run_load(gw, p, ctl, Path(tmp) / mode, progress=False, error_limit_kgf=10000.0,
                           pacing=PacingOptions(mode))
            if not res.passes:
                rows.append(Row(f"pacing, flow limit 25 % the model lacks: {mode}", f"stopped ({res.end_reason})",
                                note=res.end_message or ""))
                continue
            rep, timing = res.passes[-1], res.timings[-1]
            missed = sum(abs(tp.error_pct) > ACCURACY_PCT for tp in rep.turning_points)
            pace = timing.pacing or {}
            rows.append(Row(f"pacing, flow limit 25 % the model lacks: {mode}",
                            f"{missed} of {len(rep.turning_points)} turning points missed; {_acc(res)}",
                            "none missed (error beyond 0.5 %)", "",
                            f"programme {timing.programme_time_s:.1f} s, pacing {timing.pacing_s:.1f} s"
                            + (f" ({pace.get('waits')} waits, {pace.get('wait_s', 0):.1f} s waiting, "
                               f"{pace.get('slowed_s', 0):.1f} s slowed)" if pace else "")))
            _log(f"pacing {mode}: {missed} missed")
    return rows


def run(quick: bool) -> list[Row]:
    rows = []
    default_model = None
    for name, (spec, values) in STANDS.items():
        got, model = measure(name, spec, values, quick)
        rows += got
        default_model = default_model or model
        if quick:
            break
    rows += pacing_rows(default_model, quick)
    return rows


if __name__ == "__main__":
    print(format_table(run("--quick" in sys.argv[1:])))
