"""A rig: many loading channels on one structure, on one or several CAN buses.

- :mod:`rig.config`: the rig file (``rig.toml``): buses, channels (valve and dynamometer node
  ids, range, limits, the emulated plant), the structure (G, or K with the flow gains);
- :mod:`rig.budget`: what each bus carries per cycle against what it may, and what would fit;
- :mod:`rig.emulated`: what the emulator runs for a rig (the coupled plant, each channel's
  plant with its range, the noise seeds) and the truth of an emulated rig;
- :mod:`rig.check`: every problem of a rig file that can be found before anything moves.

The physics of the coupled channels is the plant's (:mod:`plant.rig`).
"""
