"""A one-channel stand loads as it always did: the commands of recorded passes, cycle by cycle,
bit for bit (tests/support/golden_passes.py recorded them before the stand became a station of
one channel): offline against the emulator's lockstep plant in ten scenarios (compensation,
pacing, the gain monitor following, P control, a valve lag in the model), and through the
gateway on the emulator process (``stand load --repeat 2`` and ``--fastest``)."""
from __future__ import annotations

import numpy as np
import pytest

from tests.support import golden_passes as golden


def test_offline_passes_send_the_recorded_commands():
    recorded = np.load(golden.DATA)
    now = golden.record()
    assert sorted(now) == sorted(recorded.files)
    for key in recorded.files:
        a, b = now[key], recorded[key]
        assert a.shape == b.shape, f"{key}: {a.shape} cycles, recorded {b.shape}"
        differ = np.flatnonzero(~((a == b) | (np.isnan(a) & np.isnan(b))))
        assert not len(differ), f"{key}: {len(differ)} cycles differ, first at cycle {differ[0]}: " \
                                f"{a[differ[0]]!r} against {b[differ[0]]!r}"


@pytest.mark.e2e
def test_stand_load_through_the_gateway_sends_the_recorded_commands(start_emulator, bus_spec, tmp_path):
    start_emulator(None, lockstep=True, seed=golden.GATEWAY_SEED)
    try:
        now = golden.gateway_record(bus_spec, tmp_path)
    except RuntimeError as exc:           # a stale cycle on a starved host: not comparable
        pytest.skip(str(exc))
    recorded = np.load(golden.GATEWAY_DATA)
    assert sorted(now) == sorted(recorded.files)
    for key in recorded.files:
        assert np.array_equal(now[key], recorded[key]), key
