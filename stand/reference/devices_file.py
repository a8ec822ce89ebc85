"""``docs/reference/devices-toml.md``: a device file (:mod:`devices.device`). The example is the
module's own; the roles, their profile objects and types come from :mod:`devices.roles`; the
other keys' meanings are written here, and ``tests/test_reference.py`` checks that the tables
name exactly the keys the loader accepts."""
from __future__ import annotations

from . import markdown as md
from .keys import Key, Table


def _role_keys(kind: str) -> tuple[Key, ...]:
    from devices.roles import ROLES, key_text
    out = []
    for role in ROLES[kind]:
        objects = " or ".join(key_text(k) for k in role.candidates)
        need = "needed" if role.required else f"optional: without it {role.without}"
        out.append(Key(role.name, f"the object of the {role.what}, {role.type_names()}; {need}",
                       md.code(objects), "object"))
    return tuple(out)


def _common() -> tuple[Key, ...]:
    from devices.device import ERROR_CONTROLS
    return (
        Key("eds", "the maker's EDS (or a DCF), relative to the device file", "required", "string"),
        Key("revision", "the firmware revisions accepted: `\"2.3\"`, a range `\"2.0-2.9\"`, or "
            "`\"2\"` for every 2.x", "any", "string"),
        Key("error_control", f"how the gateway knows the device is alive: "
            f"{' or '.join(md.code(c) for c in ERROR_CONTROLS)}",
            "heartbeat where the EDS has 0x1017, else guarding", "string"),
        Key("tpdo", "the TPDO (1-based) that carries what the device sends every cycle",
            "the first that carries it, else the first with a dynamic mapping", "integer"),
    )


def tables() -> tuple[Table, ...]:
    objects = ("An object is written in hex, `\"0x6300:01\"` (index and sub-index) or `\"0x6040\"` "
               "(sub-index 0); `\"none\"` for an optional one the device lacks.")
    return (
        Table("", (
            Key("name", "the device set's name in messages and run.json", "the two products' names",
                "string"),
            Key("valve", "the servo-valve drive (CiA 408)", "required", "`[valve]`"),
            Key("dynamometer", "the force amplifier (CiA 404)", "required", "`[dynamometer]`"),
        )),
        Table("[valve]", (*_common(),
            Key("rpdo", "the RPDO (1-based) that carries the command",
                "the first that carries it, else the first with a dynamic mapping", "integer"),
            *_role_keys("valve"),
            Key("setpoint_full_scale", "the setpoint's counts at 100 % (10 V)",
                "0x6311, else 16384", "integer")), objects),
        Table("[dynamometer]", (*_common(), *_role_keys("dynamometer"),
            Key("unit", "the process value's unit, where the device has no 0x6131 or says it wrongly: "
                "N, daN, kN, MN, mN, kgf, tf or lbf", "read from 0x6131", "string"),
            Key("decimals", "the process value's decimal digits (an integer value: a count is "
                "10^-decimals of the unit)", "read from 0x6132", "integer")), objects),
    )


def page() -> str:
    import devices.device
    intro = ("A device file names the valve drive and the force amplifier of a channel: each one's "
             "EDS and, where it differs from its CiA profile, the objects that play the roles the "
             "loop needs. `--devices FILE` gives it to `stand emulate`, `run`, `load`, `campaign`, "
             "`demo` and `test`; a rig file names it with `devices`. A mistake is one error naming "
             "the file, the table and what to do. How to write one: [docs/devices.md](../devices.md).")
    example = md.fenced(md.literal_block(devices.device.__doc__), "toml")
    return md.page("The device file (`devices.toml`)", intro, "## An example", example,
                   "## The keys", *[t.markdown() for t in tables()])
