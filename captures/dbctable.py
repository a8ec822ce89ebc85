"""DBC files: read with cantools (:func:`load_dbc`), and the stand's DBC as a precompiled codec
table, so decoding with it needs no cantools at run time.

Loading a DBC means ``import cantools``, and cantools imports python-can (``cantools.tester``),
whose ``can.io`` imports every log format it has: with ``hydrostand[mf4]`` installed, ``.mf4``'s
asammdf and pandas too, 0.45 s before the first frame of a candump log is read. The stand's DBC
does not change between runs, so its codecs (what :meth:`MessageCodec.from_cantools` derives from
cantools' parse, :mod:`captures.codecs`) are kept in ``dbc/stand.codecs.json`` with the SHA-256 of
the DBC they came from:

* :func:`precompiled_codecs` gives them for a DBC whose bytes are exactly those (the default
  ``dbc/stand.dbc``, or a copy of it); any other DBC, an edited ``stand.dbc`` among them, gives
  None and is read with cantools, so a stale table is never used;
* ``python -m captures.dbctable`` writes the table again after ``stand.dbc`` was edited;
  ``tests/test_captures_imports.py`` fails while it is not what cantools gives.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
from pathlib import Path
from typing import Any, Sequence

from dbc import STAND_CODECS, STAND_DBC

from .codecs import MessageCodec
from .frames import CaptureError

FORMAT = 1          #: of the table file; a table of another format is not used

log = logging.getLogger(__name__)

DEFAULT_DBC = STAND_DBC


def load_dbc(dbc: str | os.PathLike | Any = None):
    """A cantools database (default: the stand's ``dbc/stand.dbc``); a database is returned as is.

    cantools is imported here, not with this module: ``import cantools`` imports python-can
    (``cantools.tester``), and with it every python-can log format (``.mf4``'s asammdf and
    pandas among them)."""
    if dbc is None:
        dbc = DEFAULT_DBC
    if not isinstance(dbc, (str, os.PathLike)):
        if hasattr(dbc, "messages"):
            return dbc
        raise CaptureError(f"a DBC is a file path or a cantools database, not {type(dbc).__name__}")
    import cantools
    try:
        return cantools.database.load_file(str(dbc))
    except FileNotFoundError:
        raise CaptureError(f"DBC file {dbc} does not exist") from None
    except Exception as exc:  # cantools raises many parser-specific errors
        raise CaptureError(f"cannot read DBC file {dbc}: {exc}") from None


def compile_table(dbc: str | os.PathLike) -> dict[str, Any]:
    """The codec table of a DBC file, read with cantools (every message must be vectorizable)."""
    from importlib.metadata import version

    path = Path(dbc)
    db = load_dbc(path)
    return {"format": FORMAT, "dbc": path.name, "dbc_sha256": _sha256(path.read_bytes()),
            "cantools": version("cantools"),
            "messages": [MessageCodec.from_cantools(m).as_dict() for m in db.messages]}


def precompiled_codecs(dbc: Any = None, table: str | os.PathLike = STAND_CODECS) -> list[MessageCodec] | None:
    """The codecs of ``dbc`` (a path; None: the stand's DBC) from ``table``, or None when the
    table is not of this DBC's bytes (or ``dbc`` is not a path, or a file is missing)."""
    if dbc is None:
        dbc = STAND_DBC
    if not isinstance(dbc, (str, os.PathLike)):
        return None
    try:
        source = Path(dbc).read_bytes()
        text = Path(table).read_text()
    except OSError:
        return None
    try:
        content = json.loads(text)
        if content.get("format") != FORMAT or content.get("dbc_sha256") != _sha256(source):
            return None
        return [MessageCodec.from_dict(m) for m in content["messages"]]
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        log.warning("%s is damaged (%s: %s); reading the DBC with cantools instead. "
                    "Write it again: python -m captures.dbctable", table, type(exc).__name__, exc)
        return None


def write_table(dbc: str | os.PathLike = STAND_DBC, out: str | os.PathLike = STAND_CODECS) -> Path:
    """Compile ``dbc`` and write its table to ``out`` (replaced whole, never half-written)."""
    out = Path(out)
    tmp = out.with_name(f".{out.name}.{os.getpid()}")
    tmp.write_text(json.dumps(compile_table(dbc), indent=1) + "\n")
    os.replace(tmp, out)
    return out


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m captures.dbctable",
                                 description="Write the precompiled codec table of the stand's DBC.")
    ap.add_argument("--dbc", default=str(STAND_DBC), help="DBC to compile (default: %(default)s)")
    ap.add_argument("-o", "--out", default=str(STAND_CODECS), help="table to write (default: %(default)s)")
    args = ap.parse_args(argv)
    try:
        print(f"-> {write_table(args.dbc, args.out)}")
    except CaptureError as exc:
        ap.exit(2, f"{ap.prog}: error: {exc}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
