"""``stand run EXPERIMENT``: run one experiment against whatever stand is on the bus, record it."""
from __future__ import annotations

import argparse
import inspect
import re

from gateway.experiments import EXPERIMENTS, make_experiment

from .common import add_gateway, add_rig, gateway_config, sigterm_as_interrupt


def register(sub) -> None:
    p = sub.add_parser("run", help="run one experiment on the stand and record it",
                       description="Connect to the stand (boot the nodes, check each one's identity "
                                   "object 0x1018 against its EDS, configure them), run one experiment "
                                   "and write a run directory. The run is the data: stand estimate "
                                   "RUN estimates g and τ from it, stand fit and stand diagnose fit "
                                   "models to it.")
    exps = p.add_subparsers(dest="experiment", metavar="EXPERIMENT", required=True)
    for name, klass in EXPERIMENTS.items():
        doc = plain(inspect.getdoc(klass) or "")
        helps = param_help(doc)
        summary = doc.split(":param", 1)[0].strip()
        e = exps.add_parser(name, help=summary.splitlines()[0] if summary else name, description=summary,
                            formatter_class=argparse.RawDescriptionHelpFormatter)
        for pname, param in inspect.signature(klass).parameters.items():
            default = param.default
            shown = "none" if default is None else f"{default:g}" if isinstance(default, float) else default
            e.add_argument("--" + pname.replace("_", "-"), dest=f"x_{pname}", type=float,
                           default=default, metavar=metavar(pname),
                           help=f"{helps.get(pname, pname.replace('_', ' '))} (default {shown})".replace("%", "%%"))
        add_gateway(e)
        add_rig(e)
        e.add_argument("--out", required=True, metavar="DIR", help="run directory to create")
        e.add_argument("--no-progress", action="store_true", help="no progress bar")
        e.add_argument("--reset-faults", action="store_true",
                       help="before the run, reset a fault the valve latched (CiA 408 reset-fault "
                            "edge); only once its cause is gone")
        e.set_defaults(func=main)


#: a parameter's unit suffix -> the metavar its option shows
_METAVARS = {"pct": "PCT", "s": "S", "kgf": "KGF", "hz": "HZ", "rad_s": "RAD_PER_S", "fraction": "X"}


def metavar(pname: str) -> str:
    for suffix, shown in _METAVARS.items():
        if pname.endswith("_" + suffix):
            return shown
    return "N" if pname in ("cycles", "periods") else "X"


def plain(doc: str) -> str:
    """A docstring as help text: reST literals and roles as plain words."""
    doc = re.sub(r":(?:mod|class|func|meth|attr|data):`~?([^`]+)`", r"\1", doc)
    return doc.replace("``", "")


def param_help(doc: str) -> dict[str, str]:
    """``:param name: text`` lines of a docstring (text continued on indented lines)."""
    out: dict[str, str] = {}
    for m in re.finditer(r"^:param (\w+): (.*(?:\n(?!:param)\s+\S.*)*)", doc, re.M):
        out[m.group(1)] = " ".join(m.group(2).split())
    return out


def main(args: argparse.Namespace) -> int:
    from gateway import Gateway
    params = {k[2:]: v for k, v in vars(args).items() if k.startswith("x_")}
    experiment = make_experiment(args.experiment, params)
    config = gateway_config(args)
    from gateway.session import driven_channels
    driven_channels(config.rig, args.channel)     # before anything is connected
    with sigterm_as_interrupt(), Gateway(config) as gw:
        result = gw.run(experiment, args.out, progress=False if args.no_progress else None,
                        reset_faults=args.reset_faults, channels=args.channel)
    stats = result.outcome.stats
    print(f"run {result.status}: {stats.cycles} cycles, {stats.stale_cycles} stale, "
          f"{stats.overruns} overruns -> {result.path}")
    ignored = stats.unexpected_frames + stats.wrong_dlc_frames + stats.not_classic_frames
    if ignored:
        print(f"ignored {ignored} frames: {stats.unexpected_frames} from unexpected ids, "
              f"{stats.wrong_dlc_frames} with a wrong DLC, {stats.not_classic_frames} error/remote/"
              "extended/FD")
    if config.rig is not None:
        stale = (result.outcome.rig or {}).get("stale_cycles") or {}
        print(f"rig {config.rig.name}: " + ", ".join(
            f"{c.name} ({c.bus}{', driven' if c.name in args.channel else ''}"
            f"{f', {stale[c.name]} stale' if stale.get(c.name) else ''})" for c in config.rig.channels))
    if stats.limit_events:
        print(f"{stats.limit_events} limit events indicated (see run.json 'events')")
    if result.reason:
        safety = result.outcome.safety or {}
        when = ""
        if safety.get("reaction_s") is not None:
            when = (f" [safe state {safety['reaction_s'] * 1e3:.1f} ms after onset, "
                    f"bound {safety['bound_s'] * 1e3:.0f} ms, action {safety['action']}]")
        print(f"stopped early ({result.reason}): {result.outcome.message}{when}")
        return 1
    return 0
