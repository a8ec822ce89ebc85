"""The CAN bus budget: worst-case frame times (classic and FD) and a rig's load per bus."""
from __future__ import annotations

import pytest

from rig.budget import bus_budgets
from rig.config import rig_from_mapping
from standbus.budget import classic_frame_bits, fd_frame_time_s, fd_padded


def test_classic_frames_take_their_worst_case_bits_with_stuffing():
    # 47 + 8n bits with the interframe space, and at most one stuff bit per 4 of SOF..CRC
    assert [classic_frame_bits(n) for n in (0, 1, 4, 5, 8)] == [55, 65, 95, 105, 135]
    with pytest.raises(ValueError):
        classic_frame_bits(9)


def test_a_can_fd_frame_spends_its_data_phase_at_the_data_rate():
    slow = fd_frame_time_s(8, 1_000_000)
    fast = fd_frame_time_s(8, 1_000_000, 5_000_000)
    assert 34e-6 < fast < slow / 2                       # the 34 nominal bits stay
    assert fd_padded(9) == 12 and fd_padded(64) == 64    # DLC steps above 8 bytes
    assert fd_frame_time_s(12, 1_000_000) > fd_frame_time_s(8, 1_000_000)


def rig(channels: int, **bus) -> dict:
    return {"bus": [{"name": "can0", "spec": "udp_loopback:x", **bus}],
            "channel": [{"name": f"c{i}", "bus": "can0", "valve_id": 2 * i + 1,
                         "dynamometer_id": 2 * i + 2} for i in range(channels)]}


def test_six_channels_at_500_hz_do_not_fit_one_classic_bus_and_it_says_what_would():
    (b,) = bus_budgets(rig_from_mapping(rig(6)))
    assert not b.fits and round(b.load.load_pct) == 93
    # SYNC 65 bits + 6 x (95 + 95 + 105) per 2 ms, 12 heartbeats of 65 bits per 100 ms
    assert b.load.bits_per_s == pytest.approx((65 + 6 * 295) / 0.002 + 12 * 65 / 0.1)
    assert b.max_channels == 4 and 2.5e-3 < b.min_period_s < 3e-3
    assert ("bus can0: 6 channel(s) at 500 Hz need 0.93 Mbit/s of 1.00 Mbit/s (classic CAN, "
            "93 %, the limit is 70 %); at most 4 channel(s) per bus at 500 Hz, or a period of "
            "2.7 ms") == b.problem()


def test_can_fd_carries_more_channels_and_the_limit_is_the_rigs():
    (fd,) = bus_budgets(rig_from_mapping(rig(6, fd=True, data_bitrate=5_000_000)))
    assert fd.fits and fd.max_channels > 6
    relaxed = rig_from_mapping({**rig(6), "bus_load_limit_pct": 95})
    assert bus_budgets(relaxed)[0].fits
