"""Options shared by several sub-commands."""
from __future__ import annotations

import argparse
import contextlib
import signal
import sys
from typing import Iterator

from dbc import profile as P
from core.errors import ParameterError
from gateway.config import GatewayConfig
from gateway.limits import ACTIONS, ERROR_LIMIT_MIN_KGF, ERROR_LIMIT_SHARE, SafetyLimits
from standbus.realtime import DEFAULT_PRIORITY
from standbus.spec import DEFAULT_BUS


def add_bus(p: argparse.ArgumentParser, default: str | None = DEFAULT_BUS) -> None:
    p.add_argument("--bus", default=default, metavar="SPEC",
                   help="python-can bus as INTERFACE:CHANNEL[,key=value...], e.g. "
                        "udp_loopback:stand0 (default: %(default)s), socketcan:vcan0, "
                        "pcan:PCAN_USBBUS1,bitrate=1000000")


def add_node_ids(p: argparse.ArgumentParser) -> None:
    p.add_argument("--valve-id", type=int, default=P.VALVE_NODE_ID, metavar="ID", help="servo-valve node id (default %(default)s)")
    p.add_argument("--dynamometer-id", type=int, default=P.DYNAMOMETER_NODE_ID, metavar="ID",
                   help="dynamometer node id (default %(default)s)")
    p.add_argument("--devices", metavar="DEVICES.toml",
                   help="which valve drive and force amplifier the stand has: a device file naming "
                        "each one's EDS and the objects it uses (docs/devices.md; examples in "
                        "examples/devices/). Default: the emulated pair (dbc/)")


def id_args(args: argparse.Namespace) -> list[str]:
    """The node ids of ``args`` as options for an emulator started with them (none where they
    are the defaults)."""
    out = []
    if args.valve_id != P.VALVE_NODE_ID:
        out += ["--valve-id", str(args.valve_id)]
    if args.dynamometer_id != P.DYNAMOMETER_NODE_ID:
        out += ["--dynamometer-id", str(args.dynamometer_id)]
    return out


def device_set(args: argparse.Namespace):
    """The device set of ``--devices`` (None: the emulated pair); a clear error if it cannot
    be used."""
    path = getattr(args, "devices", None)
    if path is None:
        return None
    from devices import load_device_set
    return load_device_set(path)


def add_gateway(p: argparse.ArgumentParser, error_limit: str = "off") -> None:
    """The gateway's options; ``error_limit``: what the error detector is without --error-limit
    (as the help says it)."""
    add_bus(p)
    add_node_ids(p)
    p.add_argument("--period-ms", type=float, default=None, metavar="MS",
                   help="control period, ms (default 2; a rig: its file's period_ms)")
    p.add_argument("--lockstep", action="store_true",
                   help="send the next SYNC as soon as a cycle is done (needs the emulator with --lockstep)")
    p.add_argument("--boot-timeout", type=float, default=5.0, metavar="S",
                   help="seconds to wait for the nodes' boot-up (default %(default)s)")
    p.add_argument("--sdo-timeout", type=float, default=GatewayConfig.sdo_timeout_s * 1e3, metavar="MS",
                   help="how long to wait for a node's SDO answer while setting up, ms "
                        "(default %(default)g; raise it on a slow host)")
    add_rt_priority(p, "real time: run the control loop and bus reader threads")
    add_safety(p, error_limit)


def programme_error_limit(of: str) -> str:
    """The error detector's default for a loading programme, as the help says it (``of``: whose
    range: gateway.limits.programme_error_limit_kgf)."""
    return f"{100 * ERROR_LIMIT_SHARE:g} %% of {of}, at least {ERROR_LIMIT_MIN_KGF:g} kgf"


def add_rt_priority(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--rt-priority", type=int, default=DEFAULT_PRIORITY, metavar="N",
                   help=f"{what} at SCHED_FIFO priority N (1-99) where the host allows it (Linux, "
                        "root or CAP_SYS_NICE); 0: ordinary scheduling (default %(default)s)")


def add_safety(p: argparse.ArgumentParser, error_limit: str = "off") -> None:
    """The supervisor's limits and reactions (docs/safety.md); ``error_limit``: the error
    detector's default as the help says it."""
    d = SafetyLimits()
    g = p.add_argument_group("safety (see docs/safety.md)")
    g.add_argument("--force-limit", type=float, default=None, metavar="KGF",
                   help=f"force limit ±KGF (default {d.force_limit_kgf:g}; a rig: each channel's "
                        "force_limit_kgf in the rig file)")
    g.add_argument("--limit-action", choices=ACTIONS, default=d.force_action,
                   help="what the force limit does: indicate (log, go on), hold (valve HOLD, zero "
                        "command), unload (ramp the force to ~0, then hold), zero (zero command, "
                        "valve DISABLED) (default %(default)s)")
    g.add_argument("--command-limit", type=float, default=d.command_limit_pct, metavar="PCT",
                   help="clamp the valve command to ±PCT %% (default %(default)s)")
    g.add_argument("--slew-limit", type=float, default=d.slew_pct_per_s, metavar="PCT_PER_S",
                   help="limit the command's rate of change, %%/s (default: none)")
    g.add_argument("--error-limit", type=float, default=d.error_limit_kgf, metavar="KGF",
                   help="error detector: |reference - force| beyond KGF for --error-time trips "
                        f"(closed-loop experiments; default: {error_limit})")
    g.add_argument("--error-time", type=float, default=d.error_time_s, metavar="S",
                   help="how long the error must persist, s (default %(default)s)")
    g.add_argument("--error-action", choices=ACTIONS, default=d.error_action,
                   help="what the error detector does (default %(default)s)")
    g.add_argument("--stale-cycles", type=int, default=d.stale_cycles, metavar="N",
                   help="safe state after N cycles without a fresh force PDO (default %(default)s)")
    g.add_argument("--heartbeat-timeout", type=float, default=None, metavar="MS",
                   help="safe state when a node's heartbeat is older than MS (default 350 in real "
                        "time, 1000 in lockstep)")
    g.add_argument("--overrun-limit", type=float, default=d.overrun_limit_s * 1e3, metavar="MS",
                   help="real time: safe state when a cycle starts more than MS late (default %(default)g)")
    g.add_argument("--rpdo-timeout", type=int, default=GatewayConfig.rpdo_timeout_ms, metavar="MS",
                   help="the valve's own watchdog: fail-safe when no command for MS (0: off; "
                        "default %(default)s)")
    g.add_argument("--unload-rate", type=float, default=d.unload_rate_kgf_per_s, metavar="KGF_PER_S",
                   help="controlled unload: force ramp rate (default %(default)s)")


def safety_limits(args: argparse.Namespace) -> SafetyLimits:
    d = SafetyLimits()
    get = lambda name, default: getattr(args, name, default)  # noqa: E731
    force_limit = get("force_limit", None)
    return SafetyLimits(
        force_limit_kgf=d.force_limit_kgf if force_limit is None else force_limit,
        force_action=get("limit_action", d.force_action),
        command_limit_pct=get("command_limit", d.command_limit_pct),
        slew_pct_per_s=get("slew_limit", d.slew_pct_per_s),
        error_limit_kgf=get("error_limit", d.error_limit_kgf),
        error_time_s=get("error_time", d.error_time_s),
        error_action=get("error_action", d.error_action),
        stale_cycles=get("stale_cycles", d.stale_cycles),
        heartbeat_timeout_s=None if get("heartbeat_timeout", None) is None else args.heartbeat_timeout / 1e3,
        overrun_limit_s=get("overrun_limit", d.overrun_limit_s * 1e3) / 1e3,
        unload_rate_kgf_per_s=get("unload_rate", d.unload_rate_kgf_per_s))


def add_rig(p: argparse.ArgumentParser) -> None:
    """--rig, --channel, --fault-action: run on a rig of many channels (docs/rig.md)."""
    g = p.add_argument_group("a rig of many channels (see docs/rig.md)")
    g.add_argument("--rig", metavar="RIG.toml",
                   help="drive a rig: its buses, channels (node ids, force limits) and period come "
                        "from the file (--bus, --valve-id, --dynamometer-id are not used); every "
                        "channel is recorded, one capture per bus")
    g.add_argument("--channel", action="append", default=None, metavar="NAME",
                   help="with --rig: the channel the experiment drives; the others hold a zero "
                        "command (a column of G, docs/rig.md). Repeat it to drive several with "
                        "the same experiment (each its own copy: the same excitation, so their "
                        "columns of G cannot be told apart from such a run)")
    g.add_argument("--fault-action", choices=("hold", "unload"), default="hold",
                   help="with --rig: what a channel's communication or valve fault (heartbeat, "
                        "EMCY, stale reading, valve fault) or an overrun does: hold every channel, "
                        "or unload them keeping the load ratios while the faulty channel holds "
                        "(default %(default)s; force and error limits act with --limit-action "
                        "and --error-action on every channel)")


def gateway_config(args: argparse.Namespace) -> GatewayConfig:
    rig_path = getattr(args, "rig", None)
    rig = None
    period_ms = getattr(args, "period_ms", None)
    if rig_path is not None:
        from rig.config import load_rig_file
        rig = load_rig_file(rig_path)
        if period_ms is not None and abs(period_ms / 1e3 - rig.period_s) > 1e-9:
            raise ParameterError(f"--period-ms {period_ms:g}: the rig {rig_path} runs at "
                                 f"{rig.period_s * 1e3:g} ms (period_ms in the file); leave "
                                 "--period-ms out or change the file")
        if getattr(args, "devices", None) is not None:
            raise ParameterError(f"--devices: a rig's devices are in its file (devices = \"FILE\" "
                                 f"in {rig_path}, for the rig or per channel); leave --devices out")
        if getattr(args, "force_limit", None) is not None:
            raise ParameterError("--force-limit: a rig's force limits are per channel "
                                 f"(force_limit_kgf of each [[channel]] in {rig_path}, default 95 % "
                                 "of its range_kgf); leave --force-limit out")
    elif getattr(args, "channel", None):
        raise ParameterError("--channel names a channel of a rig: give --rig RIG.toml too")
    return GatewayConfig(bus=args.bus, valve_id=args.valve_id, dynamometer_id=args.dynamometer_id,
                         period_s=(2.0 if period_ms is None else period_ms) / 1000.0,
                         lockstep=args.lockstep,
                         boot_timeout_s=args.boot_timeout,
                         sdo_timeout_s=args.sdo_timeout / 1e3,
                         rt_priority=getattr(args, "rt_priority", DEFAULT_PRIORITY),
                         rpdo_timeout_ms=getattr(args, "rpdo_timeout", GatewayConfig.rpdo_timeout_ms),
                         limits=safety_limits(args), rig=rig,
                         fault_action=getattr(args, "fault_action", "hold"),
                         devices=None if rig is not None else device_set(args))


def add_effects(p: argparse.ArgumentParser) -> None:
    """--effects: the user's effect plug-ins (plant.plugins), loaded before the command runs."""
    p.add_argument("--effects", action="append", dest="plugin_sources", default=[],
                   metavar="FILE.py|DIR|MODULE",
                   help="load effects of your own (a .py file, a directory of them or a module "
                        "name; repeatable): they join the catalogue for this command "
                        "(docs/your-own-effect.md; `stand effects --new NAME` starts one)")


def load_effects(args: argparse.Namespace) -> list[str]:
    """Load the installed plug-ins (entry points ``hydrostand.effects``) and those of
    ``--effects``; say on stderr what the checks found worth a note."""
    from plant import plugins
    names = plugins.load_installed() + plugins.load_plugins(args.plugin_sources)
    for warning in plugins.WARNINGS:
        print(f"note: {warning}", file=sys.stderr)
    plugins.WARNINGS.clear()
    return names


def parse_assignments(items: list[str] | None, what: str = "--set") -> dict[str, float]:
    """``["g=100", "reversal.boost=0"]`` → ``{"g": 100.0, "reversal.boost": 0.0}``."""
    out: dict[str, float] = {}
    for item in items or []:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise ParameterError(f"{what} {item!r}: write NAME=VALUE, e.g. {what} g=120")
        try:
            out[key.strip()] = float(value)
        except ValueError:
            raise ParameterError(f"{what} {item!r}: {value!r} is not a number") from None
    return out


def add_rig_channel(p: argparse.ArgumentParser) -> None:
    """--channel for the analysis commands: which channel of a rig run to read."""
    p.add_argument("--channel", metavar="NAME",
                   help="a rig run: the channel to read (each channel is read as a one-channel "
                        "run; a rig run without it is refused with the list of its channels)")


def load_records(paths, channel: str | None = None) -> list:
    """The data sets of ``paths`` (CSV, run directories, captures), each one's notes (rows
    dropped, resampling, glitches replaced) printed to stderr: what was changed is said.
    ``channel``: the channel of a rig run."""
    from analysis import load_all
    records = load_all(paths, channel)
    for rec in records:
        for note in rec.notes:
            print(f"note: {rec.source}: {note}", file=sys.stderr)
    return records


def _terminate(signum, frame) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM (kill, systemd, a test harness) ends what runs inside like Ctrl-C: the gateway
    brings the valves to their safe state and closes the run (end_reason "interrupted"), never
    a half-written run. The previous handler comes back afterwards."""
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def rig_inputs(paths: list[str]) -> bool:
    """True if the inputs are rig runs (all of them); a mix with one-channel inputs is refused."""
    from analysis.rig.load import is_rig_input
    from core.errors import ParameterError
    flags = [is_rig_input(p) for p in paths]
    if any(flags) and not all(flags):
        rig = [p for p, f in zip(paths, flags) if f]
        one = [p for p, f in zip(paths, flags) if not f]
        raise ParameterError(f"{', '.join(rig)} {'is a rig run' if len(rig) == 1 else 'are rig runs'}"
                             f" but {', '.join(one)} {'is' if len(one) == 1 else 'are'} not: give "
                             "the runs of one rig together, one-channel data apart")
    return bool(flags) and all(flags)


def load_rig_records(paths: list[str]) -> list:
    """The rig records of ``paths``, what loading changed said on stderr."""
    from analysis.rig.load import load_rig_inputs
    records = load_rig_inputs(paths)
    for rec in records:
        for note in rec.notes:
            print(f"note: {rec.source}: {note}", file=sys.stderr)
        for name, ch in zip(rec.names, rec.channels):
            for note in ch.notes:
                print(f"note: {rec.source} [{name}]: {note}", file=sys.stderr)
    return records
