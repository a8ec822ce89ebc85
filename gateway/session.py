"""The gateway as a library: connect to a stand on any bus, run experiments, record them.

::

    from gateway import Gateway, GatewayConfig
    from gateway.experiments import Meander

    with Gateway(GatewayConfig(bus="udp_loopback:stand0", lockstep=True)) as gw:
        result = gw.run(Meander(amplitude_pct=5, period_s=4, cycles=5), "runs/m5")
    print(result.path, result.status)

``stand run`` is a thin layer over this.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

from tqdm import tqdm

from standbus import BusSpecError, open_bus
from standbus.realtime import process_threads, realtime_threads, short_gil_slices

from .capture import BusCapture, TappedNetwork
from .errors import StandError
from .config import GatewayConfig
from .experiments import Experiment
from .loop import ControlLoop, LoopOutcome, steady_heap
from .master import StandMaster
from .recorder import RunRecorder
from .supervisor import Supervisor


@dataclass
class RunResult:
    path: Path
    outcome: LoopOutcome

    @property
    def status(self) -> str:
        return self.outcome.status

    @property
    def reason(self) -> str | None:
        return self.outcome.reason


class Gateway:
    """Connects (open bus, boot, identify, configure the nodes) on enter; runs experiments."""

    def __init__(self, config: GatewayConfig | None = None) -> None:
        self.config = config or GatewayConfig()
        self.config.validate()
        self.network: TappedNetwork | None = None
        self.master: StandMaster | None = None
        self.loop: ControlLoop | None = None

    def __enter__(self) -> "Gateway":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> None:
        cfg = self.config
        try:
            bus = open_bus(cfg.bus)
        except BusSpecError as exc:
            raise StandError(str(exc)) from None
        # lockstep: the loop takes the bus from the reader thread at every run (<= one cycle)
        self.network = TappedNetwork(bus, notifier_cycle_s=0.005 if cfg.lockstep else None)
        self.network.connect()
        try:
            self.master = StandMaster(self.network, cfg.valve_id, cfg.dynamometer_id)
            self.master.boot(cfg.boot_timeout_s)
            self.master.check_identity()
            self.master.configure(cfg.period_s, cfg.heartbeat_ms, cfg.rpdo_timeout_ms)
            if cfg.lockstep and not self.master.lockstep_capable:
                raise StandError(
                    "--lockstep needs a stand that advances one period per SYNC (the emulator "
                    "started with --lockstep); this stand runs in real time. Drop --lockstep.")
            supervisor = Supervisor(self.master, cfg.limits, cfg.period_s, cfg.lockstep)
            self.loop = ControlLoop(self.network, self.master, supervisor, cfg.period_s, cfg.lockstep)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        if self.loop is not None:
            self.loop.close()
            self.loop = None
        if self.network is not None:
            try:
                if self.master is not None:
                    self.master.enter_preoperational()
            except Exception:
                pass
            self.network.disconnect()
            self.network = None

    def metadata(self, experiment: Experiment) -> dict[str, Any]:
        cfg = self.config
        m = self.master
        return {
            "experiment": {"name": experiment.name, "params": experiment.params()},
            "bus": cfg.bus,
            "clock": "lockstep" if cfg.lockstep else "realtime",
            "period_s": cfg.period_s,
            "nodes": {link.role: {"id": link.id, "identity": link.identity} for link in m.links},
            "force_scale_kgf_per_count": m.force_scale_kgf,
            "limits": asdict(cfg.limits.resolved(cfg.lockstep)),
        }

    def reset_faults(self) -> str | None:
        """Reset a fault the valve latched (RPDO timeout, ...), as an operator would after
        removing its cause: CiA 408 reset-fault edge. Returns what was reset, None if nothing
        was latched; raises :class:`NodeError` if the fault stays."""
        if self.master is None:
            raise StandError("the gateway is not connected; use it as a context manager")
        return self.master.reset_valve_fault()

    def run(self, experiment: Experiment, out: str | Path, progress: bool | None = None,
            on_progress: Callable[[float], None] | None = None,
            reset_faults: bool = False) -> RunResult:
        """Run one experiment and record it in the run directory ``out``.

        ``progress``: True/False forces the progress bar on/off; None shows it for runs of more
        than a few seconds of stand time when stderr is a terminal. ``reset_faults``: first
        reset a fault the valve latched (:meth:`reset_faults`; run.json ``fault_reset``)."""
        if self.loop is None:
            raise StandError("the gateway is not connected; use it as a context manager")
        fault_reset = self.reset_faults() if reset_faults else None
        recorder = RunRecorder(out, self.metadata(experiment))
        capture = BusCapture(recorder.capture_path)
        # first in line, so frames reach the capture in the order they were received
        self.network.notifier.listeners.insert(0, capture)
        self.network.capture = capture
        bar = None
        if progress or (progress is None and experiment.duration_s > 3.0):
            bar = tqdm(total=round(experiment.max_duration_s, 1), unit="s", unit_scale=False,
                       desc=f"{experiment.name}", leave=False, disable=None if progress is None else not progress,
                       bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total} s stand time [{elapsed}<{remaining}]")
        shown = [0.0]

        def tick(t: float) -> None:
            if bar is not None and t - shown[0] >= 0.1:
                bar.update(t - shown[0])
                shown[0] = t
            if on_progress is not None:
                on_progress(t)

        outcome = None
        scheduling: dict | None = None
        failure: BaseException | None = None
        try:
            self.master.declare_run(self.config.period_s)
            with steady_heap():   # before the valve's RPDO timeout starts running
                self.master.start()
                if self.config.lockstep:     # wall-clock timing does not matter
                    outcome = self.loop.run(experiment, recorder, tick)
                else:
                    # every thread of the process, not only the loop's (see process_threads)
                    with realtime_threads(self.config.rt_priority, process_threads()) as scheduling, \
                            short_gil_slices():
                        outcome = self.loop.run(experiment, recorder, tick)
        except BaseException as exc:
            failure = exc
            raise
        finally:
            if bar is not None:
                if outcome is not None and outcome.status == "complete":
                    bar.update(bar.total - bar.n)
                bar.close()
            try:
                self.master.enter_preoperational()
            finally:
                self.network.capture = None
                self.network.notifier.remove_listener(capture)
                capture.stop()
                stats = self.loop.stats
                supervisor = self.loop.supervisor
                if outcome is not None:
                    status, reason, message = outcome.status, outcome.reason, outcome.message
                elif isinstance(failure, KeyboardInterrupt):
                    status, reason = "aborted", "interrupted"
                    message = "interrupted (Ctrl-C or SIGTERM); the valve was set to hold, zero command"
                else:
                    status, reason = "aborted", "gateway_error"
                    message = ("the gateway raised an error"
                               + (f": {type(failure).__name__}: {failure}" if failure else "")
                               + "; the valve was set to hold, zero command")
                extra = {}
                if fault_reset is not None:
                    extra["fault_reset"] = fault_reset
                if scheduling is not None:
                    extra["realtime"] = scheduling
                if outcome is not None and outcome.safety is not None:
                    extra["safety"] = outcome.safety
                if capture.write_errors:
                    extra["capture_write_errors"] = capture.write_errors
                recorder.close(status=status, end_reason=reason, end_message=message,
                               stats=_stats_dict(stats), capture_frames=capture.frames,
                               emcy=list(supervisor.emcy_log), events=list(supervisor.events),
                               **extra)
        return RunResult(recorder.dir, outcome)


def _stats_dict(stats) -> dict[str, Any]:
    out = {k: v for k, v in asdict(stats).items() if k != "sync_jitter_s"}
    jitter = stats.sync_jitter_s
    if jitter:
        import numpy as np
        j = np.abs(np.asarray(jitter))
        out["sync_jitter_ms"] = {"p50": float(np.percentile(j, 50) * 1e3),
                                 "p99": float(np.percentile(j, 99) * 1e3), "max": float(j.max() * 1e3)}
    return out
