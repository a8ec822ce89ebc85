"""Pick the reader for a capture file by its suffix.

=================  =====================================================================
``.log``           candump / python-can canutils log: vectorized (:mod:`captures.candump`)
``.blf``           Vector BLF: vectorized (:mod:`captures.blf`)
``.asc`` ``.trc``  via python-can's readers (:mod:`captures.pycan`), batched into chunks (a Python call per frame)
``.csv`` ``.db``
``.mf4``           via python-can's ``MF4Reader`` (needs the optional ``asammdf`` package)
``*.gz``           any of the text formats, gzip-compressed
=================  =====================================================================

Every reader is an iterable of :class:`FrameChunk` with a ``stats`` (:class:`ReadStats`)
attribute that says what was skipped and where the capture is damaged. A reader's module (and
what it needs: python-can for the formats it reads) is imported when its format is opened.
"""
from __future__ import annotations

from pathlib import Path

from .formats import SUFFIXES, VECTORIZED, VIA_PYTHON_CAN  # noqa: F401 (re-exported)
from .frames import CaptureError


def capture_format(path: str | Path) -> str:
    """``"candump"``, ``"blf"``, ``"asc"``, ... from the suffix (``.gz`` looked through)."""
    path = Path(path)
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    suffix = suffixes[-1] if suffixes else ""
    if suffix in VECTORIZED:
        return VECTORIZED[suffix]
    if suffix in VIA_PYTHON_CAN:
        return VIA_PYTHON_CAN[suffix]
    raise CaptureError(f"{path}: unknown capture format {suffix or '(no suffix)'!r}; "
                       f"give one of {', '.join(SUFFIXES)} (optionally .gz)")


def open_capture(path: str | Path, chunk_bytes: int | None = None, on_damage: str = "stop"):
    """The reader for ``path`` (an iterable of :class:`FrameChunk` with ``.stats``)."""
    path = Path(path)
    if not path.exists():
        raise CaptureError(f"{path} does not exist")
    if path.is_dir():
        raise CaptureError(f"{path} is a directory, not a capture file")
    fmt = capture_format(path)
    kwargs = {"on_damage": on_damage}
    if chunk_bytes:
        kwargs["chunk_bytes"] = chunk_bytes
    # each reader is imported here, when its format is opened: a candump log needs neither the
    # BLF reader nor python-can (whose `import can` loads every log format, asammdf among them)
    if fmt == "candump":
        from .candump import CandumpReader
        return CandumpReader(path, **kwargs)
    if fmt == "blf":
        if path.suffix.lower() == ".gz":
            raise CaptureError(f"{path}: BLF is compressed already; give the .blf file")
        from .blf import BlfReader
        return BlfReader(path, **kwargs)
    from .pycan import PythonCanReader
    return PythonCanReader(path, fmt, on_damage=on_damage)
