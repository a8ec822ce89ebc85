"""A node's configuration as a DCF (CiA 306 device configuration file): its EDS with the values
the gateway sets (``ParameterValue``) and the node id and bit rate ([DeviceComissioning]), so
other CANopen tools (a configuration manager, a bus analyser, the maker's tool) load exactly
what the gateway writes at start-up. Written by canopen's own exporter."""
from __future__ import annotations

import io
from pathlib import Path

from canopen.objectdictionary import ODVariable, export_od

from .device import find_variable
from .plan import NodePlan


def node_dcf(plan: NodePlan, bitrate: int | None = None) -> str:
    """The DCF text of ``plan``'s node: every value the plan writes (the last write of each
    object, as it stands once configured), the node id and the bit rate (bit/s)."""
    od = plan.device.od(plan.node_id)
    for write in plan.writes():
        var = find_variable(od, (write.index, write.sub))
        if var is None or not isinstance(var, ODVariable):
            continue
        var.value = write.value
        var.value_raw = None
    od.node_id = plan.node_id
    if bitrate:
        od.bitrate = bitrate
    od.comments = (f"Configured by hydrostand for node {plan.node_id}: {plan.device.name} "
                   f"({plan.device.where}).\n"
                   + "\n".join(f"{p.name}: {', '.join(p.describe()['objects'])}"
                               for p in (plan.rpdo, plan.tpdo) if p is not None))
    out = io.StringIO()
    export_od(od, out, doc_type="dcf")
    return out.getvalue()


def write_dcf(plan: NodePlan, path: str | Path, bitrate: int | None = None) -> Path:
    path = Path(path)
    path.write_text(node_dcf(plan, bitrate))
    return path
