"""The DBC decoder equals cantools bit for bit; the cycle assembler turns stand traffic into the
gateway's rows exactly (known answers from the plant model), also when frames are lost,
duplicated, stored out of order, of the wrong length or unknown."""
from __future__ import annotations

import cantools
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from captures import CycleAssembler, FrameChunk, FrameDecoder
from captures.cycles import resolve_offsets
from captures.frames import EXTENDED
from captures.synthetic import FORCE_SCALE, stand_frames, synthetic_run

MIXED_DBC = '''VERSION ""
NS_ :
BS_:
BU_: A
BO_ 291 Mixed: 8 A
 SG_ be_signed : 7|12@0- (0.5,-3) [0|0] "" A
 SG_ le_unsigned : 16|16@1+ (1,0) [0|0] "" A
 SG_ be_u16 : 39|16@0+ (0.25,10) [0|0] "" A
 SG_ tail : 56|8@1- (1,0) [0|0] "" A
BO_ 2147484000 ExtFloat: 8 A
 SG_ f32 : 0|32@1- (1,0) [0|0] "" A
 SG_ f32b : 32|32@1- (2,1) [0|0] "" A
BO_ 300 Muxed: 8 A
 SG_ mux M : 0|8@1+ (1,0) [0|0] "" A
 SG_ a m0 : 8|16@1+ (1,0) [0|0] "" A
 SG_ b m1 : 8|32@1- (0.1,0) [0|0] "" A
 SG_ c : 40|16@0- (1,0) [0|0] "" A
BO_ 301 Wide: 8 A
 SG_ whole : 0|64@1+ (1,0) [0|0] "" A
SIG_VALTYPE_ 2147484000 f32 : 1;
SIG_VALTYPE_ 2147484000 f32b : 1;
'''


@pytest.fixture(scope="module")
def mixed_dbc(tmp_path_factory):
    path = tmp_path_factory.mktemp("dbc") / "mixed.dbc"
    path.write_text(MIXED_DBC)
    return path


def chunk_of(frames: list[tuple[int, bool, bytes]]) -> FrameChunk:
    n = len(frames)
    data = np.zeros((n, 8), np.uint8)
    for i, (_, _, payload) in enumerate(frames):
        data[i, :len(payload)] = np.frombuffer(payload, np.uint8)
    return FrameChunk(np.arange(n) * 0.001, np.array([f[0] for f in frames], np.uint32),
                      np.array([EXTENDED if f[1] else 0 for f in frames], np.uint8),
                      np.array([len(f[2]) for f in frames], np.uint8), data, np.zeros(n, np.int16), ["can0"])


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([(291, False), (0x160, True), (300, False), (301, False)]),
                          st.binary(min_size=8, max_size=8)), min_size=1, max_size=60))
def test_vectorized_decoding_equals_cantools_for_any_dbc_layout(mixed_dbc, frames):
    """Big- and little-endian, signed, scaled, float, multiplexed, 64-bit and extended ids."""
    db = cantools.database.load_file(str(mixed_dbc))
    chunk = chunk_of([(fid, ext, data) for (fid, ext), data in frames])
    decoded = FrameDecoder(db).decode(chunk)
    for name, dm in decoded.items():
        msg = db.get_message_by_name(name)
        for j, row in enumerate(dm.index):
            try:
                ref = msg.decode(chunk.payload(row), decode_choices=False)
            except cantools.database.DecodeError:       # a multiplexer value the DBC does not list
                ref = {s.name: dm.phys[s.name][j] for s in msg.signals if s.multiplexer_ids is None}
            for sig in msg.signals:
                ours = dm.phys[sig.name][j]
                if sig.name in ref:
                    assert ours == ref[sig.name] or (np.isnan(ours) and np.isnan(ref[sig.name])), (name, sig.name)
                else:
                    assert np.isnan(ours), (name, sig.name)    # other multiplexer group


def test_stand_dbc_decoding_equals_cantools_on_stand_traffic():
    chunk = FrameChunk.concat(list(stand_frames(synthetic_run(400))))
    db = cantools.database.load_file("dbc/stand.dbc")
    decoded = FrameDecoder(db).decode(chunk)
    compared = 0
    for name, dm in decoded.items():
        for j, row in enumerate(dm.index):
            ref = db.decode_message(int(chunk.can_id[row]), chunk.payload(row), decode_choices=False)
            assert {k: dm.phys[k][j] for k in ref} == ref
            compared += 1
    assert compared == len(chunk)


# -- the cycle assembler -------------------------------------------------------------------------

def assemble(chunk: FrameChunk, piece: int = 5000, **kw):
    dec = FrameDecoder()
    asm = CycleAssembler(dec, **kw)
    pieces = []
    for i in range(0, len(chunk), piece):
        c = chunk.take(slice(i, i + piece))
        asm.feed(c, dec.decode(c, asm.wanted))
        pieces += asm.take_rows()
    pieces += asm.finish()
    runs = {}
    for run, rows in pieces:
        runs.setdefault(run, []).append(rows)
    rows = {r: {k: np.concatenate([p[k] for p in parts]) for k in parts[0]} for r, parts in runs.items()}
    return rows, asm.runs, dec.stats


def traffic(cycles=3000, lockstep=False, seed=1, **kw):
    run = synthetic_run(cycles, seed=seed, **kw)
    return run, FrameChunk.concat(list(stand_frames(run, lockstep=lockstep)))


def assert_rows_equal_truth(rows, run, skip=()):
    keep = np.setdiff1d(np.arange(run.cycles), skip)
    assert len(rows["t"]) == run.cycles
    assert np.array_equal(rows["u"], run.u)
    assert np.array_equal(rows["y_counts"][keep], run.y_counts[:-1][keep])
    assert np.array_equal(rows["y"][keep], run.y[keep])
    assert np.array_equal(rows["cycle"], np.arange(run.cycles))
    assert np.all(np.isnan(rows["r"]))


@pytest.mark.parametrize("lockstep", [False, True])
@pytest.mark.parametrize("piece", [997, 100_000])
def test_rows_equal_the_simulated_run_bit_for_bit(lockstep, piece):
    run, chunk = traffic(3000, lockstep=lockstep)
    rows, runs, stats = assemble(chunk, piece)
    rows = rows[0]
    assert_rows_equal_truth(rows, run)
    assert np.array_equal(rows["t"], np.arange(run.cycles) * 0.002), "t = k × period exactly"
    assert np.array_equal(rows["y"], run.y_counts[:-1] * FORCE_SCALE)
    assert np.array_equal(rows["spool"], run.spool_counts[:-1] * (100 / 16384))
    assert not rows["stale"].any()
    info = runs[0]
    assert info.clock == ("lockstep" if lockstep else "realtime")
    assert info.period_s == 0.002 and info.period_source == "SDO 0x1006"
    assert info.syncs == run.cycles + 1 and info.syncs_without_row == 1, "the last SYNC ends the run"
    assert stats.unknown == 0 and not stats.wrong_dlc


def _index(chunk: FrameChunk, cob: int, k: int) -> int:
    """Position of the k-th frame with id ``cob``."""
    return int(np.flatnonzero(chunk.can_id == cob)[k])


def test_unknown_ids_are_skipped_and_counted_and_wrong_dlc_is_not_decoded():
    run, chunk = traffic(2000)
    # noise: an unknown standard id and an unknown extended id after every 100th SYNC
    syncs = np.flatnonzero(chunk.can_id == 0x080)[::100]
    noise = FrameChunk(chunk.ts[syncs], np.r_[np.full(len(syncs) - 10, 0x123), np.full(10, 0x18DAF110)].astype(np.uint32),
                       np.r_[np.zeros(len(syncs) - 10), np.full(10, EXTENDED)].astype(np.uint8),
                       np.full(len(syncs), 8, np.uint8), np.full((len(syncs), 8), 0xEE, np.uint8),
                       np.zeros(len(syncs), np.int16), ["can0"])
    merged = FrameChunk.concat([chunk, noise])
    order = np.argsort(np.r_[np.arange(len(chunk)), syncs + 0.5], kind="stable")
    merged = merged.take(order)
    # the force TPDO of cycle 700 has 4 bytes instead of 5
    bad = _index(merged, 0x182, 700)
    merged.dlc[bad] = 4
    rows, runs, stats = assemble(merged, 3001)
    rows = rows[0]
    assert stats.unknown == len(syncs) and stats.unknown_ids == {"0x123": len(syncs) - 10, "0x18DAF110": 10}
    assert stats.wrong_dlc == {"TPDO1_Dynamometer": 1}
    assert_rows_equal_truth(rows, run, skip=[700])
    assert rows["stale"][700] and rows["stale"].sum() == 1
    assert rows["y_counts"][700] == rows["y_counts"][699], "a stale cycle holds the last reading"
    assert runs[0].syncs_without_force == 1


@pytest.mark.parametrize("lockstep", [False, True])
def test_tpdos_stored_after_the_next_frames_still_pair_with_their_sync(lockstep):
    """The gateway's own capture is written by two threads: a received TPDO can land in the
    file after the RPDO and even the next SYNC the gateway sent."""
    run, chunk = traffic(2000, lockstep=lockstep)
    order = list(range(len(chunk)))
    for k in (10, 11, 500, 501, 502, 1400):
        f = _index(chunk, 0x182, k)
        v = _index(chunk, 0x181, k)
        s_next = _index(chunk, 0x080, k + 1)
        for i in (v, f):
            order.remove(i)
        at = order.index(s_next) + 1
        order[at:at] = [v, f]
    rows, runs, stats = assemble(chunk.take(np.array(order)), 1234)
    rows = rows[0]
    assert_rows_equal_truth(rows, run)
    assert not rows["stale"].any() and runs[0].tpdo_resyncs == 0
    assert stats.out_of_order == 6, "timestamps that went backwards are reported"


def test_a_lost_or_duplicated_tpdo_shifts_nothing_else():
    run, chunk = traffic(2000)
    lost = _index(chunk, 0x182, 333)
    dup = _index(chunk, 0x182, 1200)
    order = np.r_[np.arange(lost), np.arange(lost + 1, dup + 1), dup, np.arange(dup + 1, len(chunk))]
    rows, runs, _ = assemble(chunk.take(order), 800)
    rows = rows[0]
    assert_rows_equal_truth(rows, run, skip=[333])
    assert rows["stale"][333] and rows["stale"].sum() == 1
    assert runs[0].tpdo_resyncs == 2 and runs[0].tpdos_unpaired == 1


def test_real_time_stale_cycle_when_the_tpdo_came_after_the_command():
    run, chunk = traffic(1000)
    f = _index(chunk, 0x182, 400)
    r = _index(chunk, 0x201, 400 + 1)     # +1: the enabling RPDO before the first SYNC
    assert chunk.ts[r] > chunk.ts[f]
    chunk.ts[f] = chunk.ts[r] + 50e-6       # answered after the gateway had sent its command
    order = np.r_[np.arange(f), np.arange(f + 1, r + 1), f, np.arange(r + 1, len(chunk))]
    rows, _, stats = assemble(chunk.take(order))
    rows = rows[0]
    assert rows["stale"].sum() == 1 and rows["stale"][400]
    assert rows["y_counts"][400] == run.y_counts[399]
    assert_rows_equal_truth(rows, run, skip=[400])


def test_real_time_overrun_leaves_the_same_gap_as_the_gateway_record():
    run, chunk = traffic(1000)
    # the gateway missed two slots after cycle 600: every frame from SYNC 601 on is 4 ms later
    s = _index(chunk, 0x080, 601)
    chunk.ts[s:] += 0.004 + 0.0007            # and 0.7 ms late in its slot
    rows, runs, _ = assemble(chunk)
    t = rows[0]["t"]
    assert np.array_equal(t[:601], np.arange(601) * 0.002)
    assert np.array_equal(t[601:], np.arange(603, 1002) * 0.002)
    assert runs[0].grid_skips == 2


def test_period_from_argument_or_median_sync_interval_without_sdo():
    run, chunk = traffic(800)
    no_sdo = chunk.take(~np.isin(chunk.can_id, [0x601, 0x602]))
    rows, runs, _ = assemble(no_sdo)
    assert runs[0].period_source == "median SYNC interval"
    assert runs[0].period_s == 0.002, "rounded to the µs, as 0x1006 counts it"
    assert np.array_equal(rows[0]["t"], np.arange(800) * 0.002)
    rows, runs, _ = assemble(no_sdo, period_s=0.002)
    assert runs[0].period_source == "argument" and np.array_equal(rows[0]["t"], np.arange(800) * 0.002)


def test_several_runs_in_one_capture_are_told_apart():
    run_a, a = traffic(500, seed=1)
    run_b, b = traffic(700, seed=2, amplitude_pct=8)
    b.ts = b.ts + (a.ts[-1] - b.ts[0]) + 5.0
    rows, runs, _ = assemble(FrameChunk.concat([a, b]), 777)
    assert [r.rows for r in runs] == [500, 700]
    assert_rows_equal_truth(rows[0], run_a)
    assert_rows_equal_truth(rows[1], run_b)
    assert rows[1]["t"][0] == 0.0


def test_resolve_offsets_keeps_the_count_through_short_excursions():
    e = np.zeros(40, np.int64)
    e[5] = 1                                  # stored one SYNC late
    e[20:] = 1                                # a TPDO lost before #20
    off, last, unstable = resolve_offsets(e, 0, final=True, k=8)
    assert off[5] == 0 and np.all(off[:20] == 0) and np.all(off[20:] == 1) and last == 1
    off, last, unstable = resolve_offsets(e[:24], 0, final=False, k=8)
    assert unstable == 20, "four TPDOs off the count are not yet evidence of a loss"


def test_sync_without_counter_and_a_second_channel():
    """CiA 301 allows a SYNC without its counter (DLC 0); frames of another bus in the same
    file are left out with ``channel``."""
    run, chunk = traffic(600)
    syncs = chunk.can_id == 0x080
    chunk.dlc[syncs] = 0
    chunk.data[syncs] = 0
    other = chunk.take(slice(None))
    other.channel = np.ones(len(other), np.int16)
    other.channels = ["can0", "can1"]
    other.data = other.data.copy()
    other.data[other.can_id == 0x182] = 0xAA
    both = FrameChunk.concat([chunk, other]).take(np.argsort(np.r_[np.arange(len(chunk)), np.arange(len(other)) + 0.5], kind="stable"))
    dec = FrameDecoder(channel="can0")
    asm = CycleAssembler(dec)
    asm.feed(both, dec.decode(both, asm.wanted))
    parts = asm.take_rows() + asm.finish()
    rows = {k: np.concatenate([p[1][k] for p in parts]) for k in parts[0][1]}
    assert_rows_equal_truth(rows, run)
    assert dec.stats.other_channel == len(other)
    assert dec.stats.wrong_dlc == {}, "a SYNC of DLC 0 is a valid SYNC, not the wrong length"


def test_both_forms_of_the_sync_decode_silently_the_counter_is_0_without_one():
    run, chunk = traffic(400)
    syncs = np.flatnonzero(chunk.can_id == 0x080)
    plain = syncs[::2]                       # every other SYNC without its counter
    chunk.dlc[plain] = 0
    chunk.data[plain] = 0
    dec = FrameDecoder()
    decoded = dec.decode(chunk)["SYNC"]
    counter = decoded.phys["SYNC_Counter"]
    assert len(counter) == len(syncs) and dec.stats.wrong_dlc == {}
    with_counter = np.isin(decoded.index, syncs[1::2])
    assert (counter[~with_counter] == 0).all() and (counter[with_counter] >= 1).all()
    rows, _, _ = assemble(chunk, 3001)
    assert_rows_equal_truth(rows[0], run)
