"""Captured bus traffic: read any capture fast, decode it with the DBC into the gateway's run
format, and put it back on a bus (as it was, or as the stand's two nodes).

* :func:`load_capture` — a capture as an :class:`analysis.data.Record` (every analysis command
  accepts capture files through :func:`analysis.data.load`);
* :func:`decode_capture` — capture → run directory (``run.json`` + ``signals.parquet``), streamed
  with bounded memory, optionally partitioned, optionally every message as its own dataset;
* :func:`decode_frames` / :class:`FrameDecoder` — the vectorized DBC decoder on its own;
* :func:`open_capture` — the reader for a file (candump ``.log`` and ``.blf`` vectorized, other
  python-can formats through python-can), yielding :class:`FrameChunk` s;
* :mod:`captures.replay` — ``stand replay``: onto any bus with the original timing, or as the
  plant (:class:`captures.plant.ReplayedStand`).

See ``docs/captures.md``.
"""
from .cycles import CycleAssembler, RunInfo, StandSignals
from .dbcdecode import DecodedMessage, DecodeStats, FrameDecoder, load_dbc
from .decode import (DecodeOptions, DecodeResult, decode_capture, decode_frames, iter_frames,
                     load_capture)
from .frames import CaptureDamaged, CaptureError, Damage, FrameChunk, ReadStats
from .readers import SUFFIXES, capture_format, open_capture

__all__ = [
    "CaptureDamaged", "CaptureError", "CycleAssembler", "Damage", "DecodeOptions", "DecodeResult",
    "DecodeStats", "DecodedMessage", "FrameChunk", "FrameDecoder", "ReadStats", "RunInfo",
    "StandSignals", "SUFFIXES", "capture_format", "decode_capture", "decode_frames", "iter_frames",
    "load_capture", "load_dbc", "open_capture",
]
