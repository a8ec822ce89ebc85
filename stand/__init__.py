"""The ``stand`` command line: one module per sub-command in :mod:`stand.commands`, each a thin
layer over the library (:mod:`gateway`, :mod:`plant_emulator`, :mod:`analysis`)."""
