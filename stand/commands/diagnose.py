"""``stand diagnose DATA...``: which catalogue effect does the model miss?"""
from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from .common import load_records, load_rig_records, rig_inputs
from .compare import default_out
from .fit import add_data_args, check_window, print_json

if TYPE_CHECKING:
    from analysis.diagnosis.rig import RigDiagnosis


def register(sub) -> None:
    from analysis.defaults import MAX_EFFECTS, VERDICTS
    verdicts = "; ".join(f"{v} ({what})" for v, what in VERDICTS.items())
    p = sub.add_parser("diagnose", help="find the effect the model is missing (or say it is adequate)",
                       description="Fit the model (default: the paper's base model), then add every "
                                   "diagnosable catalogue effect in turn, refit, and rank them by how "
                                   f"much they lower the windowed error. Verdict: {verdicts}; with "
                                   "the residual pattern in plain words and warnings when the data "
                                   "cannot separate two explanations.")
    add_data_args(p, model_required=False, channel=False)
    p.add_argument("--candidates", metavar="A,B,...",
                   help="only try these effects (default: every diagnosable one not in the "
                        "model, the catalogue's and those of --effects)")
    p.add_argument("--plots", metavar="DIR", nargs="?", const="",
                   help="also write plots (default directory diagnose-<data>)")
    p.add_argument("--json", action="store_true",
                   help='print {"verdict", "base": {"rmse", ...}, "candidates": [{"effect", "rmse", '
                        '"improvement", ...}], "unexplained": {...} or null, ...} as JSON')
    p.add_argument("--stepwise", action="store_true",
                   help="build the model up: add the best effect, diagnose again, until the model "
                        "is within the noise (for data that miss several effects at once); then "
                        "check each added effect with the others in place. It ends adequate, "
                        "varies_between_records, unexplained or at --max-effects")
    p.add_argument("--max-effects", type=int, default=MAX_EFFECTS, metavar="N",
                   help=f"with --stepwise: add at most N effects (default {MAX_EFFECTS})")
    p.add_argument("--save", metavar="FILE.toml",
                   help="write the model it arrives at as a model file (the best candidate, or with "
                        "--stepwise the final model; nothing is written when there is none)")
    p.add_argument("--report", metavar="DIR",
                   help="with --stepwise: add each step's model as a version of DIR/history.json "
                        "and write DIR/report.html (the error falling as effects are added; "
                        "see `stand report`)")
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="worker processes for the candidates' fits (default: one per CPU, up to "
                        "8, when the data are large enough to gain; 1: none); with --rig-model "
                        "for the channels (default: one per CPU, up to 8)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    g = p.add_argument_group(
        "rig runs (many channels on one structure; docs/rig.md)",
        "With --rig-model every channel (or those of --channel) is diagnosed with the other "
        "channels' part of its force rate, Σ G_ij·w_j through their models, as a known input: "
        "the diagnosis finds the channel's own effects. The channels run in parallel (--jobs, "
        "or a dask cluster with --scheduler); --model is each channel's start (default base; "
        "'rig': its model in the rig model file); --save writes the rig model arrived at.")
    g.add_argument("--rig-model", metavar="RIG_MODEL.toml",
                   help="the rig's G and channel models (stand estimate RIG_RUNS --save writes one)")
    g.add_argument("--channel", action="append", metavar="NAME[,NAME...]",
                   help="diagnose only these channels (default: all; repeatable). Without "
                        "--rig-model one channel, read as a one-channel run (its force as it was, "
                        "the others' coupling in it)")
    g.add_argument("--rounds", type=int, default=1, metavar="N",
                   help="diagnose all channels N times, each round's coupling from the others' "
                        "models of the round before (default %(default)s)")
    g.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the channels on a dask.distributed cluster (its scheduler's "
                        "address, e.g. tcp://10.0.0.5:8786; pip install 'hydrostand[cluster]')")
    p.set_defaults(func=main)


def one_channel(channels: list[str] | None) -> str | None:
    """Without --rig-model, --channel names the one channel of a rig run to read."""
    names = [n.strip() for item in channels or [] for n in item.split(",") if n.strip()]
    if len(names) > 1:
        from gateway.errors import ParameterError
        raise ParameterError(f"--channel {','.join(names)}: without --rig-model one channel is "
                             "diagnosed at a time, read as a one-channel run; with --rig-model "
                             "(the rig's G and channel models) several")
    return names[0] if names else None


def main(args: argparse.Namespace) -> int:
    from analysis import diagnosable_effects, diagnose, resolve_model
    from analysis.reports import plots
    check_window(args)
    if args.max_effects < 1:
        from gateway.errors import ParameterError
        raise ParameterError(f"--max-effects {args.max_effects} is out of range: give 1 or more")
    if args.jobs is not None and args.jobs < 1:
        from gateway.errors import ParameterError
        raise ParameterError(f"--jobs {args.jobs} is out of range: give 1 or more")
    if args.rig_model:
        if not rig_inputs(args.data):
            from gateway.errors import ParameterError
            raise ParameterError(f"--rig-model needs rig runs; {', '.join(args.data)} "
                                 f"{'is' if len(args.data) == 1 else 'are'} one-channel data")
        return main_rig(args)
    if args.scheduler:
        from gateway.errors import ParameterError
        raise ParameterError("--scheduler goes with --rig-model (the rig's G and channel models)")
    records = load_records(args.data, one_channel(args.channel))
    model, _ = resolve_model(args.model)
    effects = ([e.strip() for e in args.candidates.split(",") if e.strip()]
               if args.candidates else None)
    if args.stepwise:
        return main_stepwise(args, records, model, effects)
    if args.report:
        from gateway.errors import ParameterError
        raise ParameterError("--report goes with --stepwise (for one model, use `stand report`)")
    total = 1 + len(effects if effects is not None else diagnosable_effects(model))
    with progress_bar(args, "diagnose", total) as progress:
        d = diagnose(records, model, window_s=args.window_s, effects=effects, progress=progress,
                     jobs=args.jobs)
    best = d.best_candidate
    saved = save_model(args, best.fit.model if best is not None else None,
                       f"stand diagnose: {d.summary}")
    files = plots_and_head(args, d, records, {
        "candidates.png": lambda p: plots.plot_candidates(d, p),
        "overlay_start_model.png": lambda p: plots.plot_overlay(d.base_eval, p),
        "regimes_start_model.png": lambda p: plots.plot_regimes(d.base_eval, p)})
    if files is None:
        return 0
    print(f"{'model':32s} {'RMSE kgf':>9s} {'change':>8s} {'of excess':>9s}  earns")
    print(f"{d.base_fit.model.spec:32s} {d.base_eval.rmse:9.4g} {'':>8s} {'':>9s}")
    for c in d.candidates:
        mark = "yes" if c.earns else "no"
        print(f"{'+' + c.effect:32s} {c.rmse:9.4g} {-100 * c.rmse_reduction:+7.1f}% "
              f"{100 * max(-9.99, c.excess_share):8.0f}%  {mark}{'  <- best' if c.effect == d.best else ''}")
    print(f"(noise floor {d.base_eval.noise_floor:.3g} kgf, σ = {d.noise_sigma:.3g} kgf; candidates "
          f"judged on the error with re-estimated window starts)")
    if d.screening["subset"]:
        print(f"(screened on {d.screening['windows_screened']} of {d.screening['windows_total']} windows; "
              f"refitted on all: {', '.join(d.screening['refit_on_all'])}; the others keep their "
              f"screening fit and are compared with the starting model fitted on the same windows)")
    if best is not None:
        print()
        print(f"fitted {best.spec}: " + ", ".join(f"{k} = {v:.4g}" for k, v in best.params.items()))
    if d.between is not None and d.between.stats.helps:
        print_between(d.between)
    print()
    print("what the residual of " + d.base_fit.model.spec + " shows:")
    for o in d.observations:
        print(f"  - {o}")
    print_tail(d, files, saved, "what these data cannot tell:")
    return 0


def plots_and_head(args: argparse.Namespace, result, records, plotters: dict) -> list | None:
    """--plots: write each plot (file name -> writer). --json: print the result with the plots'
    paths and what loading changed in the data (``data_notes``, per source) and return None
    (nothing more to print); otherwise print the verdict and summary and return the plots
    written."""
    files = []
    if args.plots is not None:
        out = Path(args.plots) if args.plots else default_out(args.data, "diagnose")
        out.mkdir(parents=True, exist_ok=True)
        files = [write(out / name) for name, write in plotters.items()]
    if args.json:
        obj = result.to_dict()
        obj["plots"] = [str(f) for f in files]
        obj["data_notes"] = {rec.source: list(rec.notes) for rec in records if rec.notes}
        print_json(obj)
        return None
    print(f"verdict: {result.verdict.upper()}")
    print(f"  {result.summary}")
    print()
    return files


#: records listed one by one at most; more are shown by their first and last ones
BETWEEN_ROWS = 16


def print_between(b) -> None:
    """The records' own g and Δ (analysis.diagnosis.between_records), a line each."""
    st = b.stats
    print()
    print(f"{b.model} with a {b.varies} of its own per record: objective error "
          f"{-100 * st.improvement:+.1f}%, {100 * max(st.excess_share, 0):.0f}% of the excess "
          f"({'earns' if st.earns else 'part of it'}; {b.extra_params} more parameters)")
    if b.refit:
        print(f"  its other parameters refitted with them: {b.refit_text}")
    rows = list(enumerate(b.records))
    if len(rows) > BETWEEN_ROWS:
        rows = rows[:BETWEEN_ROWS // 2] + [None] + rows[-BETWEEN_ROWS // 2:]
    print(f"  {'#':>3s} {'record':32s} {'g kgf/s/%':>10s} {'× shared':>8s} {'Δ kgf/s':>8s} "
          f"{'|u| %':>6s}")
    for row in rows:
        if row is None:
            print(f"  {'...':>3s}")
            continue
        i, r = row
        print(f"  {i + 1:3d} {r.source[-32:]:32s} {r.g:10.4g} {r.gain:8.3f} {r.delta:+8.3g} "
              f"{r.level:6.3g}")


@contextlib.contextmanager
def progress_bar(args: argparse.Namespace, desc: str, total: int | None = None):
    """Progress on stderr while models are fitted (nothing with --no-progress): a bar counting
    them on a terminal; elsewhere (a log, a pipe) one line per step of the build-up. Yields the
    ``progress(message)`` callback."""
    from tqdm import tqdm
    terminal = sys.stderr.isatty()
    bar = None if args.no_progress or not terminal else tqdm(
        total=total, desc=desc, unit="model", file=sys.stderr, leave=False, disable=None)

    def progress(msg: str) -> None:
        if args.no_progress or msg.startswith("refitting"):
            return
        if bar is not None:
            bar.set_postfix_str(msg)
            bar.update(1)
        elif msg.startswith("diagnosing"):      # a step of the build-up starts
            print(f"{desc}: {msg}", file=sys.stderr, flush=True)

    try:
        yield progress
    finally:
        if bar is not None:
            bar.close()


def print_tail(d, files: list, saved: Path | None, heading: str,
               ambiguities: list | None = None) -> None:
    """What a diagnosis leaves unexplained or ambiguous (``ambiguities``: these rather than
    its own), its notes, and the files written."""
    if d.unexplained:
        print(f"  - unexplained: {d.unexplained.description}")
    ambiguities = d.ambiguities if ambiguities is None else ambiguities
    if ambiguities:
        print()
        print(heading)
        for a in ambiguities:
            print(f"  - {a.text()}")
    for w in d.warnings:
        print(f"note: {w}")
    if files:
        print("\nplots: " + ", ".join(str(f) for f in files))
    if saved:
        print(f"model saved: {saved}")


def save_model(args: argparse.Namespace, model, summary: str) -> Path | None:
    """--save: the model arrived at, as a model file (None: there is no model to save)."""
    from plant import model_to_toml
    if not args.save or model is None:
        if args.save:
            print(f"note: no model to save to {args.save}: no effect earned its parameters",
                  file=sys.stderr)
        return None
    path = Path(args.save)
    header = (f"from {', '.join(Path(d).name for d in args.data)}\n{summary}")
    path.write_text(model_to_toml(model, header, path))
    return path


def main_stepwise(args: argparse.Namespace, records, model, effects) -> int:
    from analysis import stepwise, write_report
    from analysis.reports import plots
    with progress_bar(args, "diagnose --stepwise") as progress:
        r = stepwise(records, model, window_s=args.window_s, max_effects=args.max_effects,
                     effects=effects, progress=progress, jobs=args.jobs)
    saved = save_model(args, r.model if len(r.model.effects) or r.verdict == "adequate" else None,
                       f"stand diagnose --stepwise: {r.summary}")
    report = None
    if args.report:
        models = [s.diagnosis.base_fit.model for s in r.steps]
        if models[-1].spec != r.model.spec:      # the backward check dropped an effect
            models.append(r.model)
        for i, m in enumerate(models):
            last = i == len(models) - 1
            report = write_report(records, m, args.report, fit=False, window_s=args.window_s,
                                  diagnosis=r.last if last else None).path
    files = plots_and_head(args, r, records, {
        "stepwise.png": lambda p: plots.plot_stepwise(r, p),
        "candidates_last_step.png": lambda p: plots.plot_candidates(r.last, p),
        "overlay_final_model.png": lambda p: plots.plot_overlay(r.last.base_eval, p)})
    if files is None:
        return 0
    print(f"{'step':>4s}  {'model':40s} {'RMSE kgf':>9s} {'× floor':>8s}  next")
    for i, s in enumerate(r.steps):
        print(f"{i:4d}  {s.model:40s} {s.rmse:9.4g} {s.over_floor:8.2f}  {s.line}")
    print(f"(× floor: the error with re-estimated window starts over the noise floor, "
          f"{r.last.objective_floor:.3g} kgf)")
    if r.revision is not None and r.revision.kept:
        print(f"at the end, each added effect tried in place of its look-alikes: {r.revision.text}")
    if r.closest:
        print()
        print("the catalogue effects that came closest, rejected (what to try next):")
        for c in r.closest:
            print(f"  - {c}")
    if r.needed:
        print()
        print("each added effect, checked with the others in place:")
        for n in r.needed:
            print(f"  - {n.text()}")
    print()
    print(f"fitted {r.model.spec}: " + ", ".join(f"{k} = {v:.4g}" for k, v in r.model.params().items()))
    print_tail(r.last, files, saved, "what these data cannot tell about this model:",
               r.ambiguities)
    if report:
        print(f"report: {report}")
    return 0


# -- a rig: --rig-model --------------------------------------------------------------------------
def main_rig(args: argparse.Namespace) -> int:
    """``--rig-model``: every channel (or those of --channel) with the others' coupling as a known input."""
    from analysis.diagnosis.rig import diagnose_rig
    from analysis.executors import rig_executor
    from core.errors import ParameterError
    from plant.config import load_rig_model, rig_model_to_toml
    for opt in ("plots", "report"):
        if getattr(args, opt, None) is not None:
            raise ParameterError(f"--{opt} is for one channel's data; with --rig-model use --json "
                                 "or diagnose a channel's one-channel view")
    if args.rounds < 1 or args.rounds > 10:
        raise ParameterError(f"--rounds {args.rounds} is out of range: give 1 to 10")
    rig = load_rig_model(args.rig_model)
    records = load_rig_records(args.data)
    channels = None
    if args.channel:
        channels = [c.strip() for item in args.channel for c in item.split(",") if c.strip()]
        missing = [c for c in channels if c not in rig.names]
        if missing:
            raise ParameterError(f"--channel {', '.join(missing)}: the rig model {args.rig_model} "
                                 f"has channels {', '.join(rig.names)}")
    effects = ([e.strip() for e in args.candidates.split(",") if e.strip()]
               if args.candidates else None)
    names = channels or rig.names
    start = None
    if args.model != "rig":
        from analysis import resolve_model
        start, _ = resolve_model(args.model)

    def progress(msg: str) -> None:
        if not args.no_progress:
            print(f"diagnose: {msg}", file=sys.stderr, flush=True)

    with rig_executor(args.jobs, args.scheduler, tasks=len(names)) as ex:
        d = diagnose_rig(records, rig, channels, build_up=args.stepwise, start=start,
                         window_s=args.window_s, max_effects=args.max_effects, effects=effects,
                         executor=ex, rounds=args.rounds, progress=progress)
    saved = None
    if args.save:
        path = Path(args.save)
        verdicts = "; ".join(f"{c.name}: {c.verdict} ({c.spec})" for c in d.channels)
        header = (f"from {', '.join(Path(x).name for x in args.data)}: stand diagnose --rig-model "
                  f"{Path(args.rig_model).name}{' --stepwise' if args.stepwise else ''}, "
                  f"{d.rounds} round(s)\n{verdicts}")
        path.write_text(rig_model_to_toml(d.rig, header, path))
        saved = path
    if args.json:
        doc = d.to_dict()
        doc["saved"] = str(saved) if saved else None
        print_json(doc)
        return 0
    print(describe_diagnosis(d))
    if saved:
        print(f"rig model saved: {saved}")
    return 0


def describe_diagnosis(d: "RigDiagnosis") -> str:
    lines = [f"{len(d.channels)} channel(s) diagnosed with the coupling from the others in the "
             f"model, {d.rounds} round(s), {d.seconds:.1f} s"]
    lines.append(f"  {'channel':10s} {'verdict':24s} {'model':34s} {'g':>8s} {'τ ms':>7s} "
                 f"{'Δ kgf/s':>8s}  task s")
    for c in d.channels:
        p = c.params
        lines.append(f"  {c.name:10s} {c.verdict:24s} {c.spec:34s} {p['g']:8.4g} "
                     f"{p['tau'] * 1e3:7.3g} {p['delta']:8.3g}  {c.seconds:6.1f}")
    for c in d.channels:
        own = {k: v for k, v in c.params.items() if "." in k}
        lines.append("")
        lines.append(f"{c.name}: {c.summary}")
        if own:
            lines.append("  " + ", ".join(f"{k} = {v:.4g}" for k, v in own.items()))
        steps = c.detail.get("steps") if isinstance(c.detail, dict) else None
        for i, s in enumerate(steps or []):
            nxt = f"+{s['added']}: {s['why']}" if s.get("added") else s.get("why", "")
            lines.append(f"  {i:2d}  {s['model']:36s} RMSE {s['rmse']:8.4g} kgf  "
                         f"×floor {s['over_floor']:5.2f}  {nxt}")
    lines += [f"note: {n}" for n in d.notes]
    return "\n".join(lines)
