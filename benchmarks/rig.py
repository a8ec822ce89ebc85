"""Rig scaling: the lockstep real-time factor of 1, 4, 8, 16 and 32 channels (16 on 4 buses, 32 on 8, and on 4 CAN FD buses), through the benchmark's gateway and through ``stand demo --rig`` (its recording included), and real time for 16 channels on 4 buses (and 32 on 8) at 2 ms (SYNC jitter p99, the skew between the buses' SYNCs p99, missed and stale cycles, the loop's and the emulator's CPU, the host's own floor beside).

The rigs are chains (:func:`rig.chain.chain_rig`): copies of the example rig's first channel
(its base+reversal plant, 2 kgf noise), neighbours coupled 30 % through a chain stiffness,
spread evenly over the buses (4 channels per bus at most: 62.8 % of a 1 Mbit/s bus at 2 ms
by the worst-case budget, under the 70 % limit). Each rig is written as a rig file and served by
``stand emulate --rig`` in its own process on private loopback buses; the gateway drives it
with a meander on the first channel, the others at a zero command.

* Lockstep: the cycles per second the gateway's run counted over its wall time (per cycle one
  SYNC per bus, two TPDOs and one RPDO per channel); and ``stand demo --rig FILE`` as a user
  runs it (its own emulator process, every channel recorded, a capture per bus), the factor it
  prints. The CAN FD rig: 1 Mbit/s nominal, 5 Mbit/s data, 8 channels a bus (62 % by the
  budget).
* Real time: the emulator is the stand's hardware, which a bench does not share with the
  host's other work: it runs at SCHED_FIFO one priority below the loop (at ordinary scheduling
  on a busy host it fell seconds behind: 96 % of 16 channels' cycles stale), the gateway at
  its own real-time priority. CPU: the loop thread's own (``stats.loop_cpu_s``), the gateway
  process's and the emulator process's over the run, per cycle and as a share of one core. SYNC jitter: each cycle's SYNC send time (the run's
  ``sync_time``) against the ideal 2 ms grid. Skew: each cycle's SYNC on the second bus minus
  the first's, both from the runs' captures (udp_loopback stamps every frame with its send
  time), paired by cycle (the SYNC counters agree). The 16-channel rig again on a busy host:
  4 processes beside it that only compute (ordinary scheduling, as a user's analysis or a build
  would), from before the run to its end.

* Unload keeping the ratios (the issue's case): the example rig (4 channels, neighbours
  coupled 30 %, each its own g, τ and reversal boost; outer's and tip's ranges raised to 10 t so
  the load case fits), loaded 6000 / 4000 / 5000 / 3000 kgf, lockstep. All valves alive: root
  driven at +5 % into its force limit (6100 kgf), ``--limit-action unload``. One valve dead:
  inner's valve is stopped by an NMT command from outside at 0.5 s (it drops to its own safe
  state; the gateway sees it leave OPERATIONAL), ``--fault-action unload``: inner is excluded
  and held, the others unload. The deviation from the ratios is the gateway's own record
  (run.json ``safety.unload``: ``d_i = y_i − σ·y_i(t0)``), as % of each channel's range.

A shared 2-core VM: the load average before and after is in the note.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .table import Row

ORDER = 12
PERIOD_S = 0.002
#: the busy host's real-time rows: this many processes that only compute, beside the run
BUSY_PROCESSES = 4
SYNC_ID = 0x80
#: (channels, buses, CAN FD data bit rate or None) of the lockstep rows
SIZES = ((1, 1, None), (4, 2, None), (8, 2, None), (16, 4, None), (32, 8, None), (32, 4, 5_000_000))
#: the goals: lockstep real-time factors, the real-time rows' figures
LOCKSTEP_GOALS = {16: 10.0, 32: 4.0}
STALE_GOAL = 0.01
#: the loop's real-time priority (the gateway's default) and the emulator's, one below
LOOP_PRIORITY = 50
COUPLING = 0.3
JITTER_GOAL_MS = 0.5
SKEW_GOAL_MS = 0.2
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "rig.toml"


def chain_file(directory: Path, channels: int, buses: int, data_bitrate: int | None = None) -> Path:
    """A chain rig of ``channels`` on ``buses`` private loopback buses (CAN FD ones with
    ``data_bitrate``), written as a rig file."""
    from rig.chain import chain_rig
    from rig.config import load_rig_file
    from rig.files import rig_to_toml
    tag = f"bench-rig{channels}-{os.getpid()}-{time.monotonic_ns() % 10**6}"
    rig = chain_rig(load_rig_file(EXAMPLE).channels[0], channels, buses, COUPLING, PERIOD_S, tag,
                    data_bitrate=data_bitrate)
    path = directory / f"chain-{channels}-on-{buses}{'-fd' if data_bitrate else ''}.toml"
    path.write_text(rig_to_toml(rig, header="a benchmark's chain rig (benchmarks/rig.py)", path=path))
    return path


def process_cpu_s(pid: int) -> float:
    """CPU time (user + system, s) a process has used, its ended threads included."""
    fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def drive(path: Path, out: Path, lockstep: bool, stand_s: float, emulator_args: list[str] | None = None,
          limits=None, beside=None, cpu: dict | None = None):
    """Serve the rig file with ``stand emulate --rig`` and run a meander of ``stand_s`` seconds
    on its first channel through the gateway (``limits``: its SafetyLimits); ``beside()`` is
    called just before the run starts. The run's result and the rig; ``cpu`` gets the gateway
    process's and the emulator's CPU time over the run (s)."""
    from gateway import Gateway, GatewayConfig, SafetyLimits
    from gateway.experiments import Meander
    from plant_emulator.process import RigEmulatorProcess
    from rig.config import load_rig_file
    rig = load_rig_file(path)
    period = max(stand_s, 2 * PERIOD_S)
    with RigEmulatorProcess(path, lockstep=lockstep, seed=1, extra_args=emulator_args or []) as emu, \
            Gateway(GatewayConfig(rig=rig, lockstep=lockstep, limits=limits or SafetyLimits())) as gw:
        if beside is not None:
            beside()
        emu0, own0 = process_cpu_s(emu.pid), process_cpu_s(os.getpid())
        result = gw.run(Meander(5, period, 1), out, progress=False, channels=[rig.names[0]])
        if cpu is not None:
            cpu["emulator_s"] = process_cpu_s(emu.pid) - emu0
            cpu["gateway_s"] = process_cpu_s(os.getpid()) - own0
    return result, rig


def lockstep_rate(channels: int, buses: int, stand_s: float, data_bitrate: int | None = None) -> dict:
    """Lockstep cycles per second of a chain rig (module docstring)."""
    cpu: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        result, rig = drive(chain_file(Path(tmp), channels, buses, data_bitrate), Path(tmp) / "run",
                            True, stand_s, cpu=cpu)
    s = result.outcome.stats
    status = result.status if result.reason is None else f"{result.status}: {result.outcome.message}"
    return {"rate": s.cycles / s.wall_s, "cycles": s.cycles, "status": status,
            "frames": len(rig.buses) + 3 * channels, "loop_cpu_us": 1e6 * s.loop_cpu_s / max(s.cycles, 1),
            "emulator_cpu_us": 1e6 * cpu["emulator_s"] / max(s.cycles, 1)}


def demo_factor(channels: int, buses: int, data_bitrate: int | None, cycles: int,
                period_s: float = 4.0) -> dict:
    """``stand demo --rig`` on a chain rig as a user runs it (a process of its own, its own
    emulator, every channel recorded, a capture per bus): the real-time factor it prints."""
    import re
    import subprocess
    import sys
    with tempfile.TemporaryDirectory() as tmp:
        path = chain_file(Path(tmp), channels, buses, data_bitrate)
        out = subprocess.run([sys.executable, "-m", "stand", "demo", "--rig", str(path), "--cycles",
                              str(cycles), "--period-s", str(period_s), "--out", str(Path(tmp) / "demo")],
                             capture_output=True, text=True, timeout=1800)
    found = re.search(r"run \S+: (\w+), ([\d,]+) cycles .*?\(([\d.]+)x real time\)", out.stdout)
    if found is None:
        return {"factor": float("nan"), "status": f"failed ({out.returncode}): {out.stdout[-300:]} {out.stderr[-300:]}",
                "cycles": 0}
    return {"factor": float(found.group(3)), "status": found.group(1),
            "cycles": int(found.group(2).replace(",", ""))}


def sync_stamps(capture: Path) -> tuple[np.ndarray, np.ndarray]:
    """Send stamps (s) and counters of the SYNCs in a capture (python-can's LogReader)."""
    import can
    frames = [(m.timestamp, m.data[0] if m.data else -1) for m in can.LogReader(str(capture))
              if m.arbitration_id == SYNC_ID and not m.is_error_frame]
    return np.array([f[0] for f in frames]), np.array([f[1] for f in frames])


def bus_skew_s(captures: list[Path]) -> tuple[np.ndarray, np.ndarray]:
    """Per cycle, the latest SYNC of the buses minus the earliest (s), paired by cycle, and
    the earliest (wall-clock s); every capture must hold the same SYNCs (count and counters),
    else ValueError."""
    stamps = [sync_stamps(c) for c in captures]
    n = {len(t) for t, _ in stamps}
    if len(n) != 1:
        raise ValueError(f"the captures hold {sorted(n)} SYNCs: not one per bus per cycle")
    if not all(np.array_equal(k, stamps[0][1]) for _, k in stamps[1:]):
        raise ValueError("the buses' SYNC counters differ cycle by cycle")
    t = np.vstack([s for s, _ in stamps])
    first = t.min(axis=0)
    return t.max(axis=0) - first, first


def grid_jitter_ms(sync_time: np.ndarray, t: np.ndarray) -> np.ndarray:
    """|each SYNC's send time − its slot on the ideal grid| (ms), the grid's phase the median."""
    slots = np.round(t / PERIOD_S)
    dev = (sync_time - sync_time[0]) - slots * PERIOD_S
    return np.abs(dev - np.median(dev)) * 1e3


def answer_lag_ms(capture: Path) -> np.ndarray:
    """Per SYNC of a capture, how long after it the emulator's first TPDO came (ms)."""
    import can
    frames = [(m.timestamp, m.arbitration_id) for m in can.LogReader(str(capture))]
    t = np.array([f[0] for f in frames])
    ids = np.array([f[1] for f in frames])
    syncs = t[ids == SYNC_ID]
    tpdos = np.sort(t[(ids > 0x180) & (ids < 0x200)])
    k = np.searchsorted(tpdos, syncs)
    ok = k < len(tpdos)
    return (tpdos[k[ok]] - syncs[ok]) * 1e3


def realtime_rig(channels: int, buses: int, duration_s: float,
                 emulator_priority: int = LOOP_PRIORITY - 1, busy: int = 0) -> dict:
    """A real-time run of a chain rig at 2 ms (module docstring): jitter and skew, ms. The
    stale readings do not stop the run (the emulator's answers are measured, not judged).
    Bare real-time threads in other processes, one pinned to each CPU
    (:mod:`benchmarks.wakeup`), sleep on their own 2 ms grids meanwhile: the host's floor in
    the same seconds, and which late cycles fell on one of its stalls. ``busy``: that many
    processes that only compute beside the run (ordinary scheduling), a busy host."""
    from gateway import SafetyLimits, load_run

    from . import wakeup
    floors = []
    cpu: dict = {}
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
    try:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "run"
            result, rig = drive(chain_file(Path(tmp), channels, buses), out, False, duration_s,
                                emulator_args=["--rt-priority", str(emulator_priority)],
                                limits=SafetyLimits(stale_cycles=100_000),
                                beside=lambda: floors.extend(wakeup.start_on_every_cpu(duration_s + 3.0)),
                                cpu=cpu)
            host = [wakeup.result(f) for f in floors]
            run = load_run(out)
            captures = [out / f"capture-{b.name}.log" for b in rig.buses]
            skew, first_sync = bus_skew_s(captures)
            skew = skew * 1e3
            lag = np.concatenate([answer_lag_ms(c) for c in captures])
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
    jitter = grid_jitter_ms(np.asarray(run.sync_time), np.asarray(run.t))
    s = result.outcome.stats
    sched = run.meta.get("realtime", {})
    stalls = [st for h in host for st in h["stalls"]]
    # the late cycles only, as benchmarks/control_loop.py places them (every cycle against
    # every stall was 15,000 × 7,000 comparisons in Python for the full row)
    late = jitter >= wakeup.STALL_S * 1e3
    at_host = np.zeros(len(jitter), bool)
    at_host[late] = [wakeup.at_host_stalls([(t - d * 1e-3, d * 1e-3)], stalls) > 0
                     for t, d in zip(np.asarray(run.sync_time)[late], jitter[late])]
    # a late SYNC whose cycle began behind: the cycle before ended after its time (the loop's
    # own work and answer window), not a late wake-up
    behind = np.asarray(s.behind_s[:len(jitter)]) > 0
    # the cycles whose SYNCs left further apart than the goal, placed the same way
    skewed = skew >= SKEW_GOAL_MS
    skew_at_host = np.zeros(len(skew), bool)
    skew_at_host[skewed] = [wakeup.at_host_stalls([(t, d * 1e-3)], stalls) > 0
                            for t, d in zip(first_sync[skewed], skew[skewed])]
    # the missed slots: a cycle that began more than a period late (the loop's own lateness,
    # before it skipped the slots between), placed as benchmarks/control_loop.py places a late
    # one: while a bare thread a priority above the loop was late too (the host did not run
    # it), or the loop's own
    n = min(len(s.sync_jitter_s), len(run.sync_time))
    began_late = np.asarray(s.sync_jitter_s[:n])
    gone = began_late > PERIOD_S
    gaps = list(zip((np.asarray(run.sync_time)[:n][gone] - began_late[gone]).tolist(),
                    began_late[gone].tolist()))
    gaps_at_host = wakeup.at_host_stalls(gaps, stalls)
    per_cycle = 1e6 / max(s.cycles, 1)
    return {"missed_gaps": len(gaps), "missed_gaps_at_host": gaps_at_host,
            "loop_cpu_us": s.loop_cpu_s * per_cycle, "gateway_cpu_us": cpu["gateway_s"] * per_cycle,
            "emulator_cpu_us": cpu["emulator_s"] * per_cycle,
            "jitter": jitter, "skew": skew, "lag": lag, "cycles": s.cycles, "overruns": s.overruns,
            "stale": s.stale_cycles, "status": result.status,
            "host_p99": max((h["p99_ms"] for h in host), default=float("nan")),
            "host_stalls": len(stalls), "late": int(late.sum()),
            "late_at_host": int((late & at_host).sum()), "jitter_off_host": jitter[~at_host],
            "late_behind": int((late & behind).sum()),
            "late_behind_off_host": int((late & behind & ~at_host).sum()),
            "skewed": int(skewed.sum()), "skewed_at_host": int((skewed & skew_at_host).sum()),
            "skew_off_host": skew[~skew_at_host],
            "policy": (f"{sched['policy']} {sched['priority']}" if "priority" in sched
                       else f"ordinary scheduling ({sched.get('note', '?')})")}


def _pct(a: np.ndarray, q: float) -> float:
    return float(np.percentile(a, q)) if a.size else float("nan")


#: the issue's load case, kgf, in the example rig's channel order (root, inner, outer, tip)
LOAD_CASE = (6000.0, 4000.0, 5000.0, 3000.0)
UNLOAD_GOAL_PCT = 2.0


def loaded_example(directory: Path, limit_root_kgf: float) -> Path:
    """The example rig on private loopback buses, every range 10 t, loaded with
    :data:`LOAD_CASE`, root's force limit ``limit_root_kgf``."""
    import dataclasses
    from rig.config import load_rig_file
    from rig.files import on_private_loopback, rig_to_toml
    rig = on_private_loopback(load_rig_file(EXAMPLE), f"bench-unload-{os.getpid()}-{time.monotonic_ns() % 10**6}")
    chans = []
    for c, load in zip(rig.channels, LOAD_CASE):
        plant = dataclasses.replace(c.plant, initial_force_kgf=load,
                                    sensor={**c.plant.sensor, "range_kgf": 10_000.0})
        chans.append(dataclasses.replace(c, range_kgf=10_000.0, plant=plant,
                                         force_limit_kgf=limit_root_kgf if c is rig.channels[0] else 9000.0))
    path = directory / "loaded.toml"
    path.write_text(rig_to_toml(dataclasses.replace(rig, channels=chans), path=path))
    return path


def push(u_pct: float, duration_s: float):
    """An experiment that holds one open-loop command (the fault injection: a channel driven
    into its force limit; the paper's experiments stop themselves short of it)."""
    from gateway.experiments.base import Experiment

    class Push(Experiment):
        name = "push"

        @property
        def duration_s(self) -> float:
            return duration_s

        def params(self):
            return {"u": u_pct, "duration": duration_s}

        def step(self, t, y):
            return u_pct, float("nan")

    return Push()


def unload_case(dead_valve: bool) -> dict:
    """The issue's unload (module docstring); run.json's ``safety`` and the forces at the end."""
    import json
    import can
    from gateway import Gateway, GatewayConfig, SafetyLimits, load_run
    from plant_emulator.process import RigEmulatorProcess
    from rig.config import load_rig_file
    from standbus import open_bus
    from gateway.experiments import EXPERIMENTS
    with tempfile.TemporaryDirectory() as tmp:
        path = loaded_example(Path(tmp), 9000.0 if dead_valve else 6100.0)
        rig = load_rig_file(path)
        inner = rig.channel("inner")
        stopped: list[float] = []
        side = open_bus(rig.bus(inner.bus).spec) if dead_valve else None

        def stop_inner(t: float) -> None:
            if side is not None and t >= 0.5 and not stopped:
                stopped.append(t)
                side.send(can.Message(arbitration_id=0, data=[0x02, inner.valve_id], is_extended_id=False))

        if dead_valve:
            config = GatewayConfig(rig=rig, lockstep=True, fault_action="unload")
            experiment = EXPERIMENTS["meander"](amplitude_pct=0.5, period_s=2.0, cycles=4)
        else:
            config = GatewayConfig(rig=rig, lockstep=True, limits=SafetyLimits(force_action="unload"))
            experiment = push(5.0, 8.0)
        try:
            with RigEmulatorProcess(path, lockstep=True, seed=2), Gateway(config) as gw:
                result = gw.run(experiment, Path(tmp) / "run", progress=False, channels=["root"],
                                on_progress=stop_inner)
        finally:
            if side is not None:
                side.shutdown()
        meta = json.loads((Path(tmp) / "run" / "run.json").read_text())
        run = load_run(Path(tmp) / "run")
        end = {n: float(run.signals[f"y.{n}"][-1]) for n in rig.names}
    return {"status": result.status, "reason": result.reason, "safety": meta.get("safety", {}),
            "end": end, "message": result.outcome.message}


def unload_row(case: dict, dead_valve: bool) -> Row:
    safety = case["safety"]
    unload = safety.get("unload") or {}
    chans = unload.get("channels", {})
    live = {n: c for n, c in chans.items() if c.get("unloaded")}
    worst = max((c["max_deviation_pct_of_range"] for c in live.values()), default=float("nan"))
    big = unload.get("largest_deviation", {})
    excluded = [e["channel"] for e in safety.get("rig", {}).get("excluded", [])]
    dead = "".join(f"; {n} (excluded, held) went {chans[n]['from_kgf']:.0f} -> {case['end'][n]:.0f} kgf "
                   "through the coupling" for n in excluded if n in chans)
    label = ("rig unload keeping the ratios, 6000/4000/5000/3000 kgf, one valve dead (inner)"
             if dead_valve else "rig unload keeping the ratios, 6000/4000/5000/3000 kgf, all valves alive")
    return Row(label,
               f"largest deviation {worst:.2f} % of its range ({big.get('kgf', float('nan')):.0f} kgf "
               f"on {big.get('channel', '?')})",
               f"goal every channel within {UNLOAD_GOAL_PCT:g} % of its range",
               f"{worst / UNLOAD_GOAL_PCT:.2f} of goal",
               f"trip {case['reason']} on {safety.get('channel')}; {unload.get('outcome')} in "
               f"{unload.get('duration_s', float('nan')):.2f} s, {len(live)} of {len(chans)} "
               f"channels unloaded, ends {', '.join(f'{n} {v:.0f}' for n, v in case['end'].items())} kgf"
               f"{dead}; per channel " + ", ".join(f"{n} {c['max_deviation_pct_of_range']:.2f} %"
                                                 for n, c in live.items()))


def _kind(buses: int, data_bitrate: int | None) -> str:
    return (f"{buses} CAN FD buses ({data_bitrate / 1e6:g} Mbit/s data)" if data_bitrate
            else f"{buses} bus{'es' if buses > 1 else ''}")


def realtime_rows(channels: int, buses: int, duration_s: float, load_before: float,
                  busy: int = 0) -> list[Row]:
    """The real-time rows of one rig size (module docstring), ``busy`` computing processes
    beside."""
    rt = realtime_rig(channels, buses, duration_s, busy=busy)
    load_after = os.getloadavg()[0]
    j, k = rt["jitter"], rt["skew"]
    what = (f"rig real time, {channels} channels on {buses} buses at 2 ms"
            + (f", {busy} busy process{'es' if busy > 1 else ''} beside" if busy else ""))
    stale_share = rt["stale"] / max(rt["cycles"], 1)
    where = (f"{rt['cycles']:,} cycles ({rt['status']}), {rt['overruns']} missed, {rt['stale']} "
             f"stale ({100 * stale_share:.2f} %); {rt['late']} cycles ≥ 0.5 ms late, {rt['late_at_host']} "
             f"of them at one of the host's {rt['host_stalls']} stalls (a bare real-time thread per CPU, "
             f"host floor p99 {rt['host_p99']:.2f} ms); off the host's stalls p99 "
             f"{_pct(rt['jitter_off_host'], 99):.3f} ms; {rt['late_behind']} of the late cycles began "
             f"behind (the cycle before ended after their SYNC time), {rt['late_behind_off_host']} "
             f"of them off the host's stalls; gateway at {rt['policy']}, the emulator ({channels} "
             f"channels, one process) at SCHED_FIFO {LOOP_PRIORITY - 1}; load average "
             f"{load_before:.1f} before, {load_after:.1f} after, 2 cores")
    period_us = PERIOD_S * 1e6
    return [
        Row(f"{what}: SYNC jitter",
            f"p50 {_pct(j, 50):.3f} / p99 {_pct(j, 99):.3f} / max {j.max():.2f} ms",
            f"goal p99 < {JITTER_GOAL_MS} ms", f"{_pct(j, 99) / JITTER_GOAL_MS:.2f} of goal",
            "SYNC send time vs ideal grid; " + where),
        Row(f"{what}: skew between the buses' SYNCs",
            f"p50 {_pct(k, 50):.3f} / p99 {_pct(k, 99):.3f} / max {k.max():.2f} ms",
            f"goal p99 < {SKEW_GOAL_MS} ms", f"{_pct(k, 99) / SKEW_GOAL_MS:.2f} of goal",
            f"the last bus's SYNC minus the first's, each cycle, from the captures' send stamps; "
            f"{rt['skewed']} cycles ≥ {SKEW_GOAL_MS} ms, {rt['skewed_at_host']} of them "
            f"at one of the host's stalls; off the host's stalls p99 "
            f"{_pct(rt['skew_off_host'], 99):.3f} ms"),
        Row(f"{what}: missed and stale cycles, the emulator's answer",
            f"{rt['overruns']} missed, {100 * stale_share:.2f} % stale; first TPDO after its SYNC "
            f"p50 {_pct(rt['lag'], 50):.2f} / p90 {_pct(rt['lag'], 90):.2f} ms",
            f"goal 0 missed, stale < {100 * STALE_GOAL:g} %",
            "met" if rt["overruns"] == 0 and stale_share < STALE_GOAL else "not met",
            f"{rt['stale']:,} of {rt['cycles']:,} cycles with a reading not in time (the run not "
            f"stopped for them); the missed slots in {rt['missed_gaps']} gap(s), "
            f"{rt['missed_gaps_at_host']} of them at one of the host's stalls (a bare real-time "
            f"thread a priority above the loop late then too); host floor p99 "
            f"{rt['host_p99']:.2f} ms"),
        Row(f"{what}: CPU per cycle",
            f"loop {rt['loop_cpu_us']:.0f} µs, gateway {rt['gateway_cpu_us']:.0f} µs, emulator "
            f"{rt['emulator_cpu_us']:.0f} µs",
            f"a period: {period_us:.0f} µs of one core",
            f"{rt['loop_cpu_us'] / period_us:.2f} / {rt['gateway_cpu_us'] / period_us:.2f} / "
            f"{rt['emulator_cpu_us'] / period_us:.2f} of a core",
            "the loop thread's own CPU (run.json stats.loop_cpu_s), the gateway process's (loop, "
            "captures, recorder, reader) and the emulator process's over the run, per cycle"),
    ]


def run(quick: bool) -> list[Row]:
    load_before = os.getloadavg()[0]
    rows = []
    base = None
    for channels, buses, dbr in ((1, 1, None), (4, 2, None)) if quick else SIZES:
        r = lockstep_rate(channels, buses, 1.0 if quick else 10.0, dbr)
        base = base or r["rate"]
        factor = r["rate"] * PERIOD_S
        goal = LOCKSTEP_GOALS.get(channels)
        rows.append(Row(f"rig lockstep, {channels} channel(s) on {_kind(buses, dbr)}",
                        f"{r['rate']:,.0f} cycles/s", f"real time: {1 / PERIOD_S:,.0f} cycles/s"
                        + (f"; goal ≥ {goal:g}x" if goal else ""),
                        f"{factor:.2f}x real time",
                        f"{r['cycles']:,} cycles ({r['status']}), {r['frames']} frames per cycle; "
                        f"{r['rate'] / base:.2f} of 1 channel's rate; CPU per cycle: loop "
                        f"{r['loop_cpu_us']:.0f} µs, emulator {r['emulator_cpu_us']:.0f} µs (both poll "
                        f"while they wait); chain rig, neighbours {COUPLING:.0%}, stand emulate --rig "
                        f"in its own process; load average {os.getloadavg()[0]:.1f}"))
    for channels, buses, dbr in ((4, 2, None),) if quick else SIZES:
        d = demo_factor(channels, buses, dbr, 2 if quick else 3, 2.0 if quick else 4.0)
        goal = LOCKSTEP_GOALS.get(channels)
        rows.append(Row(f"stand demo --rig, {channels} channel(s) on {_kind(buses, dbr)}",
                        f"{d['factor']:.1f}x real time", "the user's own path" + (f"; goal ≥ {goal:g}x" if goal else ""),
                        f"{d['factor']:.1f}x",
                        f"the factor the demo prints: {d['cycles']:,} cycles ({d['status']}), every "
                        f"channel recorded, a capture per bus, its own emulator process; load "
                        f"average {os.getloadavg()[0]:.1f}"))
    if quick:      # (the busy host's path too: one process that only computes beside)
        rows += realtime_rows(4, 2, 3.0, load_before, busy=1)
    else:
        rows += realtime_rows(16, 4, 30.0, load_before)
        rows += realtime_rows(32, 8, 30.0, os.getloadavg()[0])
        rows += realtime_rows(16, 4, 30.0, os.getloadavg()[0], busy=BUSY_PROCESSES)
    for dead in (False, True):
        rows.append(unload_row(unload_case(dead), dead))
    return rows
