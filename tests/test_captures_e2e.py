"""Round trip with the real emulator process and the gateway: a run's capture decodes to the
signals the gateway recorded — bit for bit in lockstep; in real time too (t is k × period on
both sides), except cycles the gateway itself recorded as stale (their exact deadline is not on
the bus). On a starved host, what the bus cannot tell (the slot of a SYNC sent most of a period
late, the SYNC a late answer answers) is bounded instead of equal."""
from __future__ import annotations

import numpy as np
import pytest

from analysis import load
from captures import decode_capture
from captures.cycles import RESYNC_AFTER
from gateway import Gateway, GatewayConfig, load_run
from gateway.experiments import Meander
from tests.support.stand import BASE, plant

pytestmark = pytest.mark.e2e
EXACT = ("u", "y", "cycle", "y_counts", "spool", "valve_status", "stale")


def _run(bus_spec, out, lockstep):
    with Gateway(GatewayConfig(bus=bus_spec, lockstep=lockstep)) as gw:
        return gw.run(Meander(amplitude_pct=5, period_s=1, cycles=2), out, progress=False)


def test_lockstep_capture_decodes_bit_for_bit_to_the_recorded_run(bus_spec, start_emulator, tmp_path):
    start_emulator(plant(BASE), lockstep=True, seed=3)
    result = _run(bus_spec, tmp_path / "run", lockstep=True)
    assert result.status == "complete", result.outcome.message
    recorded = load_run(result.path)
    decoded = decode_capture(result.path / "capture.log")
    rows = decoded.signals[0]
    info = decoded.runs[0]
    assert info.clock == "lockstep" and info.period_source == "SDO 0x1006" and info.period_s == 0.002
    assert info.clock_source == "SDO 0x2100", "the gateway declares the clock in the capture"
    assert len(rows["t"]) == len(recorded) >= 1000
    for name in ("t",) + EXACT:
        assert np.array_equal(rows[name], recorded.signals[name]), name
    assert np.all(np.isnan(rows["r"])), "the reference is not on the bus"
    assert np.allclose(rows["sync_time"], recorded.sync_time, atol=0.05)
    assert decoded.frames.unknown == 0 and not decoded.frames.wrong_dlc
    # and the analysis gets the same record from the capture as from the run
    a, b = load(result.path / "capture.log"), load(result.path)
    assert np.array_equal(a.y, b.y) and np.array_equal(a.u, b.u) and np.array_equal(a.t, b.t)


@pytest.mark.slow
@pytest.mark.serial
def test_realtime_capture_decodes_to_the_recorded_run(bus_spec, start_emulator, tmp_path):
    start_emulator(plant(BASE, model="base"), lockstep=False, seed=5)
    result = _run(bus_spec, tmp_path / "rt", lockstep=False)
    recorded = load_run(result.path)
    decoded = decode_capture(result.path / "capture.log")
    rows = decoded.signals[0]
    assert decoded.runs[0].clock == "realtime" and decoded.runs[0].period_s == 0.002
    assert decoded.runs[0].clock_source == "SDO 0x2100"
    # every cycle the gateway recorded, with the command it sent (also the trip cycle of a run
    # the supervisor stopped on a loaded host)
    assert len(rows["t"]) == len(recorded) > 0
    assert np.array_equal(rows["u"], recorded.u) and np.array_equal(rows["cycle"], recorded.cycle)
    stats = recorded.meta["stats"]
    clean = (result.status == "complete" and stats["stale_cycles"] == 0 and stats["overruns"] == 0
             and stats["sync_jitter_ms"]["max"] < 1.0)
    same_t = rows["t"] == recorded.t                   # the same slot of the 2 ms grid
    if clean:
        assert np.array_equal(rows["t"], recorded.t), "t is k × period on both sides"
        for name in EXACT:
            assert np.array_equal(rows[name], recorded.signals[name]), name
    else:
        # a starved host. The bus does not say which slot a SYNC sent late was meant for (the
        # gateway skips the slots it overran; the SYNC counter counts SYNCs sent): the decoder
        # puts the slot boundary into the widest phase gap of the SYNCs' stamps (grid_bias b), so
        # only a SYNC that went out at least (1 - b) of a period late, by the gateway's stamp or
        # the capture's (give or take 0.05 of a period between them), may land in another slot
        T, b = 0.002, decoded.runs[0].grid_bias
        late = np.maximum(_lateness(recorded.sync_time, recorded.t), _lateness(rows["sync_time"], recorded.t))
        misplaced = ~same_t
        assert np.all(late[misplaced] >= (0.95 - b) * T), (result.status, stats, b, late[misplaced] / T)
        # ... and which SYNC an answer that came late answers, the gateway (by arrival, late ones
        # dropped) and the decoder (by count) may tell apart: every fresh decoded force lies
        # within the readings the gateway recorded around it (re-sync reach, one step of slack);
        # where the gateway itself got no fresh reading within that reach (a stall longer than
        # it), it recorded nothing a late answer could be compared with
        reach = RESYNC_AFTER + 1
        window = lambda a, fill: np.lib.stride_tricks.sliding_window_view(  # noqa: E731
            np.pad(a, reach, **fill), 2 * reach + 1)
        near = window(recorded.y_counts, {"mode": "edge"})
        known = window(~recorded.signals["stale"].astype(bool), {"constant_values": False}).any(axis=1)
        step = np.abs(np.diff(recorded.y_counts)).max()
        y = rows["y_counts"]
        inside = (y >= near.min(axis=1) - step) & (y <= near.max(axis=1) + step)
        judged = ~rows["stale"] & known
        assert inside[judged].all(), (result.status, stats, np.flatnonzero(judged & ~inside)[:20])


def _lateness(stamps, t):
    """How late each SYNC went out after its slot, s (SYNCs are never early: the least is 0)."""
    d = (np.asarray(stamps) - stamps[0]) - (np.asarray(t) - t[0])
    return d - d.min()
