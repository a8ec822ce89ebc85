"""``docs/reference/rig-toml.md``: the rig file (:mod:`rig.config`). The example is the module's
own; defaults come from its constants; the meanings are written here, and
``tests/test_reference.py`` checks that the tables name exactly the keys the loader accepts."""
from __future__ import annotations

from . import markdown as md
from .keys import Key, Table, value


def tables() -> tuple[Table, ...]:
    from rig.config import (CHANGE_FACTOR_RANGE, DEFAULT_BITRATE, DEFAULT_LIMIT_SHARE, DEFAULT_LOAD_LIMIT,
                            DEFAULT_PERIOD_S, DEFAULT_RANGE_KGF, RigConfig)
    name_rule = "letters, digits, `_` or `-`, starting with a letter (it names files and columns)"
    return (
        Table("", (
            Key("name", "the rig's name in reports and run.json", "the file's name", "string"),
            Key("period_ms", "the control period, ms (0.5 to 100): one SYNC per bus per cycle",
                value(DEFAULT_PERIOD_S * 1e3), "number"),
            Key("bus_load_limit_pct", "the worst-case load a bus may carry, % (1 to 100); "
                "`stand rig check` says when a bus would exceed it", value(100 * DEFAULT_LOAD_LIMIT), "number"),
            Key("heartbeat_ms", "the nodes' heartbeat period, ms (10 to 10000)", value(RigConfig.heartbeat_ms),
                "integer"),
            Key("devices", "the device file of every channel's valve drive and amplifier, relative "
                "to the rig file ([device files](devices-toml.md)); a channel may name its own",
                "the emulated pair", "string"),
            Key("bus", "the CAN buses, at least one", "required", "`[[bus]]`"),
            Key("channel", "the loading channels, at least one, in the order of G's rows", "required",
                "`[[channel]]`"),
            Key("structure", "what couples the channels; without it each channel's plant gives its own g "
                "(no coupling)", "", "`[structure]`"),
        )),
        Table("[[bus]]", (
            Key("name", f"the bus's name: {name_rule}", "required", "string"),
            Key("spec", "a python-can bus, `INTERFACE:CHANNEL[,key=value...]`: `socketcan:can0`, "
                "`pcan:PCAN_USBBUS1`, `udp_loopback:rig-can0`", "required", "string"),
            Key("bitrate", "the nominal (arbitration) bit rate, bit/s (10,000 to 1,000,000)",
                value(DEFAULT_BITRATE), "integer"),
            Key("fd", "CAN FD: the data phase at `data_bitrate`", value(False), "true/false"),
            Key("data_bitrate", "with `fd = true`: the data phase's bit rate, bit/s (`bitrate` to 12,000,000)",
                "`bitrate`", "integer"),
        )),
        Table("[[channel]]", (
            Key("name", f"the channel's name: {name_rule}", "required", "string"),
            Key("bus", "the `name` of the `[[bus]]` its two nodes are on", "required", "string"),
            Key("valve_id", "the servo-valve drive's CANopen node id (CiA 408), 1 to 127", "required", "integer"),
            Key("dynamometer_id", "the dynamometer's node id (CiA 404), 1 to 127; every id on a bus is "
                "used once", "required", "integer"),
            Key("range_kgf", "the dynamometer's range, kgf", value(DEFAULT_RANGE_KGF), "number"),
            Key("force_limit_kgf", "the supervisor's force limit, kgf (at most `range_kgf`)",
                f"{100 * DEFAULT_LIMIT_SHARE:g} % of `range_kgf`", "number"),
            Key("devices", "this channel's device file ([device files](devices-toml.md))",
                "the rig's `devices`", "string"),
            Key("plant", "the emulated plant behind the two nodes (`stand emulate --rig` only): a plant "
                "file's tables, or the path of a plant file ([model files](model-toml.md#plant-files)); "
                "its g is the structure's diagonal", "", "table or string"),
        )),
        Table("[structure]", (
            Key("G", "the coupling, kgf/(%·s): N rows of N numbers in the channels' order; row i is "
                "channel i's force rate, column j channel j's valve, `G[i][i]` the channel's own g",
                "", "array"),
            Key("K", "instead of G: the structure's stiffness at the attachment points, kgf/mm "
                "(N × N, symmetric); then `G = K·diag(c/A)`", "", "array"),
            Key("flow_gain_mm_per_pct_s", "with K: each actuator's flow gain over its piston area, "
                "c/A in mm/(%·s), N positive numbers", "", "array"),
            Key("change", "the emulated structure's scheduled changes (a crack); the emulator only",
                "", "`[[structure.change]]`"),
        ), "Give G, or K with `flow_gain_mm_per_pct_s`, or neither when every channel has a plant."),
        Table("[[structure.change]]", (
            Key("channel", "the channel at whose attachment point the structure changes", "required",
                "string"),
            Key("stiffness_factor", f"the point's stiffness times this ({CHANGE_FACTOR_RANGE[0]:g} to "
                f"{CHANGE_FACTOR_RANGE[1]:g}; below 1: softer); its row and column of K and G fall by it",
                "required", "number"),
            Key("from_s", "the stand time it begins at, s since the emulator started", "required", "number"),
            Key("ramp_s", "at once (0), or linearly over this long, s", value(0.0), "number"),
        ), "`stand emulate --rig RIG.toml --change CHANNEL:FACTOR@FROM_S[+RAMP_S]` adds more."),
    )


def page() -> str:
    import rig.config
    intro = ("A rig file says what a rig *is*: its CAN buses, its loading channels (a valve and a "
             "dynamometer each) and the structure that couples them. `stand rig check RIG.toml` "
             "checks it; `--rig RIG.toml` gives it to `stand emulate`, `run`, `campaign`, `load` "
             "and a test file's `station`. A mistake is one error naming the file, the table and "
             "the key; an unknown key is refused by name. How to build a rig: "
             "[docs/rig.md](../rig.md).")
    example = md.fenced(md.literal_block(rig.config.__doc__), "toml")
    return md.page("The rig file (`rig.toml`)", intro, "## An example", example, "## The keys",
                   *[t.markdown() for t in tables()])
