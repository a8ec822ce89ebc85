"""Files that outlive a crash or a power cut: a JSON record written whole or not at all (the one
way the project writes ``run.json``, a campaign's plan, an endurance test's session records),
and the ``fsync`` of a file or of a directory's entries that a rename needs to be durable."""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Mapping


def write_json(path: str | Path, data: Mapping[str, Any]) -> None:
    """Write ``data`` to ``path`` atomically and durably: into a hidden temporary file beside it,
    flushed to the disk, then renamed over ``path`` (the rename made durable too where the
    system allows), so a crash or a power cut leaves the old file or the new one, never half
    of one. numpy scalars and paths are written as numbers and strings; anything else that
    JSON cannot hold is a TypeError, before the old file is touched."""
    path = Path(path)
    text = json.dumps(data, indent=2, default=_json_default) + "\n"
    tmp = path.parent / f".{path.name}.{os.getpid()}.tmp"      # (two writers never share one)
    try:
        with open(tmp, "w") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def fsync_file(path: str | Path) -> None:
    """The file's data on the disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_dir(path: str | Path) -> None:
    """The directory's entries on the disk (a rename or a new file in it made durable); where
    the system cannot open or sync a directory, nothing."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "item"):           # numpy scalars
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")
