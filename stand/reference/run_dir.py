"""``docs/reference/run.md``: the run directory every run, decoded capture and endurance event
window is (:mod:`gateway.runs`): its files, its signals (the columns and their meanings are
:mod:`gateway.runs`'s schema and docstring table), and ``run.json`` (the limits' and the loop
counters' keys are their dataclasses'; the rest is written here, and ``tests/test_reference.py``
checks the top level against a run the gateway records)."""
from __future__ import annotations

from . import markdown as md
from .keys import Key, Table, dataclass_keys


def signal_rows() -> list[list[str]]:
    """The signals' table of :mod:`gateway.runs`'s docstring (name, type, meaning), checked
    against its Arrow schema: a column added to one and not the other cannot be published."""
    import gateway.runs as runs
    lines = runs.__doc__.splitlines()
    rules = [i for i, ln in enumerate(lines) if ln.startswith("=====")]
    if len(rules) < 2:
        raise RuntimeError("gateway/runs.py's docstring has no signals table (=====  ====)")
    rows: list[list[str]] = []
    for ln in lines[rules[0] + 1:rules[1]]:
        if not ln.strip():
            continue
        if ln[0] != " ":                                   # a new column: name, type, meaning
            name, kind, meaning = ln.split(None, 2)
            rows.append([name, kind, meaning])
        else:                                              # the meaning goes on
            rows[-1][2] += " " + ln.strip()
    schema = {f.name: str(f.type) for f in runs.SCHEMA}
    table = {r[0]: r[1] for r in rows}
    if table != {k: ("float64" if v == "double" else v) for k, v in schema.items()}:
        raise RuntimeError(f"gateway/runs.py: the docstring's signals {table} are not the schema's {schema}")
    return [[md.code(n), md.code(k), md.text(md.rst(m))] for n, k, m in rows]


def tables() -> tuple[Table, ...]:
    from gateway.limits import (ACTIONS, HEARTBEAT_TIMEOUT_LOCKSTEP_S, HEARTBEAT_TIMEOUT_REALTIME_S,
                                SafetyLimits)
    from gateway.loop import LoopStats
    actions = ", ".join(f"`{a}`" for a in ACTIONS)
    return (
        Table("", (
            Key("format", "`hydrostand-run/1`"),
            Key("status", "`running` (while recorded, or cut short by a crash), `complete`, `stopped` (the "
                "supervisor or the experiment stopped it), `aborted` (an error, Ctrl-C, SIGTERM), "
                "`damaged` (a decoded capture, up to the damage)"),
            Key("started", "when the run began (ISO 8601, UTC)"),
            Key("ended", "when it ended"),
            Key("versions", "Python's and the stack's versions"),
            Key("command", "the command line that made it"),
            Key("experiment", "`name` and `params` of the experiment (a loading pass: its programme)"),
            Key("bus", "the python-can bus (a one-channel run)"),
            Key("clock", "`lockstep` or `realtime`"),
            Key("period_s", "the control period, s"),
            Key("nodes", "`valve` and `dynamometer`: each one's `id` and `identity` (its 0x1018 object)"),
            Key("force_scale_kgf_per_count", "kgf per count of the dynamometer's process value"),
            Key("devices", "`valve` and `dynamometer`: each one's device file, EDS, identity, roles' "
                "objects and the `configuration` the gateway gave it (its PDOs, error control, notes; "
                "[device files](devices-toml.md))"),
            Key("device_notes", "what the devices lack and what the run then cannot do, a line each"),
            Key("startup", "the capture's first `frames` frames are the start-up (boot, identity, "
                "configuration), up to the wall time `until`"),
            Key("limits", "the supervisor's settings (below)"),
            Key("files", "the run's files: `signals`, `capture` (a rig: `captures`, one per bus), "
                "`dbc` for devices other than the emulated pair (a rig: per channel)"),
            Key("rows", "the signals' rows"),
            Key("end_reason", "why it ended early, a word (`force_limit`, `error_limit`, `heartbeat_lost`, "
                "`interrupted`, ...; [docs/safety.md](../safety.md)); null when complete"),
            Key("end_message", "the same in a sentence"),
            Key("stats", "the loop's counters (below)"),
            Key("capture_frames", "frames in the capture (a rig: per bus)"),
            Key("emcy", "the EMCY messages received, in order"),
            Key("events", "limit crossings that were only indicated (`--limit-action indicate`)"),
        ), "Every run a gateway records. Written when the run starts (`status` running) and again "
           "when it ends."),
        Table("", (
            Key("realtime", "real time: the scheduling the loop got (SCHED_FIFO priority, or why not)"),
            Key("safety", "a supervisor's stop: `reason`, `action`, `message`, the wall times `onset`, "
                "`detected`, `safe_state`, `reaction_s`, `bound_s` (and `unload`, `channel`)"),
            Key("fault_reset", "`--reset-faults`: the valve fault that was reset"),
            Key("capture_write_errors", "frames the capture could not write"),
            Key("rig", "a rig run: `name`, `file`, `period_s`, `heartbeat_ms`, `G`, `structure_from`, "
                "`bus_load_limit_pct`, `fault_action`, `buses` (each with its capture and budget), "
                "`channels` (bus, nodes, range, force limit, `driven`), `driven`"),
            Key("source", "a decoded capture: `capture`"),
            Key("capture", "a decoded capture: its `path`, `format`, `bytes`, `dbc`, `run`, `runs_in_capture`"),
            Key("decode", "a decoded capture: what was decoded, the frames, the reader, the time it took, "
                "its notes"),
            Key("period_source", "a decoded capture: where the period came from"),
            Key("clock_source", "a decoded capture: where the clock came from"),
            Key("event", "an endurance test's event window: the event's `kind`, `message`, `channel`, "
                "`flight`, `time` and the window"),
        ), "Present only where they apply."),
        Table("limits", dataclass_keys(SafetyLimits, {
            "force_limit_kgf": "the force limit ±kgf (a rig run: null here, each channel's in `rig`)",
            "command_limit_pct": "the valve command's clamp, ±%",
            "error_time_s": "how long the error must persist, s",
            "error_action": f"what the error detector does: {actions}",
            "stale_cycles": "safe state after this many cycles without a fresh force reading",
            "heartbeat_timeout_s": f"a node's heartbeat older than this stops the run, s (unless set: "
                                   f"{HEARTBEAT_TIMEOUT_REALTIME_S:g} in real time, {HEARTBEAT_TIMEOUT_LOCKSTEP_S:g} "
                                   "in lockstep)",
            "unload_rate_kgf_per_s": "a controlled unload: the force's ramp rate, kgf/s",
            "unload_gain_pct_per_kgf": "its loop gain, %/kgf",
            "unload_max_pct": "its command bound, ±%",
            "unload_tolerance_kgf": "the band counted as unloaded, ±kgf",
            "unload_timeout_s": "the time it may take before falling back to hold, s",
        }, show_defaults=False), "`stand COMMAND --help` lists the options that set them "
           "([cli.md](cli.md)); what each does: [docs/safety.md](../safety.md)."),
        Table("stats", dataclass_keys(LoopStats, {
            "cycles": "control cycles run",
            "stale_cycles": "cycles without a fresh force reading",
            "overruns": "real time: cycles that started late",
            "late_frames": "answers that came after their cycle",
            "max_lateness_s": "the latest of them, s",
            "wall_s": "the run's wall-clock time, s",
            "wrong_dlc_frames": "(see `unexpected_frames`)",
            "not_classic_frames": "(see `unexpected_frames`)",
        }, skip=("sync_jitter_s", "behind_s", "answer_window_min_s"), show_defaults=False) + (
            Key("answer_window_min_ms", "real time: the shortest wait for the nodes' answers after a SYNC, ms"),
            Key("cycles_begun_behind", "real time: cycles begun after their SYNC time"),
            Key("sync_jitter_ms", "real time: the SYNC's lateness, `p50`, `p99`, `max`, ms"),
            Key("begun_behind_ms", "real time: how late the cycles began, `p50`, `p99`, `max`, ms"),
            Key("stale_cycles_by_channel", "a rig: stale cycles per channel"),
        )),
    )


def page() -> str:
    from gateway.runs import (CAPTURE_FILE, CHANNEL_COLUMNS, META_FILE, RIG_RUN_COLUMNS, SIGNALS_FILE,
                              STREAM_FILE, TRUTH_FILE, capture_file)
    files = md.table(["file", "what it is"], [
        [md.code(META_FILE), "what ran, on what, how it ended (below)"],
        [md.code(SIGNALS_FILE), "one row per control cycle (Apache Parquet: pandas, polars, DuckDB, "
         "Spark read it)"],
        [md.code(STREAM_FILE), "the same while the run is going (Arrow IPC, flushed at least every 0.5 s); "
         "a run cut short by a crash keeps only this, and every complete chunk of it is read back"],
        [md.code(CAPTURE_FILE), "the raw bus capture (candump -L)"],
        [md.code(capture_file("BUS")), "a rig run: a capture per bus"],
        [md.code(TRUTH_FILE), "an emulated run: the emulator's true parameters (the analysis never reads it)"],
    ])
    rig = (f"**A rig run** keeps {', '.join(md.code(c) for c in RIG_RUN_COLUMNS)} once and "
           f"{', '.join(md.code(c) for c in CHANNEL_COLUMNS)} once per channel, named "
           "`<column>.<channel>` (`y.root`). `--channel NAME` reads one channel as a one-channel run.")
    top, conditional, *rest = tables()
    intro = ("Every `stand run`, `campaign`, `load` pass and `demo` records a run directory; `stand "
             "decode` makes one from a bus capture; an endurance test keeps one per event window. "
             "Every analysis command reads it.")
    return md.page("The run directory (`run.json`, `signals.parquet`)", intro, "## Its files", files,
                   "## The signals", md.table(["column", "type", "what it is"], signal_rows()), rig,
                   "## `run.json`",
                   top.intro, top.key_table(), conditional.intro, conditional.key_table(),
                   *[t.markdown() for t in rest])
