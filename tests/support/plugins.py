"""A plug-in effect for the tests, and a catalogue that is left as it was found."""
from __future__ import annotations

import contextlib
import textwrap
from typing import Iterator

from plant import loader, plugins
from plant.catalogue import CATALOGUE

#: a force disturbance A·sin(2πft + φ) whose default frequency (1 Hz) is a third of the tests'
RIPPLE = textwrap.dedent('''\
    import numpy as np
    from plant import Effect, Param, Stage

    class Ripple(Effect):
        """Pump ripple: a force disturbance A·sin(2πft + φ)."""
        name = "ripple"
        stage = Stage.DISTURBANCE
        summary = "pump ripple"
        params = (Param("amplitude", 20.0, 0.0, 500.0, "kgf", "amplitude A"),
                  Param("frequency", 1.0, 0.1, 50.0, "Hz", "frequency f", log=True),
                  Param("phase", 0.0, -3.1416, 3.1416, "rad", "phase"))

        def disturbance(self, t, dt):
            w = 2 * np.pi * self.frequency
            return self.amplitude * (np.sin(w * (t + dt) + self.phase) - np.sin(w * t + self.phase)) / dt
''')


@contextlib.contextmanager
def isolated_catalogue() -> Iterator[None]:
    """Plug-ins join the process's catalogue: restore it (and what the loader remembers)."""
    saved = (dict(CATALOGUE), dict(plugins.ORIGINS), dict(loader._LOADED),
             plugins._installed_loaded, list(plugins.WARNINGS))
    try:
        yield
    finally:
        for live, old in zip((CATALOGUE, plugins.ORIGINS, loader._LOADED), saved):
            live.clear()
            live.update(old)
        plugins._installed_loaded = saved[3]
        plugins.WARNINGS[:] = saved[4]
