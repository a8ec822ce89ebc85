"""Compiled loops: :func:`njit` compiles a plain Python loop over numpy arrays with numba the first
time it is called (not at import: importing numba costs ~0.7 s, which a command that never runs
the loop should not pay). Compiled code is cached beside the module (``__pycache__``), so a
later process loads it instead of compiling again (~1 s a function).

Only for loops a profile showed to matter: those numpy cannot vectorize (a recursion along the
samples: a play, a rate limit), and an elementwise law called so often that numpy's temporaries
dominate (the stiffness's gain: 14× faster in one pass; a law around ``**`` is not, numpy's
power is faster than the compiled loop's); everything else stays numpy."""
from __future__ import annotations

import functools
from typing import Callable, TypeVar

F = TypeVar("F", bound=Callable)


def njit(fn: F) -> F:
    """``numba.njit(cache=True)(fn)``, compiled on the first call."""
    compiled: list[Callable] = []

    @functools.wraps(fn)
    def call(*args):
        if not compiled:
            import numba
            compiled.append(numba.njit(cache=True, nogil=True)(fn))
        return compiled[0](*args)

    call.py_func = fn     # the plain Python version (tests compare the two)
    return call  # type: ignore[return-value]
