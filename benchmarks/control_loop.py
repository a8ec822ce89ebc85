"""Control loop over the real multi-process loopback bus: lockstep throughput and real-time
SYNC jitter at the default 2 ms period (the emulator is a separate process in both)."""
from __future__ import annotations

import multiprocessing as mp
import os
import socket
import tempfile
import threading
import time

import can
import numpy as np

from gateway import Gateway, GatewayConfig, load_run
from gateway.experiments import Meander
from plant.config import load_plant_config
from plant_emulator.process import EmulatorProcess

from . import wakeup
from .table import Row

ORDER = 10
PERIOD_S = 0.002
SYNC_ID = 0x80


def lockstep_cycles_per_s(cycles: int) -> tuple[float, float, dict[str, float], dict[str, float]]:
    """Lockstep cycles per second, the cycles run, where a cycle's time goes and how the
    cycle times spread."""
    bus = f"udp_loopback:bench-ls-{os.getpid()}"
    with tempfile.TemporaryDirectory() as tmp, EmulatorProcess(bus, load_plant_config(), lockstep=True):
        with Gateway(GatewayConfig(bus=bus, lockstep=True)) as gw:
            res = gw.run(Meander(5, 4, max(1, round(cycles * PERIOD_S / 4))), f"{tmp}/run", progress=False)
        stamps, ids = send_stamps(f"{tmp}/run/capture.log")   # read once for both
    parts = cycle_breakdown(stamps, ids)
    spread = cycle_spread(stamps, ids)
    s = res.outcome.stats
    return s.cycles / s.wall_s, s.cycles, parts, spread


def send_stamps(capture: str) -> tuple[np.ndarray, np.ndarray]:
    """The send stamps (s) and arbitration ids of a capture's frames, in bus order (python-can's
    LogReader)."""
    frames = [(m.timestamp, m.arbitration_id) for m in can.LogReader(capture)]
    return np.array([f[0] for f in frames]), np.array([f[1] for f in frames], dtype=np.int64)


#: the four legs of a lockstep cycle, between the send stamps of its frames (in bus order)
LEGS = ("SYNC→1st TPDO", "1st→2nd TPDO", "2nd TPDO→RPDO", "RPDO→next SYNC")


def cycle_breakdown(stamps: np.ndarray, ids: np.ndarray) -> dict[str, float]:
    """Median µs of each leg of the cycles of a lockstep capture (:func:`send_stamps`).
    Every frame carries its sender's wall-clock send time (udp_loopback), so the legs are:
    the emulator answering a SYNC (after the RPDO before it), the emulator's second send (0: its
    answers to a SYNC leave in one datagram, stamped alike), the transit and the gateway's
    decision, and the gateway's bookkeeping up to the next SYNC."""
    syncs = np.flatnonzero(ids == SYNC_ID)
    legs: list[list[float]] = [[] for _ in LEGS]
    for a, b in zip(syncs[:-1], syncs[1:]):
        tpdos, rpdo = ids[a + 1:a + 3], ids[a + 3]
        if b - a == 4 and np.all((tpdos >= 0x180) & (tpdos < 0x200)) and 0x200 <= rpdo < 0x280:
            for i in range(4):
                legs[i].append(stamps[a + i + 1] - stamps[a + i])
    return {name: float(np.median(v) * 1e6) if v else float("nan") for name, v in zip(LEGS, legs)}


def cycle_spread(stamps: np.ndarray, ids: np.ndarray) -> dict[str, float]:
    """How the lockstep cycle times (SYNC to SYNC send stamps of :func:`send_stamps`, µs)
    spread: mean, p50, p90, p99, and the share of the run's time spent in cycles longer than
    twice the median (the tail: the emulator computing a plant block ahead, the capture thread
    holding the GIL, the host)."""
    d = np.diff(stamps[ids == SYNC_ID]) * 1e6
    if d.size == 0:
        return {"mean": float("nan"), "p50": float("nan"), "p90": float("nan"),
                "p99": float("nan"), "tail_share": float("nan")}
    p50 = float(np.median(d))
    return {"mean": float(d.mean()), "p50": p50, "p90": float(np.percentile(d, 90)),
            "p99": float(np.percentile(d, 99)), "tail_share": float(d[d > 2 * p50].sum() / d.sum())}


def _echo_datagrams(sock, peer, n: int, spin: bool) -> None:
    for _ in range(n):
        sock.sendto(_wait_datagram(sock, spin), peer)


def _wait_datagram(sock, spin: bool) -> bytes:
    if not spin:
        return sock.recv(64)
    while True:
        try:
            return sock.recv(64)
        except BlockingIOError:
            os.sched_yield()


def bare_round_trips(n: int, timeout_s: float = 120.0) -> tuple[float, str]:
    """The floor under any two-process Python loop here: round trips per second of a bare UDP
    ping-pong between two processes on 127.0.0.1 (one 34-byte datagram each way, no CAN, no
    CANopen, no work), the better of sleeping and polling receivers, and which it was. A
    lockstep cycle needs at least one round trip: the command of cycle k needs its force.
    Raises RuntimeError if the echo process has not answered them all within ``timeout_s``."""
    best = (0.0, "")
    for spin in (False, True):
        a = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        a.bind(("127.0.0.1", 0))
        b.bind(("127.0.0.1", 0))
        a.setblocking(not spin)
        b.setblocking(not spin)
        echo = mp.get_context("fork").Process(target=_echo_datagrams, daemon=True,
                                              args=(b, a.getsockname(), n + 100, spin))
        echo.start()
        # the deadline wakes the loop with an empty datagram (no check in the timed path but
        # the length of what arrived)
        alarm = threading.Timer(timeout_s, _send_empty, args=(a.getsockname(),))
        alarm.start()
        frame = bytes(34)
        peer = b.getsockname()    # once: a system call per round trip would be in the floor
        try:
            for i in range(n + 100):
                if i == 100:          # after a warm-up
                    t0 = time.perf_counter()
                a.sendto(frame, peer)
                if not _wait_datagram(a, spin):
                    raise RuntimeError(f"the echo process answered only {i} of {n + 100} round "
                                       f"trips in {timeout_s:g} s ({'polling' if spin else 'sleeping'})")
            rate = n / (time.perf_counter() - t0)
        finally:
            alarm.cancel()
            echo.join(10)
            if echo.is_alive():
                echo.terminate()
            a.close()
            b.close()
        if rate > best[0]:
            best = (rate, "polling" if spin else "sleeping")
    return best


def _send_empty(addr) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(b"", addr)


def realtime_jitter(duration_s: float, experiment=None) -> dict:
    """SYNC timing of a real-time run: each SYNC's wall-clock send time (recorded per cycle)
    against the ideal grid t0 + k·T, k counting the period slots (a missed cycle skips one).
    Bare real-time threads in other processes, one pinned to each CPU (:mod:`benchmarks.wakeup`),
    sleep on their own 2 ms grids meanwhile: a late cycle at a moment one of them woke late too
    is the host's doing. ``experiment``: what the loop runs (default: a meander at 5 %)."""
    bus = f"udp_loopback:bench-rt-{os.getpid()}"
    if experiment is not None:
        duration_s = experiment.max_duration_s
    with tempfile.TemporaryDirectory() as tmp, EmulatorProcess(bus, load_plant_config(), lockstep=False):
        with Gateway(GatewayConfig(bus=bus, lockstep=False)) as gw:
            floors = wakeup.start_on_every_cpu(duration_s + 3.0)
            if experiment is None:
                experiment = Meander(5, 2, max(1, round(duration_s / 2)))
            res = gw.run(experiment, f"{tmp}/run", progress=False)
            host = [stall for f in floors for stall in wakeup.result(f)["stalls"]]
        run = load_run(f"{tmp}/run")
    s = res.outcome.stats
    n = min(len(s.sync_jitter_s), len(run.sync_time))
    late = np.asarray(s.sync_jitter_s[:n])      # each cycle's start minus its scheduled time, s
    sel = late >= wakeup.STALL_S
    stalls = list(zip((run.sync_time[:n][sel] - late[sel]).tolist(), late[sel].tolist()))
    slots = np.round(run.t / PERIOD_S)
    dev = (run.sync_time - run.sync_time[0]) - slots * PERIOD_S
    dev -= np.median(dev)                       # the grid's phase
    j = np.abs(dev) * 1e3
    sched = run.meta.get("realtime", {})
    policy = (f"{sched['policy']} {sched['priority']}" if "priority" in sched
              else f"ordinary scheduling: {sched.get('note', '?')}")
    return {"p50": float(np.percentile(j, 50)), "p99": float(np.percentile(j, 99)), "max": float(j.max()),
            "overruns": s.overruns, "stale": s.stale_cycles, "cycles": s.cycles, "status": res.status,
            "policy": policy, "late_cycles": len(stalls),
            "at_host_stall": wakeup.at_host_stalls(stalls, host),
            "host_stalls": len(host)}


def run(quick: bool) -> list[Row]:
    rate, n, parts, spread = lockstep_cycles_per_s(4000 if quick else 30000)
    floor, how = bare_round_trips(5000 if quick else 100000)   # short runs read low
    rt = realtime_jitter(2.0 if quick else 60.0)       # quick: one meander period
    rig_rate, rig_n = rig_lockstep_cycles_per_s(1000 if quick else 5000)
    return [
        Row("lockstep HIL loop (loopback bus, 2 processes)", f"{rate:,.0f} cycles/s",
            f"real time: {1 / PERIOD_S:,.0f} cycles/s", f"{rate * PERIOD_S:.1f}x real time",
            f"{n:,} cycles, SYNC+2 TPDO+RPDO each"),
        Row("lockstep cycle: where the time goes (medians)",
            " / ".join(f"{k} {v:.0f}" for k, v in parts.items()) + " µs",
            f"100x real time: {PERIOD_S / 100 * 1e6:.0f} µs per cycle in all",
            f"{sum(parts.values()) / (PERIOD_S / 100 * 1e6):.1f}x over",
            f"mean cycle {1e6 / rate:.0f} µs; from the frames' send stamps in the run's capture: "
            "emulator answer, its 2nd send (0: one datagram), transit + gateway decision, gateway "
            "bookkeeping"),
        Row("lockstep cycle times (SYNC to SYNC)",
            f"mean {spread['mean']:.0f} / p50 {spread['p50']:.0f} / p90 {spread['p90']:.0f} / "
            f"p99 {spread['p99']:.0f} µs",
            f"100x real time: {PERIOD_S / 100 * 1e6:.0f} µs per cycle", "",
            f"{spread['tail_share']:.0%} of the run's time in cycles over twice the median: at "
            "the median the loop would run "
            f"{PERIOD_S / (spread['p50'] * 1e-6):.0f}x real time"),
        Row("floor: bare UDP round trip, 2 Python processes", f"{floor:,.0f} round trips/s",
            f"100x real time: {100 / PERIOD_S:,.0f} cycles/s, one round trip each at least",
            f"{floor * PERIOD_S:.0f}x real time with no work",
            f"{1e6 / floor:.1f} µs per round trip ({how} receivers), no CAN, no CANopen, no plant: "
            f"a lockstep cycle (4 frames, both stacks, plant, supervisor, recorder) takes "
            f"{floor / rate:.1f} of these"),
        Row("lockstep rig loop, 4 channels on 2 buses", f"{rig_rate:,.0f} cycles/s",
            f"real time: {1 / PERIOD_S:,.0f} cycles/s", f"{rig_rate * PERIOD_S:.1f}x real time",
            f"{rig_n:,} cycles, per cycle 2 SYNCs + 8 TPDOs + 4 RPDOs; examples/rig.toml, "
            "stand emulate --rig in its own process"),
        Row("real-time loop 2 ms: SYNC jitter", f"p50 {rt['p50']:.3f} / p99 {rt['p99']:.3f} / max {rt['max']:.2f} ms",
            "target p99 < 0.5 ms, no missed cycle", "",
            f"{rt['cycles']:,} cycles, {rt['overruns']} missed, {rt['stale']} stale; SYNC send time vs "
            f"ideal grid; loop at {rt['policy']}; {rt['late_cycles']} cycles started ≥ "
            f"{wakeup.STALL_S * 1e3:g} ms late, {rt['at_host_stall']} of them while a bare thread in "
            f"another process (one per CPU) woke late too ({rt['host_stalls']} such stalls in the run)"),
    ]


def rig_lockstep_cycles_per_s(cycles: int) -> tuple[float, int]:
    """Lockstep cycles per second of a rig: the example rig (4 coupled channels on 2 loopback
    buses) served by ``stand emulate --rig`` in one process, a meander on its first channel, the
    others at a zero command. Returns (cycles/s, cycles)."""
    from pathlib import Path
    from plant_emulator.process import RigEmulatorProcess
    from rig.config import load_rig_file
    example = Path(__file__).resolve().parents[1] / "examples" / "rig.toml"
    tag = f"bench-rig-{os.getpid()}"
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "rig.toml"
        path.write_text(example.read_text().replace("udp_loopback:rig-", f"udp_loopback:{tag}-"))
        rig = load_rig_file(path)
        with RigEmulatorProcess(path, lockstep=True, seed=1), \
                Gateway(GatewayConfig(rig=rig, lockstep=True)) as gw:
            res = gw.run(Meander(5, 4, max(1, round(cycles * PERIOD_S / 4))), f"{tmp}/run",
                         progress=False, channels=[rig.channels[0].name])
    s = res.outcome.stats
    return s.cycles / s.wall_s, s.cycles
