"""The stand's frame definitions: one EDS per CANopen node and one DBC for every frame.

- ``servo_valve.eds``: servo-valve drive, CiA 408 (node 1 by default)
- ``dynamometer.eds``: force transducer, CiA 404 (node 2 by default)
- ``stand.dbc``: every frame on the bus (NMT, SYNC, EMCY, PDOs, SDO, heartbeats); the force
  signal ``Force`` is in kgf and the valve command ``Command`` in %.
- ``stand.codecs.json``: ``stand.dbc``'s signal codecs, precompiled so a capture is decoded
  without loading cantools (written by ``python -m captures.dbctable``)
"""
from pathlib import Path

HERE = Path(__file__).resolve().parent
VALVE_EDS = HERE / "servo_valve.eds"
DYNAMOMETER_EDS = HERE / "dynamometer.eds"
STAND_DBC = HERE / "stand.dbc"
STAND_CODECS = HERE / "stand.codecs.json"

__all__ = ["DYNAMOMETER_EDS", "HERE", "STAND_CODECS", "STAND_DBC", "VALVE_EDS"]
