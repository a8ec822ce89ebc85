"""Captured bus traffic: read any capture fast, decode it with the DBC into the gateway's run
format, and put it back on a bus (as it was, or as the stand's two nodes).

* :func:`capture_run` — one run of a capture as its signals (every analysis command accepts
  capture files through :func:`analysis.load`, which makes a record of them);
* :func:`decode_capture` — capture → run directory (``run.json`` + ``signals.parquet``), streamed
  with bounded memory, optionally partitioned, optionally every message as its own dataset;
* :func:`decode_frames` / :class:`FrameDecoder` — the vectorized DBC decoder on its own;
* :func:`open_capture` — the reader for a file (candump ``.log`` and ``.blf`` vectorized, other
  python-can formats through python-can), yielding :class:`FrameChunk` s;
* :mod:`captures.replay` — ``stand replay``: onto any bus with the original timing, or as the
  plant (:class:`plant_emulator.replayed.ReplayedStand`, fed by :func:`captures.trace.force_trace`).

See ``docs/captures.md``.
"""
from __future__ import annotations

from core.lazy import lazy_exports

# imported on first use (core.lazy): `import captures.x` and `stand --help` stay light
_EXPORTS = {
    "CycleAssembler": ".cycles",
    "RunInfo": ".cycles",
    "StandSignals": ".cycles",
    "DecodedMessage": ".dbcdecode",
    "DecodeStats": ".dbcdecode",
    "FrameDecoder": ".dbcdecode",
    "load_dbc": ".dbctable",
    "DecodeOptions": ".decode",
    "DecodeResult": ".decode",
    "decode_capture": ".decode",
    "decode_frames": ".decode",
    "iter_frames": ".decode",
    "capture_run": ".decode",
    "CaptureDamaged": ".frames",
    "CaptureError": ".frames",
    "Damage": ".frames",
    "FrameChunk": ".frames",
    "ReadStats": ".frames",
    "SUFFIXES": ".formats",
    "capture_format": ".readers",
    "open_capture": ".readers",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
