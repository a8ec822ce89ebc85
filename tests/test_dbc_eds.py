"""The DBC describes exactly the frames the EDS files' PDO mappings produce."""
from __future__ import annotations


import canopen
import cantools
import pytest

from dbc import DYNAMOMETER_EDS, STAND_DBC, VALVE_EDS
from dbc import profile as P
from dbc.pdo_codec import PdoLayout

DB = cantools.database.load_file(str(STAND_DBC))
_SIGNED = {canopen.objectdictionary.INTEGER8, canopen.objectdictionary.INTEGER16,
           canopen.objectdictionary.INTEGER32}
# DBC signal name for each mapped object
SIGNAL_OF = {
    (0x6040, 0): "ControlWord", (0x6300, 1): "Command",
    (0x6041, 0): "StatusWord", (0x6301, 1): "ValvePosition",
    (0x9130, 1): "Force", (0x6150, 1): "ForceStatus",
}


def _pdo_maps(eds, node_id):
    net = canopen.Network()
    node = canopen.LocalNode(node_id, str(eds))
    net.add_node(node)
    node.tpdo.read(from_od=True)
    node.rpdo.read(from_od=True)
    return [m for m in list(node.tpdo.map.values()) + list(node.rpdo.map.values()) if m.enabled]


@pytest.mark.parametrize("eds,node_id", [(VALVE_EDS, P.VALVE_NODE_ID), (DYNAMOMETER_EDS, P.DYNAMOMETER_NODE_ID)])
def test_every_enabled_pdo_has_a_matching_dbc_message(eds, node_id):
    maps = _pdo_maps(eds, node_id)
    assert maps, "each node has at least one enabled PDO"
    for m in maps:
        msg = DB.get_message_by_frame_id(m.cob_id)
        assert msg.length == m.length // 8, f"{msg.name}: DBC length vs mapping"
        mapped = [v for v in m.map if v.length]
        assert len(msg.signals) == len(mapped), msg.name
        for var in mapped:
            sig = msg.get_signal_by_name(SIGNAL_OF[var.index, var.subindex])
            assert sig.start == var.offset and sig.length == var.length, sig.name
            assert sig.byte_order == "little_endian"
            assert sig.is_signed == (var.od.data_type in _SIGNED), sig.name


def test_dbc_scaling_matches_the_profiles():
    force = DB.get_message_by_name("TPDO1_Dynamometer").get_signal_by_name("Force")
    assert force.unit == "kgf"
    assert force.scale == P.force_scale_kgf(P.UNIT_N_DEFAULT, 1)   # 0.1 N per count, bit-exact
    cmd = DB.get_message_by_name("RPDO1_Valve").get_signal_by_name("Command")
    assert cmd.unit == "%" and cmd.scale == P.PERCENT_PER_COUNT
    assert cmd.scale * 16384 == 100.0
    # the EDS defaults the gateway reads to scale the force say the same
    od = canopen.import_od(str(DYNAMOMETER_EDS), 2)
    assert od[0x6131][1].default == P.UNIT_N_DEFAULT and od[0x6132][1].default == 1


def test_dbc_describes_the_protocol_frames_of_both_nodes():
    ids = {m.frame_id for m in DB.messages}
    for nid in (P.VALVE_NODE_ID, P.DYNAMOMETER_NODE_ID):
        assert {0x80 + nid, 0x580 + nid, 0x600 + nid, 0x700 + nid} <= ids
    assert {0x000, 0x080} <= ids
    sync = DB.get_message_by_frame_id(0x80)
    assert sync.decode(bytes([17]))["SYNC_Counter"] == 17


def test_decoding_a_force_pdo_with_the_dbc_gives_kgf():
    msg = DB.get_message_by_name("TPDO1_Dynamometer")
    layout = PdoLayout.from_entries(0x182, [(0x9130, 1, 32, canopen.objectdictionary.INTEGER32),
                                            (0x6150, 1, 8, canopen.objectdictionary.UNSIGNED8)])
    data = layout.encode(-980665, P.AI_STATUS_NEGATIVE_OVERLOAD)
    decoded = msg.decode(data)
    assert decoded["Force"] == pytest.approx(-10000.0, abs=1e-9)
    assert decoded["ForceStatus"] == P.AI_STATUS_NEGATIVE_OVERLOAD


def test_eds_identity_and_device_types():
    valve = canopen.import_od(str(VALVE_EDS), 1)
    dyn = canopen.import_od(str(DYNAMOMETER_EDS), 2)
    assert valve[0x1000].default & 0xFFFF == 408 and dyn[0x1000].default & 0xFFFF == 404
    assert valve[0x1018][1].default == valve.device_information.vendor_number
    assert dyn[0x1018][2].default == dyn.device_information.product_number
    assert (valve.device_information.vendor_number, valve.device_information.product_number) != \
           (dyn.device_information.vendor_number, dyn.device_information.product_number)


def test_command_scaling_round_trip_and_nan_safety():
    assert P.percent_to_counts(100.0) == 16384 and P.percent_to_counts(-250.0) == -16384
    assert P.percent_to_counts(float("nan")) == 0 and P.percent_to_counts(float("inf")) == 0
    for counts in (-16384, -1, 0, 1, 8192, 16384):
        assert P.percent_to_counts(P.counts_to_percent(counts)) == counts
    with pytest.raises(ValueError, match="not newtons"):
        P.force_scale_kgf(0x00FF0000, 1)
