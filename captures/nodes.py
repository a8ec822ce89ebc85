"""Read one channel of a rig's bus: its nodes' frames as the stand's DBC expects them.

A rig's bus carries several channels, each a valve and a dynamometer with their own node ids;
the stand's DBC describes node 1 (valve) and node 2 (dynamometer). A CANopen COB-ID is a
function code plus a node id (CiA 301: ``id = function | node``, the node in the low 7 bits),
so reading channel (valve v, dynamometer d) is a permutation of the node ids: v → 1, d → 2, and
the nodes 1 and 2 (another channel's) to v and d, where the DBC does not look (counted as unknown
ids). NMT (0x000) and SYNC (0x080) have node 0 and stay.
"""
from __future__ import annotations

import numpy as np

from dbc import profile as P

from .frames import EXTENDED, FrameChunk


def node_table(valve_id: int, dynamometer_id: int) -> np.ndarray:
    """The node permutation (128 entries) that makes (valve, dynamometer) nodes 1 and 2."""
    for nid in (valve_id, dynamometer_id):
        if not 1 <= nid <= 127:
            raise ValueError(f"node id {nid} is outside 1..127")
    if valve_id == dynamometer_id:
        raise ValueError("the valve and the dynamometer need different node ids")
    table = np.arange(128, dtype=np.uint32)
    wanted = {valve_id: P.VALVE_NODE_ID, dynamometer_id: P.DYNAMOMETER_NODE_ID}
    displaced = [n for n in (P.VALVE_NODE_ID, P.DYNAMOMETER_NODE_ID) if n not in wanted]
    free = [n for n in (valve_id, dynamometer_id) if n not in (P.VALVE_NODE_ID, P.DYNAMOMETER_NODE_ID)]
    for src, dst in wanted.items():
        table[src] = dst
    for src, dst in zip(displaced, free):
        table[src] = dst
    return table


def remap_nodes(chunk: FrameChunk, table: np.ndarray) -> None:
    """Renumber the nodes of the chunk's 11-bit frames in place (:func:`node_table`)."""
    ids = chunk.can_id
    std = (chunk.flags & EXTENDED) == 0
    node = ids & 0x7F
    chunk.can_id = np.where(std, (ids & ~np.uint32(0x7F)) | table[node], ids).astype(ids.dtype)
