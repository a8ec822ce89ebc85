"""The stand's DBC for a channel's devices as configured: what a capture decoder (ours, or any
DBC tool) needs to read a run of devices other than the emulated pair.

``dbc/stand.dbc`` describes the emulated pair at nodes 1 and 2; another device set puts its
cyclic PDOs on other COB-IDs, with other layouts and process value types. This writes the same
database with those three messages replaced by the ones the master set up (its
:class:`~devices.plan.NodePlan`), their signals named as the capture decoder reads them
(``StatusWord``, ``ValvePosition``, ``Force``, ``ForceStatus``, ``ControlWord``, ``Command``;
other mapped objects by their index), at nodes 1 and 2 as the decoder renumbers a channel's
nodes (``captures.nodes``). The gateway writes it into a run directory (``stand.dbc``) and
``stand bench dcf`` beside the DCFs.
"""
from __future__ import annotations

import cantools
from cantools.database.can import Message, Signal
from cantools.database.conversion import BaseConversion
from canopen.objectdictionary import REAL32

from dbc import STAND_DBC
from dbc import profile as P

from .plan import NodePlan, PdoSetup
from .roles import Key

_SIGNED = {0x2, 0x3, 0x4}     # INTEGER8/16/32


def _signals(setup: PdoSetup, names: dict[Key, tuple[str, float, str]], receiver: str) -> list[Signal]:
    out, start = [], 0
    for index, sub, bits, dtype in setup.entries:
        name, scale, unit = names.get((index, sub), (f"Obj_{index:04X}_{sub:02X}", 1.0, ""))
        is_float = dtype == REAL32
        out.append(Signal(name, start, bits, "little_endian", is_signed=dtype in _SIGNED or is_float,
                          conversion=BaseConversion.factory(scale=scale, offset=0, is_float=is_float),
                          unit=unit or None, receivers=[receiver]))
        start += bits
    return out


def _message(setup: PdoSetup, node_id: int, default_node: int, name: str, sender: str,
             receiver: str, names, comment: str) -> Message:
    frame_id = setup.cob_id - node_id + default_node if setup.cob_id & 0x7F == node_id else setup.cob_id
    return Message(frame_id, name, (sum(e[2] for e in setup.entries) + 7) // 8,
                   _signals(setup, names, receiver), senders=[sender], comment=comment,
                   cycle_time=None)


def stand_dbc(valve: NodePlan, dynamometer: NodePlan, force_kgf_per_count: float,
              setpoint_full_scale: int) -> str:
    """The stand's DBC text for these devices as configured (the module doc)."""
    db = cantools.database.load_file(str(STAND_DBC))
    cyclic = {"TPDO1_Valve", "TPDO1_Dynamometer", "RPDO1_Valve"}
    keep = [m for m in db.messages if m.name not in cyclic]
    pct = 100.0 / setpoint_full_scale
    vd, dd = valve.device, dynamometer.device
    valve_names = {vd.key("status_word"): ("StatusWord", 1.0, ""),
                   vd.key("actual_spool"): ("ValvePosition", pct, "%"),
                   vd.key("control_word"): ("ControlWord", 1.0, ""),
                   vd.key("setpoint"): ("Command", pct, "%")}
    force_names = {dd.key("process_value"): ("Force", force_kgf_per_count, "kgf"),
                   dd.key("status"): ("ForceStatus", 1.0, "")}
    messages = keep + [
        _message(valve.tpdo, valve.node_id, P.VALVE_NODE_ID, "TPDO_Valve", "Valve", "Gateway",
                 valve_names, f"Valve {valve.tpdo.name} ({vd.name}), on every SYNC"),
        _message(dynamometer.tpdo, dynamometer.node_id, P.DYNAMOMETER_NODE_ID, "TPDO_Dynamometer",
                 "Dynamometer", "Gateway", force_names,
                 f"Amplifier {dynamometer.tpdo.name} ({dd.name}), on every SYNC"),
        _message(valve.rpdo, valve.node_id, P.VALVE_NODE_ID, "RPDO_Valve", "Gateway", "Valve",
                 valve_names, f"Valve {valve.rpdo.name} ({vd.name}): the command"),
    ]
    out = cantools.database.can.Database(messages=sorted(messages, key=lambda m: m.frame_id),
                                         nodes=db.nodes, version=db.version)
    return out.as_dbc_string()
