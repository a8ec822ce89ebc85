"""The master's start-up of one node from its device file: identity, configuration, read-back.

What CiA 302's configuration manager does, for the objects the loop needs:

1. **identity** (0x1018): vendor and product as the device's EDS states them, the revision in
   the range its device file accepts; a mismatch names the node and what was expected;
2. **configuration**: the node's plan (:func:`devices.plan.plan_node`: error control, period,
   device mode, the cyclic PDOs in CiA 301's order), each SDO write checked; a refusal says
   which write, the abort code and what it means;
3. **read-back** of every PDO the loop uses (canopen's ``PdoMap.read``): its COB-ID, transmission
   type and mapping must be what the plan set; the loop's codecs are built from what was read;
4. **scaling**: the process value's unit and decimals (0x6131/0x6132, or the device file's), the
   setpoint's reference (0x6311, or the file's, or 16384 counts at 100 %).

Every failure is one :class:`~core.errors.NodeError` naming the node, its device file and what
to do: never a traceback, and nothing has moved (the nodes are still PRE-OPERATIONAL).
"""
from __future__ import annotations

import contextlib
import logging
from dataclasses import dataclass, field
from typing import Iterator

import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from core.errors import NodeError
from dbc import HERE as DBC_DIR
from dbc.pdo_codec import PdoLayout, PdoLayoutError
from devices import Device, NodePlan
from devices.device import revision_text
from devices.plan import PdoSetup
from devices.roles import DYNAMOMETER, key_text
from devices.units import FULL_SCALE_DEFAULT, SetpointScale, kgf_per_count, unit_name_of_code

log = logging.getLogger(__name__)

_SDO_ERRORS = (SdoCommunicationError, SdoAbortedError)
IDENTITY = 0x1018

#: what an SDO abort code means for the master's set-up, and what to do (CiA 301 §7.2.4.3.17)
ABORT_ADVICE = {
    0x06010000: "the device does not allow this access to the object",
    0x06010002: "the object is read-only on this device although its EDS lets the master "
                "write it: the EDS is not this device's (check its revision), or mark the "
                "object ro in the EDS so the gateway uses it as it is",
    0x06020000: "the device has no such object although its EDS lists it: the EDS is not this "
                "device's (check its revision)",
    0x06040041: "the device cannot map this object to a PDO: choose another object in the "
                "device file, or correct PDOMapping in the EDS",
    0x06040042: "the mapped objects exceed the PDO's length on this device: map fewer or "
                "smaller objects",
    0x06040043: "a parameter is incompatible with the device's other settings",
    0x06070010: "the data type does not match the object (wrong length): the EDS's DataType "
                "is not the device's",
    0x06090011: "the device has no such sub-index although its EDS lists it",
    0x06090030: "the value is outside the range the device accepts",
    0x08000020: "the device cannot store or transfer the value now",
    0x08000022: "the device refuses it in its present state: it must be PRE-OPERATIONAL, and a "
                "PDO's COB-ID invalid while its mapping changes",
}


def abort_text(code: int) -> str:
    """An SDO abort code as CiA 301 names it, with what it means here."""
    name = SdoAbortedError.CODES.get(code, "unknown abort code")
    advice = ABORT_ADVICE.get(code)
    return f"SDO abort 0x{code:08X} ({name})" + (f": {advice}" if advice else "")


@dataclass
class NodeSetup:
    """What the start-up found and set on one node: its identity, its plan, the layouts of the
    PDOs the loop uses as read back, and the notes (what the device lacks)."""

    identity: dict = field(default_factory=dict)
    plan: NodePlan | None = None
    tpdo: PdoLayout | None = None
    rpdo: PdoLayout | None = None
    notes: list[str] = field(default_factory=list)


def node_label(role: str, node_id: int, device: Device) -> str:
    """``valve node 1``, with the device and its file where it is not the emulated pair's."""
    if device.eds.parent == DBC_DIR:
        return f"{role} node {node_id}"
    return f"{role} node {node_id} ({device.name}, {device.where})"


@contextlib.contextmanager
def sdo_errors(label: str, node: canopen.RemoteNode, what: str) -> Iterator[None]:
    """An SDO timeout or abort as a :class:`NodeError` that names the node and says what the
    master was doing, not canopen's traceback."""
    try:
        yield
    except SdoAbortedError as exc:
        raise NodeError(node.id, f"{label}: {what}: {abort_text(exc.code)}") from None
    except SdoCommunicationError as exc:
        timeout = node.sdo.RESPONSE_TIMEOUT
        raise NodeError(node.id, f"{label}: {what}: {exc} within {timeout * 1e3:g} ms: is it "
                                 "powered and on this bus? On a slow host, raise --sdo-timeout") from None


def check_identity(node: canopen.RemoteNode, role: str, device: Device) -> dict:
    """Read 0x1018 and compare it with the device's EDS (vendor, product) and the device
    file's revision range; returns what was read."""
    label = node_label(role, node.id, device)
    od = node.object_dictionary
    values = {}
    with sdo_errors(label, node, "cannot read its identity (0x1018) over SDO"):
        for sub, name in ((1, "vendor"), (2, "product"), (3, "revision"), (4, "serial")):
            if sub <= 2 or (IDENTITY in od and sub in od[IDENTITY]):
                values[name] = int(node.sdo[IDENTITY][sub].raw)
    expected = device.identity
    if (values["vendor"], values["product"]) != (expected.vendor, expected.product):
        raise NodeError(
            node.id,
            f"node {node.id} is not the expected {role}: it answers vendor 0x{values['vendor']:08X} "
            f"product 0x{values['product']:08X}, but {device.where} describes "
            f"{expected.text()}. Check --valve-id/--dynamometer-id (swapped node ids?) and that "
            "the device file names this device's EDS (stand bench scan lists what answers)")
    revision = values.get("revision")
    if device.revisions is not None and revision is not None and revision not in device.revisions:
        raise NodeError(
            node.id,
            f"{label}: revision {revision_text(revision)} is outside the revisions "
            f"{device.revisions.text} its device file accepts: check the EDS is this "
            "revision's and widen `revision` in the device file if it is")
    return values


def sdo_variable(node: canopen.RemoteNode, key):
    """The node's SDO variable for ``(index, sub)``, a plain variable or a sub-index alike."""
    index, sub = key
    var = node.sdo[index]
    if isinstance(node.object_dictionary[index], canopen.objectdictionary.ODVariable):
        return var
    return var[sub]


def write_plan(node: canopen.RemoteNode, label: str, plan: NodePlan) -> None:
    """Carry out the plan's SDO writes in order (:meth:`devices.plan.NodePlan.writes`)."""
    for write in plan.writes():
        with sdo_errors(label, node, f"the device refused {write.text()}"):
            sdo_variable(node, (write.index, write.sub)).raw = write.value


def read_back(node: canopen.RemoteNode, label: str, setup: PdoSetup) -> PdoLayout:
    """The PDO as the device now has it (canopen's ``PdoMap.read``), checked against the plan;
    the loop's codec for it."""
    maps = node.tpdo if setup.direction == "tpdo" else node.rpdo
    pdo_map = maps[setup.number]
    with sdo_errors(label, node, f"cannot read {setup.name} back (0x{setup.com_index:04X}/"
                                 f"0x{setup.map_index:04X})"):
        pdo_map.read()
    found = []
    if not pdo_map.enabled:
        found.append("it is disabled (COB-ID bit 31 set)")
    if (pdo_map.cob_id or 0) != setup.cob_id:
        found.append(f"COB-ID 0x{pdo_map.cob_id or 0:X} instead of 0x{setup.cob_id:X}")
    if pdo_map.trans_type != setup.trans_type:
        found.append(f"transmission type {pdo_map.trans_type} instead of {setup.trans_type}")
    keys = tuple((v.index, v.subindex) for v in pdo_map.map if v.length)
    if keys != setup.keys:
        found.append(f"mapping {', '.join(key_text(k) for k in keys) or 'empty'} instead of "
                     f"{', '.join(key_text(k) for k in setup.keys)}")
    if found:
        raise NodeError(node.id, f"{label}: {setup.name} read back differs from what was set: "
                                 f"{'; '.join(found)}. The device did not keep its configuration "
                                 "(is it in PRE-OPERATIONAL? does its EDS match it?)")
    try:
        return PdoLayout.from_map(pdo_map)
    except PdoLayoutError as exc:
        raise NodeError(node.id, f"{label}: {setup.name}: {exc}") from None


def force_scale(node: canopen.RemoteNode, role: str, device: Device) -> float:
    """kgf per count of the amplifier's process value: the unit and decimals of its device
    file, else of 0x6131/0x6132 read from it."""
    label = node_label(role, node.id, device)
    unit, decimals = device.unit, device.decimals
    integer = device.types["process_value"] != canopen.objectdictionary.REAL32
    with sdo_errors(label, node, "cannot read its unit/decimals (0x6131/0x6132)"):
        if unit is None:
            code = int(sdo_variable(node, device.key("pv_unit")).raw)
            try:
                unit = unit_name_of_code(code)
            except ValueError as exc:
                raise NodeError(node.id, f"{label}: {exc}") from None
        if decimals is None:
            key = device.key("pv_decimals")
            decimals = int(sdo_variable(node, key).raw) if key is not None else 0
    try:
        return kgf_per_count(unit, decimals, integer)
    except ValueError as exc:
        raise NodeError(node.id, f"{label}: the process value's {exc}") from None


def setpoint_scale(node: canopen.RemoteNode, role: str, device: Device) -> SetpointScale:
    """The valve's counts at 100 %: the device file's, else 0x6311 read from it, else 16384."""
    bits = device.type_bits("setpoint")
    full = device.setpoint_full_scale
    key = device.key("setpoint_reference")
    if full is None and key is not None:
        with sdo_errors(node_label(role, node.id, device), node,
                        f"cannot read its setpoint reference ({key_text(key)})"):
            full = int(sdo_variable(node, key).raw)
        if full <= 0:
            raise NodeError(node.id, f"{node_label(role, node.id, device)}: its setpoint reference "
                                     f"({key_text(key)}) is {full}: give setpoint_full_scale in the "
                                     "device file")
    return SetpointScale(full or FULL_SCALE_DEFAULT, bits)


def is_dynamometer(device: Device) -> bool:
    return device.kind == DYNAMOMETER
