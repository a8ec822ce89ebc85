"""A rig's dynamometers read together (lockstep) give what each gives read on its own."""
import numpy as np
import pytest

from plant.sensor import Dynamometer, SensorBank

#: noise, resolution, range: the usual, noise-free, unrounded with a small range, a fine step
KINDS = [(2.0, 0.5, 1e4), (0.0, 0.5, 1e4), (3.0, 0.0, 50.0), (1.0, 0.1, 1e4)]


def sensors(kinds):
    return [Dynamometer(noise_kgf=n, resolution_kgf=r, range_kgf=rg, seed=i)
            for i, (n, r, rg) in enumerate(kinds)]


@pytest.mark.parametrize("kinds", [KINDS * 4, [KINDS[0]] * 16, [KINDS[1]] * 3],
                         ids=["mixed", "all-alike", "noise-free"])
@pytest.mark.parametrize("block", [7, 1024])
def test_a_bank_reads_bit_for_bit_what_each_sensor_reads_alone(kinds, block):
    alone, together = sensors(kinds), SensorBank(sensors(kinds), block=block)
    rng = np.random.default_rng(0)
    for k in range(300):        # across several of the bank's noise blocks
        forces = rng.normal(0.0, 80.0, len(kinds))
        if k % 5 == 0:          # beyond the range, and not a number at all
            forces[k % len(kinds)] = [np.nan, np.inf, -np.inf, 1e5][k % 4]
        one = [s.read(f) for s, f in zip(alone, forces)]
        readings, over = together.read(forces.tolist())
        np.testing.assert_array_equal(readings, [r for r, _ in one])   # NaN where NaN
        assert over.tolist() == [o for _, o in one]
