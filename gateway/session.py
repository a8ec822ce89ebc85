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

import contextlib
import copy
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from tqdm import tqdm

from standbus import BusSpecError, open_bus
from standbus.realtime import process_threads, realtime_threads, short_gil_slices

from .capture import (BATCH_LOCKSTEP_S, BATCH_REALTIME_S, BusCapture, StartupCapture,
                      TappedNetwork)
from .errors import NodeError, ParameterError, StandError
from .config import GatewayConfig
from .experiments import Experiment
from .experiments.rig import RigExperiment, is_rig_experiment
from .loop import (ControlLoop, LoopChannel, LoopOutcome, RigSafety, steady_heap, sync_window_s,
                   takes_buses_over)
from .master import StandMaster, boot_all, start_all
from .recorder import RunRecorder
from .runs import CAPTURE_FILE, DBC_FILE, SIGNALS_FILE, capture_file
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
    """Connects (open bus, boot, identify, configure the nodes) on enter; runs experiments.

    With ``config.rig`` it is the master of a rig: before anything is opened each bus's load per
    cycle is checked against the rig's limit (:mod:`rig.budget`; over it the rig is refused with
    the figures and what would fit), then every bus is opened, every channel's nodes boot
    together, and one loop drives them all (:class:`ControlLoop`), one SYNC per bus per cycle."""

    def __init__(self, config: GatewayConfig | None = None) -> None:
        self.config = config or GatewayConfig()
        self.config.validate()
        self.networks: list[TappedNetwork] = []
        self.masters: list[StandMaster] = []
        self.loop: ControlLoop | None = None
        #: a rig: each bus's budget, checked before anything is opened
        self.budgets: list | None = None
        #: each bus's start-up traffic (boot, identity, configuration): every run's capture
        #: begins with it (run.json ``startup`` says how many frames)
        self.startup: list[StartupCapture] = []

    @property
    def network(self) -> TappedNetwork | None:
        return self.networks[0] if self.networks else None

    @property
    def master(self) -> StandMaster | None:
        return self.masters[0] if self.masters else None

    @property
    def rig(self):
        return self.config.rig

    def __enter__(self) -> "Gateway":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- connect ---------------------------------------------------------------------------------
    def _bus_specs(self) -> list[str]:
        rig = self.rig
        return [self.config.bus] if rig is None else [b.spec for b in rig.buses]

    def check_budget(self) -> None:
        """A rig: refuse it, before any bus is opened, if a bus cannot carry its channels at
        the rig's period (:func:`rig.budget.bus_budgets`)."""
        if self.rig is None:
            return
        from rig.budget import bus_budgets
        self.budgets = bus_budgets(self.rig)
        problems = [b.problem() for b in self.budgets if not b.fits]
        if problems:
            raise StandError(f"{self.rig.where}: the rig does not fit its buses; nothing was "
                             "started:\n  " + "\n  ".join(problems))

    def open(self) -> None:
        self.check_budget()
        # the loop takes the buses from their reader threads at every run (<= one cycle: in
        # real time, on a rig, the valves' RPDO timeouts already run by then)
        notifier_cycle_s = 0.005 if takes_buses_over(self.config.lockstep, self.rig is not None) else None
        kinds = [(False, False)] if self.rig is None else \
            [(b.fd, b.fd and bool(b.data_bitrate) and b.data_bitrate != b.bitrate) for b in self.rig.buses]
        try:
            for spec, (fd, brs) in zip(self._bus_specs(), kinds):
                try:
                    bus = open_bus(spec)
                except BusSpecError as exc:
                    raise StandError(str(exc)) from None
                network = TappedNetwork(bus, notifier_cycle_s=notifier_cycle_s, fd=fd,
                                        bitrate_switch=brs)
                self.networks.append(network)
                network.connect()
            self.startup = [StartupCapture() for _ in self.networks]
            for network, startup in zip(self.networks, self.startup):
                startup.attach(network)
            try:
                self._connect()
            finally:
                for network, startup in zip(self.networks, self.startup):
                    startup.detach(network)
        except BaseException:
            self.close()
            raise

    def _channels(self) -> list[tuple[str, int, int, int, Any]]:
        """(name, bus index, valve id, dynamometer id, devices) of every channel."""
        rig = self.rig
        if rig is None:
            return [("", 0, self.config.valve_id, self.config.dynamometer_id, self.config.devices)]
        index = {b.name: i for i, b in enumerate(rig.buses)}
        return [(c.name, index[c.bus], c.valve_id, c.dynamometer_id, c.devices) for c in rig.channels]

    def _connect(self) -> None:
        cfg = self.config
        plan = self._channels()
        self.masters = [StandMaster(self.networks[bus], valve, dyn, cfg.sdo_timeout_s, devices)
                        for _, bus, valve, dyn, devices in plan]
        with self._naming_channel(None):
            boot_all(self.masters, cfg.boot_timeout_s)
        for i, master in enumerate(self.masters):
            with self._naming_channel(i):
                master.check_identity()
                master.configure(cfg.period_s, cfg.heartbeat_ms, cfg.rpdo_timeout_ms,
                                 cfg.life_time_factor())
        if cfg.lockstep and not all(m.lockstep_capable for m in self.masters):
            raise StandError(
                "--lockstep needs a stand that advances one period per SYNC (the emulator "
                "started with --lockstep); this stand runs in real time. Drop --lockstep.")
        if self.rig is None:
            supervisor = Supervisor(self.master, cfg.limits, cfg.period_s, cfg.lockstep)
            self.loop = ControlLoop(self.network, self.master, supervisor, cfg.period_s, cfg.lockstep)
            return
        channels = []
        for (name, bus, _, _, _), master, ch in zip(plan, self.masters, self.rig.channels):
            sup = Supervisor(master, cfg.channel_limits(ch), cfg.period_s, cfg.lockstep)
            channels.append(LoopChannel(name, master, sup, bus, ch.range_kgf))
        self.loop = ControlLoop(self.network, self.master, channels[0].supervisor, cfg.period_s,
                                cfg.lockstep, channels=channels, networks=self.networks,
                                rig_safety=RigSafety(cfg.fault_action, self.rig.G))

    @contextlib.contextmanager
    def _naming_channel(self, index: int | None) -> Iterator[None]:
        """A rig: a node error names the channel (and its bus) it belongs to; ``index`` None
        while booting: the first channel with a node that did not boot."""
        try:
            yield
        except NodeError as exc:
            if self.rig is None:
                raise
            i = index
            if i is None:
                i = next((k for k, m in enumerate(self.masters)
                          if any(not l.booted.is_set() for l in m.links)), None)
            if i is None:
                raise
            ch = self.rig.channels[i]
            raise NodeError(exc.node_id, f"channel {ch.name} (bus {ch.bus}): {exc}") from None

    def close(self) -> None:
        if self.loop is not None:
            self.loop.close()
            self.loop = None
        for master in self.masters if self.networks else ():
            try:
                master.enter_preoperational()
            except Exception:
                pass
            master.close()
        for network in self.networks:
            try:
                network.disconnect()
            except Exception:
                pass
        self.networks = []

    # -- run -------------------------------------------------------------------------------------
    def metadata(self, experiment: Experiment, driven: Sequence[str] = ()) -> dict[str, Any]:
        cfg = self.config
        if self.rig is not None:
            return self._rig_metadata(experiment, driven)
        m = self.master
        return {
            "experiment": {"name": experiment.name, "params": experiment.params()},
            "bus": cfg.bus,
            "clock": "lockstep" if cfg.lockstep else "realtime",
            "period_s": cfg.period_s,
            "nodes": {link.role: {"id": link.id, "identity": link.identity} for link in m.links},
            "force_scale_kgf_per_count": m.force_scale_kgf,
            "devices": m.describe(),
            "device_notes": m.notes(),
            "startup": self._startup_meta(0),
            "limits": asdict(cfg.limits.resolved(cfg.lockstep)),
        }

    def _startup_meta(self, bus: int) -> dict | None:
        """What of a bus's capture is the start-up: its first ``frames`` frames, up to ``until``
        (the wall-clock stamp of the last)."""
        if bus >= len(self.startup):
            return None
        s = self.startup[bus]
        return {"frames": s.frames, "until": s.last_stamp}

    def _rig_metadata(self, experiment: Experiment, driven: Sequence[str]) -> dict[str, Any]:
        cfg, rig = self.config, self.rig
        budgets = {b.bus.name: b.to_dict() for b in (self.budgets or [])}
        limits = asdict(cfg.limits.resolved(cfg.lockstep))
        limits["force_limit_kgf"] = None      # per channel: rig.channels[].force_limit_kgf
        channels = []
        for ch, m in zip(rig.channels, self.masters):
            channels.append({
                "name": ch.name, "bus": ch.bus,
                "nodes": {link.role: {"id": link.id, "identity": link.identity} for link in m.links},
                "range_kgf": ch.range_kgf, "force_limit_kgf": ch.limit_kgf,
                "force_scale_kgf_per_count": m.force_scale_kgf, "driven": ch.name in driven,
                "devices": m.describe(), "device_notes": m.notes()})
        return {
            "experiment": {"name": experiment.name, "params": experiment.params()},
            "clock": "lockstep" if cfg.lockstep else "realtime",
            "period_s": cfg.period_s,
            "limits": limits,
            "rig": {
                "name": rig.name, "file": str(rig.path) if rig.path else None,
                "period_s": rig.period_s, "heartbeat_ms": rig.heartbeat_ms,
                "G": rig.G.tolist() if rig.G is not None else None,
                "structure_from": rig.structure_from,
                "bus_load_limit_pct": 100 * rig.bus_load_limit,
                "fault_action": cfg.fault_action,
                "buses": [{"name": b.name, "spec": b.spec, "bitrate": b.bitrate, "fd": b.fd,
                           "data_bitrate": b.data_bitrate, "capture": capture_file(b.name),
                           "budget": budgets.get(b.name), "startup": self._startup_meta(i)}
                          for i, b in enumerate(rig.buses)],
                "channels": channels,
                "driven": list(driven),
            },
        }

    def reset_faults(self) -> str | dict[str, str] | None:
        """Reset a fault the valve latched (RPDO timeout, ...), as an operator would after
        removing its cause: CiA 408 reset-fault edge. Returns what was reset, None if nothing
        was latched (a rig: per channel, only those that had one); raises :class:`NodeError`
        if the fault stays."""
        if not self.masters:
            raise StandError("the gateway is not connected; use it as a context manager")
        if self.rig is None:
            return self.master.reset_valve_fault()
        done = {}
        for i, (ch, m) in enumerate(zip(self.rig.channels, self.masters)):
            with self._naming_channel(i):
                what = m.reset_valve_fault()
            if what is not None:
                done[ch.name] = what
        return done or None

    def drivers(self, experiment: Experiment, channels: Sequence[str] | None) -> dict[int, Experiment]:
        """Which channels run ``experiment`` (each its own copy); the others hold a zero
        command. One channel: channel 0, ``channels`` must be None."""
        indices = driven_channels(self.rig, channels)
        return {i: experiment if k == 0 else copy.deepcopy(experiment)
                for k, i in enumerate(indices)}

    def _vector_drivers(self, experiment: RigExperiment, channels: Sequence[str] | None) -> None:
        """A station's experiment drives every channel: refuse ``channels``, and an experiment
        made for other channels (before anything moves): a rig's names its channels, in order;
        on a one-channel stand it is one channel's."""
        names = list(getattr(experiment, "names", [""]))
        if self.rig is None:
            if len(names) != 1:
                raise ParameterError(f"{experiment.name}: the experiment drives the channels "
                                     f"{', '.join(names)}; give --rig RIG.toml (this gateway drives one stand)")
            return None
        if channels:
            raise ParameterError(f"{experiment.name}: a rig experiment drives every channel itself; "
                                 "leave --channel out")
        if names != list(self.rig.names):
            raise ParameterError(f"{experiment.name}: the experiment is for the channels "
                                 f"{', '.join(names)}; the rig {self.rig.where} has "
                                 f"{', '.join(self.rig.names)} (in that order)")
        return None

    def run(self, experiment: Experiment | RigExperiment, out: str | Path | None,
            progress: bool | None = None, on_progress: Callable[[float], None] | None = None,
            reset_faults: bool = False, channels: Sequence[str] | None = None,
            recorder=None) -> RunResult:
        """Run one experiment and record it in the run directory ``out``.

        ``progress``: True/False forces the progress bar on/off; None shows it for runs of more
        than a few seconds of stand time when stderr is a terminal. ``reset_faults``: first
        reset a fault the valve latched (:meth:`reset_faults`; run.json ``fault_reset``).
        ``channels``: a rig's channels the experiment drives (each its own copy of it); every
        other channel holds a zero command. A :class:`~gateway.experiments.rig.RigExperiment`
        (N forces in, N commands out) drives every channel at once: no ``channels``.
        ``recorder``: record the run with this object instead of a run directory (one with
        :class:`RunRecorder`'s ``append_cycle``, ``poll``, ``close(**meta)`` and ``dir``: an
        endurance test's rolling window, :mod:`endurance.run`); ``out`` is then not used and
        no bus capture is written."""
        if self.loop is None:
            raise StandError("the gateway is not connected; use it as a context manager")
        if is_rig_experiment(experiment):
            drivers = self._vector_drivers(experiment, channels)
            driven = list(self.rig.names) if self.rig is not None else []
        else:
            drivers = self.drivers(experiment, channels)
            driven = [self.rig.names[i] for i in sorted(drivers)] if self.rig is not None else []
        fault_reset = self.reset_faults() if reset_faults else None
        batch_s = BATCH_LOCKSTEP_S if self.config.lockstep else BATCH_REALTIME_S
        if recorder is not None:
            captures = []
        elif self.rig is None:
            dbcs = self._dbc_texts()
            files = {"signals": SIGNALS_FILE, "capture": CAPTURE_FILE}
            if dbcs:
                files["dbc"] = DBC_FILE
            recorder = RunRecorder(out, self.metadata(experiment), files=files)
            self._write_dbcs(recorder.dir, {DBC_FILE: text for text in dbcs.values()})
            captures = [BusCapture(recorder.capture_path, batch_s=batch_s)]
        else:
            dbcs = self._dbc_texts()
            files = {"signals": SIGNALS_FILE,
                     "captures": {b.name: capture_file(b.name) for b in self.rig.buses}}
            if dbcs:
                files["dbc"] = {name: f"{name}.dbc" for name in dbcs}
            recorder = RunRecorder(out, self.metadata(experiment, driven), channels=self.rig.names,
                                   files=files)
            self._write_dbcs(recorder.dir, {f"{name}.dbc": text for name, text in dbcs.items()})
            captures = [BusCapture(recorder.capture_path_of(b.name), batch_s=batch_s)
                        for b in self.rig.buses]
        for network, capture, startup in zip(self.networks, captures, self.startup):
            capture.write_first(startup)       # the start-up's traffic first
            # first in line, so frames reach the capture in the order they were received
            capture.attach(network)
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
            window = sync_window_s(self.config.period_s, self.config.lockstep)
            for master in self.masters:
                master.declare_run(self.config.period_s, window)
            with steady_heap():   # before the valves' RPDO timeouts start running
                start_all(self.masters)
                if self.config.lockstep:     # wall-clock timing does not matter
                    outcome = self.loop.run(experiment, recorder, tick, drivers=drivers)
                else:
                    # every thread of the process, not only the loop's (see process_threads)
                    with realtime_threads(self.config.rt_priority, process_threads()) as scheduling, \
                            short_gil_slices():
                        outcome = self.loop.run(experiment, recorder, tick, drivers=drivers)
        except BaseException as exc:
            failure = exc
            raise
        finally:
            if bar is not None:
                if outcome is not None and outcome.status == "complete":
                    bar.update(bar.total - bar.n)
                bar.close()
            try:
                for master in self.masters:
                    master.enter_preoperational()
            finally:
                for network, capture in zip(self.networks, captures):
                    capture.detach(network)
                    capture.stop()
                self._close_run(recorder, captures, outcome, failure, fault_reset, scheduling)
        return RunResult(recorder.dir, outcome)

    def _dbc_texts(self) -> dict[str, str]:
        """The stand's DBC for each channel whose devices are not the emulated pair (by channel
        name; a stand's under ""): a capture of the run is then decoded with it
        (:func:`captures.decode.run_dbc`)."""
        from devices.dbcfile import stand_dbc
        out = {}
        for i, m in enumerate(self.masters):
            if m.devices.is_default:
                continue
            name = self.rig.channels[i].name if self.rig is not None else ""
            out[name] = stand_dbc(m.valve.setup.plan, m.dynamometer.setup.plan,
                                  m.force_scale_kgf, m.setpoint.full_scale)
        return out

    @staticmethod
    def _write_dbcs(run_dir: Path, texts: dict[str, str]) -> None:
        for name, text in texts.items():
            (run_dir / name).write_text(text)

    def _close_run(self, recorder: RunRecorder, captures: list[BusCapture],
                   outcome: LoopOutcome | None, failure: BaseException | None,
                   fault_reset, scheduling: dict | None) -> None:
        loop = self.loop
        stats = loop.stats
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
        if self.rig is not None and outcome is None:
            message = message.replace("the valve was set", "every valve was set")
        extra: dict[str, Any] = {}
        if fault_reset is not None:
            extra["fault_reset"] = fault_reset
        if scheduling is not None:
            extra["realtime"] = scheduling
        if outcome is not None and outcome.safety is not None:
            extra["safety"] = outcome.safety
        write_errors = sum(c.write_errors for c in captures)
        if write_errors:
            extra["capture_write_errors"] = write_errors
        stats_dict = _stats_dict(stats)
        if self.rig is None:
            sup = loop.supervisor
            frames: Any = captures[0].frames if captures else None
            emcy, events = list(sup.emcy_log), list(sup.events)
        else:
            frames = {b.name: c.frames for b, c in zip(self.rig.buses, captures)}
            emcy, events = [], []
            for ch in loop.channels:
                emcy += [dict(e, channel=ch.name) for e in ch.supervisor.emcy_log]
                events += [dict(e, channel=ch.name) for e in ch.supervisor.events]
            emcy.sort(key=lambda e: e.get("time", 0.0))
            events.sort(key=lambda e: e.get("time", 0.0))
            if outcome is not None and outcome.rig:
                stats_dict["stale_cycles_by_channel"] = outcome.rig["stale_cycles"]
        recorder.close(status=status, end_reason=reason, end_message=message,
                       stats=stats_dict, capture_frames=frames, emcy=emcy, events=events, **extra)


def driven_channels(rig, channels: Sequence[str] | None) -> list[int]:
    """The indices of the channels an experiment drives on ``rig`` (None: the one-channel
    stand, channel 0); a clear :class:`ParameterError` for a missing, unknown or repeated name,
    so a command line can check it before anything is connected."""
    if rig is None:
        if channels:
            raise ParameterError("--channel names a channel of a rig: give --rig RIG.toml too "
                                 "(a one-channel stand has no channels to choose)")
        return [0]
    if not channels:
        raise ParameterError(f"{rig.where}: choose the channel(s) the experiment drives with "
                             f"--channel NAME (repeat it for several); the others hold a zero "
                             f"command. The rig's channels: {', '.join(rig.names)}")
    out: list[int] = []
    for name in channels:
        rig.channel(name)          # a clear error for an unknown name
        i = rig.names.index(name)
        if i in out:
            raise ParameterError(f"--channel {name} given twice")
        out.append(i)
    return out


def _stats_dict(stats) -> dict[str, Any]:
    import numpy as np
    out = {k: v for k, v in asdict(stats).items()
           if k not in ("sync_jitter_s", "answer_window_min_s", "behind_s")}
    if math.isfinite(stats.answer_window_min_s):    # real time
        out["answer_window_min_ms"] = stats.answer_window_min_s * 1e3
        out["cycles_begun_behind"] = sum(1 for b in stats.behind_s if b > 0)
    for key, values in (("sync_jitter_ms", stats.sync_jitter_s), ("begun_behind_ms", stats.behind_s)):
        if values:
            v = np.abs(np.asarray(values)) * 1e3
            out[key] = {"p50": float(np.percentile(v, 50)), "p99": float(np.percentile(v, 99)),
                        "max": float(v.max())}
    return out
