"""Running the command line as a user does: ``python -m stand ...`` in a process of its own."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def stand(*args: str, timeout: float = 300, cwd: str | Path | None = None) -> subprocess.CompletedProcess:
    """``stand ARGS``; never a traceback, whatever it says."""
    res = subprocess.run([sys.executable, "-m", "stand", *map(str, args)], capture_output=True,
                         text=True, timeout=timeout, cwd=cwd)
    assert "Traceback" not in res.stderr + res.stdout, res.stderr
    return res
