"""``docs/reference/load-json.md`` and ``docs/reference/test-status-json.md``: what ``stand load
--json`` (schema ``hydrostand-load/1``, :mod:`loading.report`, :mod:`gateway.load`) and ``stand
test status --json`` (the live page's ``/status.json``, :meth:`endurance.journal.Journal.status`)
print. The pass timing's keys are its dataclass's; the rest is written here, and
``tests/test_reference.py`` checks the tables against the objects the code builds."""
from __future__ import annotations

from . import markdown as md
from .keys import Key, Table, dataclass_keys

#: a channel's figures: the top level's (the worst channel's) and each of ``channels``'s
FIGURES = (
    Key("peak_valley_error_pct", "`max` and `p95` of \\|achieved − commanded\\| at the programme's peaks "
        "and valleys, % of the programme's range"),
    Key("rms_error_pct", "the RMS tracking error, % of the range"),
    Key("extra_cycles", "self-oscillation: rainflow cycles of the force the programme does not have, "
        "above 0.5 % of the range (a half cycle counts ½)"),
    Key("largest_extra_cycle_kgf", "the largest of them, kgf"),
    Key("overshoot_max_pct", "the largest overshoot beyond a level, % of the range"),
    Key("range_kgf", "the programme's range, kgf"),
    Key("turning_points", "the turning points judged"),
)


def load_tables() -> tuple[Table, ...]:
    from gateway.load import PassTiming
    timing = dataclass_keys(PassTiming, {
        "pacing": "null pacing's record (`waits`, `slowed_s`, ...); only with `--pacing`",
        "scaling": "time scaling: the segments `land`ed, `hold`, `miss`ed; only with `--accuracy`/`--fastest`",
        "gain_blocks": "the gain monitor's blocks of this pass; only with `--gain`",
    }, show_defaults=False)
    timing = timing[:2] + (Key("time_over_minimum", "`programme_time_s` over `minimum_time_s`"),) + timing[2:]
    return (
        Table("", (Key("schema", "`hydrostand-load/1`"),) + FIGURES + (
            Key("worst_channel", "the channel the figures above are (the largest p95); a stand: `stand`"),
            Key("ratio_error_pct", "load cases of a rig: the largest deviation from a load case's ratios "
                "between the channels, % of a channel's range; null otherwise"),
            Key("channels", "per channel, its figures (the keys above, `peak_valley_error_pct` to "
                "`turning_points`)"),
        ) + timing + (
            Key("end_reason", "`complete`, or why the last pass stopped (`error_limit`, `interrupted`, ...)"),
            Key("end_message", "the same in a sentence; only when it stopped early"),
            Key("passes", "every pass's figures, the keys above from `peak_valley_error_pct` to "
                "`gain_blocks`, in order"),
            Key("runs", "the passes' run directories"),
            Key("schedule", "time scaling: the fastest schedule that met the accuracy, `time_s`, "
                "`minimum_time_s`, `accuracy_pct`, `verified` (null if none did)"),
            Key("converged", "time scaling: the last pass ran every segment settled and met the accuracy"),
            Key("gain", "with `--gain`: the gain monitor, below"),
        ), "The top level's figures are the last pass's worst channel's."),
        Table("gain", (
            Key("alarm", "`fall`, `rise` or `margins` (the loop's margins at the estimated g below the "
                "design's) once it fired, else null"),
            Key("alarm_channel", "the channel whose g moved"),
            Key("alarm_message", "the alarm in a sentence"),
            Key("action", "what the alarm did: `note`, `hold`, `unload`"),
            Key("fall_pct", "the fall that alarms, %"),
            Key("rise_pct", "the rise that alarms, %"),
            Key("block_s", "stand time per estimate, s"),
            Key("follows", "the feedforward follows g (`--gain adapt`)"),
            Key("channels", "per channel: `g_reference`, `blocks_total`, `blocks_estimated`, `last_g`, "
                "`alarm`, `alarm_message`, `alarm_block`, the options, `g_follow`"),
            Key("g_reference", "a stand: the model's g, kgf/(%·s) (and the other keys of its channel)"),
            Key("blocks_total", "a stand: blocks of stand time"),
            Key("blocks_estimated", "a stand: blocks that gave an estimate"),
            Key("last_g", "a stand: the latest estimate of g"),
            Key("alarm_block", "a stand: the block the alarm fired in"),
            Key("g_follow", "a stand: the g the feedforward uses now"),
        )),
    )


def status_tables() -> tuple[Table, ...]:
    from endurance.journal import STATES
    states = ", ".join(f"`{s}`" for s in STATES)
    return (
        Table("", (
            Key("name", "the test's name"),
            Key("testdir", "its directory"),
            Key("state", f"{states} (`interrupted`: its process died; `stand test resume` goes on)"),
            Key("reason", "why it stopped or was interrupted, a sentence; null while running"),
            Key("flights_done", "flights counted, each exactly once"),
            Key("flights_target", "the target"),
            Key("flight", "the flight in progress, or the next: `number`, `type`, `block`, `position` "
                "(in its block), `load_cases`, `attempt` (null when not begun); null once finished"),
            Key("load_case", "the next load case of that flight, from 1"),
            Key("pace_flights_per_h", "flights per hour over the last hour; null before two flights"),
            Key("eta_s", "seconds to the target at that pace"),
            Key("events", "the latest events (`--events N`), oldest first"),
            Key("holder", "the process running it: `pid`, `host`; null when none"),
            Key("updated", "when the journal last changed, s since the epoch"),
            Key("fingerprint", "the test file's fingerprint (a resume refuses a changed test)"),
            Key("channels", "the station's channels"),
        )),
        Table("events[]", (
            Key("id", "the event's number in the journal"),
            Key("time", "when, s since the epoch"),
            Key("kind", "`started`, `stopped`, `finished`, `interrupted`, `inspection`, `trend_note`, "
                "`operator`, `loading`, ... ([docs/endurance.md](../endurance.md))"),
            Key("channel", "the channel it concerns, or null"),
            Key("flight", "the flight it happened in, or null"),
            Key("load_case", "the load case, or null"),
            Key("message", "what happened, a sentence"),
        )),
    )


def load_page() -> str:
    intro = ("`stand load ... --json` prints this object when the passes are done (`OUT/report.json` holds "
             "the same). Percentages are of the programme's range, "
             "`R = max r − min r`; a turning point's error is the extreme of the force near it "
             "minus its level. How to read a report: [docs/loading.md](../loading.md).")
    return md.page("The loading summary (`stand load --json`, `hydrostand-load/1`)", intro,
                   *[t.markdown("##") for t in load_tables()])


def status_page() -> str:
    intro = ("`stand test status TESTDIR --json` prints this object; the live page serves the same "
             "at `/status.json`. It reads the test's journal and may be run while the test runs. "
             "How to run and watch a test: [docs/endurance.md](../endurance.md).")
    return md.page("An endurance test's status (`stand test status --json`)", intro,
                   *[t.markdown("##") for t in status_tables()])
