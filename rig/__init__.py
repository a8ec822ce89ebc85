"""A rig: many loading channels on one structure, on one or several CAN buses.

- :mod:`rig.config`: the rig file (``rig.toml``): buses, channels (valve and dynamometer node
  ids, range, limits, the emulated plant), the structure (G, or K with the flow gains);
- :mod:`rig.budget`: what each bus carries per cycle against what it may, and what would fit.

The physics of the coupled channels is the plant's (:mod:`plant.rig`).
"""
