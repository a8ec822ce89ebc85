"""``docs/reference/controller-toml.md``: the controller files ``stand design`` writes and ``stand
load --controller`` and a test file's ``controller`` read (:mod:`loading.controller_files`): a
stand's (``hydrostand-controller/1``) and a rig's (``hydrostand-rig-controller/1``). The margins'
keys are the code's dataclasses; the rest is written here, and ``tests/test_reference.py``
checks the tables against the files :mod:`loading.design` writes."""
from __future__ import annotations

from . import markdown as md
from .keys import Key, Table, dataclass_keys, value

_PARAMS = Key('"PARAM"', "every parameter of the model's spec, by its name as `stand effects` lists it "
              '(`"g"`, `"tau"`, `"delta"`, `"reversal.boost"`, ...): all must be given', "required", "number")


def stand_tables() -> tuple[Table, ...]:
    from loading.design import COMMAND_LIMIT_PCT
    from loading.margins import Margins
    return (
        Table("[loop]", (
            Key("period_s", "the control period it was designed for, s; the loop must run at it",
                "required", "number"),
            Key("command_limit_pct", "the valve command's limit, % (up to 100)", value(COMMAND_LIMIT_PCT),
                "number"),
            Key("feedforward", "feed the reference forward through the model's inverse (`false`: "
                "feedback alone)", value(True), "true/false"),
        )),
        Table("[feedback]", (
            Key("kp_pct_per_kgf", "the PI's proportional gain, %/kgf", "required", "number"),
            Key("ti_s", "its integral time, s (`inf`: P alone)", "required", "number"),
        )),
        Table("[model]", (
            Key("spec", 'the model it was designed from, e.g. `"base+reversal"`', "required", "string"),
            Key("plugins", "the plug-in effects the model uses (files relative to this file, or modules)",
                "", "array of strings"),
            _PARAMS,
        )),
        Table("[design]", (
            Key("boost", "ρ, the largest gain factor the model predicts (after a reversal)", value(1.0),
                "number"),
            Key("lambda_s", "λ, the closed loop's time constant the PI was tuned to, s", "", "number"),
            Key("nominal", "the loop's margins at the model's g (written, not read back)", "", "table"),
            Key("boosted", "the same at ρ·g", "", "table"),
        )),
        Table("[design.nominal]", dataclass_keys(Margins, {
            "crossover_hz": "the loop's gain crossover, Hz",
            "gain_margin": "how many times the loop gain may grow before it is unstable",
            "phase_margin_deg": "the phase margin, degrees",
            "control_gain_margin": "the gain margin from python-control's `stability_margins` (a cross-check)",
            "control_phase_margin_deg": "the phase margin from python-control, degrees",
        }, show_defaults=False), "`[design.boosted]` has the same keys."),
    )


def rig_tables() -> tuple[Table, ...]:
    from loading.design import COMMAND_LIMIT_PCT, COUPLING_ERROR, FEEDBACKS, FEEDFORWARDS
    from loading.margins import LoopMargins
    return (
        Table("", (
            Key("channels", "the channels, in the order of G's rows (a rig file's names, any order)",
                "required", "array of strings"),
            Key("plugins", "the plug-in effects the channels' models use", "", "array of strings"),
            Key("loop", "the loop", "required", "`[loop]`"),
            Key("structure", "`G`: the model's coupling, kgf/(%·s), N rows of N numbers", "required",
                "`[structure]`"),
            Key("design", "how it was designed", "", "`[design]`"),
            Key("channel", "each channel's PI and model", "required", "`[channel.NAME]`"),
        )),
        Table("[loop]", (
            Key("period_s", "the control period, s; the rig file's must match", "required", "number"),
            Key("command_limit_pct", "every valve command's limit, %", value(COMMAND_LIMIT_PCT), "number"),
            Key("feedback", " or ".join(f"`{f}`" for f in FEEDBACKS) + ": each channel's PI on the "
                "errors decoupled through G⁻¹·diag(g), or on its own error", value(FEEDBACKS[0]), "string"),
            Key("feedforward", ", ".join(f"`{f}`" for f in FEEDFORWARDS) + ": through G⁻¹, each channel "
                "through its own model, or none", value(FEEDFORWARDS[0]), "string"),
        )),
        Table("[structure]", (Key("G", "the model's coupling; its diagonal is each channel's g",
                                  "required", "array"),)),
        Table("[design]", (
            Key("detuning", "κ: every channel's λ over its one-channel design's", value(1.0), "number"),
            Key("coupling_error", "how far the plant's off-diagonal G may be off the model's (0.2: "
                "±20 %)", value(COUPLING_ERROR), "number"),
            Key("margins", "the loops' margins together, per case (written, not read back)", "",
                "`[[design.margins]]`"),
        )),
        Table("[[design.margins]]", dataclass_keys(LoopMargins, {
            "gain_margin": "the smallest gain margin of the loci",
            "phase_margin_deg": "the smallest phase margin, degrees",
        }, skip=("stable",), show_defaults=False)),
        Table("[channel.NAME]", (
            Key("kp_pct_per_kgf", "the channel's PI proportional gain, %/kgf", "required", "number"),
            Key("ti_s", "its integral time, s", "required", "number"),
            Key("lambda_s", "λ it was tuned to, s", "", "number"),
            Key("boost", "ρ of its model", value(1.0), "number"),
            Key("model", "its model", "required", "`[channel.NAME.model]`"),
        )),
        Table("[channel.NAME.model]", (
            Key("spec", "the channel's model, e.g. `\"base+reversal\"`; its g must be G's diagonal",
                "required", "string"),
            _PARAMS,
        )),
    )


def page() -> str:
    from loading.design import SCHEMA, STATION_SCHEMA
    intro = ("`stand design MODEL.toml -o controller.toml` writes a stand's controller; `stand design "
             "RIG-MODEL.toml -o controller.toml` a rig's. `stand load --controller` and a test file's "
             "`controller` read them. The file's first line names its schema. A file written for "
             "another period, or missing a parameter of its model, is refused saying what to do; "
             "the margins are what the design computed and are not checked again on load (edit "
             "the gains with care). What the design does: [docs/loading.md](../loading.md).")
    return md.page("Controller files", intro,
                   f"## A stand's controller ({md.code(SCHEMA)})",
                   *[t.markdown() for t in stand_tables()],
                   f"## A rig's controller ({md.code(STATION_SCHEMA)})",
                   *[t.markdown() for t in rig_tables()])
