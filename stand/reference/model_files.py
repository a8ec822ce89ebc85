"""``docs/reference/model-toml.md``: model files, plant files (the emulator's) and rig model
files (:mod:`plant.config`). Every parameter table is the code's: the base model's, each
built-in effect's, the sensor's and the initial state's :class:`~plant.params.Param` (default,
range, unit, meaning); the examples are the module's own. Effects of plug-ins are not listed
(``stand effects --effects FILE.py`` lists them with the same columns)."""
from __future__ import annotations

from typing import Sequence

from . import markdown as md
from .keys import Key, Table, value


def params_table(params: Sequence, prefix: str = "") -> str:
    """A table of :class:`~plant.params.Param`: key, unit, default, range, meaning."""
    rows = [[md.code(prefix + p.name), md.text(p.unit), value(p.default),
             f"{p.lower:g} to {p.upper:g}", md.text(p.doc)] for p in params]
    return md.table(["key", "unit", "default", "range", "what it is"], rows)


def model_tables() -> tuple[Table, ...]:
    return (Table("", (
        Key("model", 'which effects, e.g. `"base+reversal"` (starts with `base`); an effect named here '
            "without a table takes its defaults", '`"base"` and the tables\' effects', "string"),
        Key("plugins", "the plug-in effects the model uses: `.py` files (relative to this file) or module "
            "names ([docs/your-own-effect.md](../your-own-effect.md))", "", "array of strings"),
        Key("base", "the base model's parameters", "", "`[base]`"),
        Key("effects", "a table per effect, its keys the effect's parameters and `enabled` "
            "(`false` keeps the numbers and switches the effect off)", "", "`[effects.NAME]`"),
    )),)


def plant_tables() -> tuple[Table, ...]:
    return (Table("", model_tables()[0].keys + (
        Key("sensor", "the dynamometer: noise, resolution, range", "", "`[sensor]`"),
        Key("initial", "where the plant starts", "", "`[initial]`"),
    )),)


def rig_model_tables() -> tuple[Table, ...]:
    return (
        Table("", (
            Key("channels", "the channels' names in the order of G's rows and columns", "required",
                "array of strings"),
            Key("plugins", "the plug-in effects the channels' models use", "", "array of strings"),
            Key("structure", "`G`: N rows of N numbers, kgf/(%·s); row i is channel i's force, column j "
                "channel j's valve, the diagonal each channel's own g", "required", "`[structure]`"),
            Key("channel", "each channel's model: a model file's tables (`model`, `[base]` without g, "
                "`[effects.NAME]`)", "required", "`[channel.NAME]`"),
        )),
        Table("[structure]", (Key("G", "the coupling, kgf/(%·s)", "required", "array"),)),
    )


def _effects() -> str:
    from plant.catalogue import BUILTINS, CATALOGUE
    parts = []
    for name in BUILTINS:
        cls = CATALOGUE[name]
        flag = "" if cls.diagnosable else " (not offered by `stand diagnose`)"
        parts.append(f"#### `[effects.{name}]`\n\n{md.text(cls.summary)}{flag}.\n\n"
                     + params_table(cls.params))
    return "\n\n".join(parts)


def page() -> str:
    import plant.config
    from plant.config import DEFAULT_MODEL, DEFAULT_VALUES, INITIAL_PARAMS
    from plant.model import BASE_PARAMS
    from plant.sensor import SENSOR_PARAMS
    doc = plant.config.__doc__
    intro = ("Three kinds of TOML file describe a plant. A **model file** is what the analysis found: "
             "`stand fit --save`, `stand diagnose --save` write one; `--model FILE.toml` and `stand "
             "design` read it. A **plant file** is what the emulator runs: a model file with a "
             "sensor and a start (`stand emulate --config`, a rig channel's `plant`). A **rig "
             "model file** is a rig's coupled plant as identified (`stand estimate RIG_RUNS "
             "--save`, `stand design RIG-MODEL.toml`). A value out of its range is refused naming "
             "the file, the table and the range. Controller files: [controller-toml.md]"
             "(controller-toml.md).")
    defaults = ", ".join(f"{k} = {v:g}" for k, v in DEFAULT_VALUES.items())
    return md.page(
        "Model, plant and rig model files",
        intro,
        "## Model files",
        md.fenced(md.literal_block(doc, 0), "toml") + "\n\n" + md.fenced(md.literal_block(doc, 1), "toml"),
        *[t.markdown() for t in model_tables()],
        "### `[base]`\n\n`dy/dt = g·u(t − τ) + Δ`, the paper's model with its trend.\n\n" + params_table(BASE_PARAMS),
        "### `[effects.NAME]`\n\nEvery effect of the catalogue, its parameters and their ranges "
        "(`stand effects` prints the same with each effect's equation; `stand effects --doc` its "
        "whole documentation). Each table also takes `enabled` (true or false, default true).",
        _effects(),
        "## Plant files",
        f"Without `--config` the emulator runs {md.code(DEFAULT_MODEL)} with {md.code(defaults)}.",
        md.fenced(md.literal_block(doc, 2), "toml"),
        *[t.markdown() for t in plant_tables()],
        "### `[sensor]`\n\n" + params_table(SENSOR_PARAMS),
        "### `[initial]`\n\n" + params_table(INITIAL_PARAMS),
        "## Rig model files",
        md.fenced(md.literal_block(doc, 3), "toml"),
        *[t.markdown() for t in rig_model_tables()],
    )
