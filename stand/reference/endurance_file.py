"""``docs/reference/test-toml.md``: an endurance test's file (:mod:`endurance.testfile`). The
example is the module's own; the monitors' and the storage's defaults come from their
dataclasses (the trend's meanings from its fields' comments); ``tests/test_reference.py``
checks that the tables name exactly the keys the loader accepts."""
from __future__ import annotations

from . import markdown as md
from .keys import Key, Table, dataclass_keys, value


def tables() -> tuple[Table, ...]:
    from endurance.testfile import (SEARCH_FLIGHTS, STAND_FORCE_LIMIT_KGF, STAND_PERIOD_MS,
                                    STAND_RANGE_KGF, GainMonitor, StoragePolicy, TimeScaling)
    from endurance.trends import ACTIONS, SIDES, TrendOptions
    actions = " \\| ".join(f"`{a}`" for a in ACTIONS)
    storage = StoragePolicy()
    gain = GainMonitor()
    return (
        Table("", (
            Key("name", "the test's name (status, reports, the live page)", "the file's name", "string"),
            Key("station", 'what is loaded: a rig file (relative to this file), or `"stand"`: a '
                "one-channel stand, a station of one channel named `stand` (its flight types' CSVs "
                "name their column `level`)", "required", "string"),
            Key("controller", "the station's controller file (`stand design` output), relative to "
                "this file", "required", "string"),
            Key("rate_kgf_s", "every flight type's peak rate between load cases, kgf/s, unless it gives "
                "its own (or `frequency_hz`, not both)", "", "number"),
            Key("frequency_hz", "instead of `rate_kgf_s`: a half cycle per 1/(2 f) between load cases",
                "", "number"),
            Key("flights", "the target: this many flights (or `blocks`, one of them; `stand test start "
                "--flights N` overrides it)", "required", "integer"),
            Key("blocks", "the target as whole blocks", "", "integer"),
            Key("stand", 'with `station = "stand"`: the stand\'s period and limits', "", "`[stand]`"),
            Key("flight", "the flight types, a table each", "required", "`[flight.NAME]`"),
            Key("block", "the flights of one block", "required", "`[block]`"),
            Key("inspection", "where the test stops for an inspection", "", "`[[inspection]]`"),
            Key("monitor", "what watches the structure: `[monitor.trend]`, `[monitor.gain]`", "",
                "table"),
            Key("storage", "what full-rate data is kept", "", "`[storage]`"),
            Key("time_scaling", "every flight type's segments timed to the valves, as `stand load "
                "--accuracy` times a programme", "", "`[time_scaling]`"),
        ), "Give `flights` or `blocks`, and `rate_kgf_s` or `frequency_hz` here or in every flight type."),
        Table("[stand]", (
            Key("period_ms", "the control period, ms (0.5 to 100)", value(STAND_PERIOD_MS), "number"),
            Key("range_kgf", "the dynamometer's range, kgf", value(STAND_RANGE_KGF), "number"),
            Key("force_limit_kgf", "the supervisor's force limit, kgf (at most `range_kgf`)",
                value(STAND_FORCE_LIMIT_KGF), "number"),
        ), 'Only with `station = "stand"`: a rig\'s period and limits are its rig file\'s.'),
        Table("[flight.NAME]", (
            Key("load_cases", "a load-case CSV, relative to this file: `case` and a column per channel "
                "(a stand: `level`), as `stand load --rig` reads it", "required", "string"),
            Key("rate_kgf_s", "this type's rate, kgf/s", "the file's", "number"),
            Key("frequency_hz", "instead of `rate_kgf_s`", "the file's", "number"),
            Key("schedule", "its segment durations to replay: a schedule file `stand load --fastest` "
                "made for these load cases", "", "string"),
        ), "NAME: letters, digits, `_` or `-`, starting with a letter."),
        Table("[block]", (
            Key("flights", "how many flights of each type a block flies, e.g. `{ A = 1, B = 4 }`; every "
                "flight type once", "required", "table"),
            Key("seed", "the seed of each block's random order (the order depends on it and the block's "
                "number only)", value(0), "integer"),
        )),
        Table("[[inspection]]", (
            Key("at_flight", "the test stops (state stopped, reason inspection) once this flight is done",
                "required", "integer"),
            Key("note", "what to inspect, shown with the stop", value(""), "string"),
        )),
        Table("[monitor]", (
            Key("trend", "the end points' trend: a crack needs more flow to reach the same levels",
                "off", "`[monitor.trend]`"),
            Key("gain", "the stand's gain estimated block by block, as `stand load --gain`", "off",
                "`[monitor.gain]`"),
        )),
        Table("[monitor.trend]", dataclass_keys(TrendOptions, {
            "sides": " or ".join(f"`{s}`" for s in SIDES) + ": `both` watches for more flow and for "
                     "less on every channel, `soften` for more only",
            "action": f"what the running test does on an alarm: {actions}",
        }), "Ranges: `learn_flights` at least the channels + 5, `shift_pct` 0.01 to 100, "
            "`false_alarm_flights` 10 to 10¹², `floor_pct` 0 to 10, `confidence` 0.5 to 0.999. How "
            "the trend is built: [docs/endurance.md](../endurance.md)."),
        Table("[monitor.gain]", (
            Key("mode", "`off`, `watch` (estimate g, alarm on a fall or a rise) or `adapt` (also let "
                "the feedforward follow it)", f"`watch` when the table is given, else {value(gain.mode)}",
                "string"),
            Key("block_s", "stand time per estimate, s (0.1 to 3600)", value(gain.block_s), "number"),
            Key("fall_pct", "alarm when g falls more than this % below the model's (0.01 to 90)",
                value(gain.fall_pct), "number"),
            Key("rise_pct", "alarm when g rises more than this % above the model's (0.01 to 900)",
                value(gain.rise_pct), "number"),
            Key("action", f"what the alarm does: {actions}", value(gain.action), "string"),
        )),
        Table("[time_scaling]", (
            Key("accuracy_pct", "each turning point within this % of the range (p95; max twice it), "
                "0.01 to 10", value(TimeScaling.accuracy_pct), "number"),
            Key("search_flights", "a flight type's flights that search its durations at most (at least "
                "2); then the fastest that met the accuracy is kept", value(SEARCH_FLIGHTS), "integer"),
        )),
        Table("[storage]", (
            Key("rolling_window_s", "full-rate signals kept for the last this many seconds (at most 7 "
                "days)", value(storage.rolling_window_s), "number"),
            Key("event_window_s", "and ± this many seconds around each event, as run directories (at "
                "most 3600 and the rolling window)", value(storage.event_window_s), "number"),
            Key("chunk_s", "the rolling window's files, s each (at most 3600 and the rolling window)",
                value(storage.chunk_s), "number"),
        )),
    )


def page() -> str:
    import endurance.testfile
    intro = ("A test file says what an endurance test loads, on which station, in which order, "
             "how far, and what watches it. `stand test plan TEST.toml` checks it and prints the "
             "block, the times and the storage; `stand test start TEST.toml --out TESTDIR` runs it. "
             "A mistake is one error naming the file and the key; an unknown key is refused by "
             "name. A resume refuses a test file whose station, controller, flight types or block "
             "changed (the target, inspections, monitors and storage may change). How to run a "
             "test: [docs/endurance.md](../endurance.md).")
    example = md.fenced(md.literal_block(endurance.testfile.__doc__), "toml")
    return md.page("The endurance test file (`test.toml`)", intro, "## An example", example,
                   "## The keys", *[t.markdown() for t in tables()])
