"""A rig: many loading channels on one structure, on one or several CAN buses.

- :mod:`rig.config`: the rig file (``rig.toml``): buses, channels (valve and dynamometer node
  ids, range, limits, the emulated plant), the structure (G, or K with the flow gains).

The physics of the coupled channels is the plant's (:mod:`plant.rig`).
"""
