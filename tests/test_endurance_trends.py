"""End-point trends (endurance.trends): the CUSUM's run lengths, a flight's end points and flows,
the detector on flights whose truth is known (no alarm intact, a change at one channel named,
every valve's flow moving together ignored), its journal (a resumed test goes on with the same
statistic, bit for bit), its refusals; and on offline passes of the example rig whose structure
softens at one attachment mid-test (the plant's schedule)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from core.errors import ParameterError
from endurance.trends import (TrendAlarm, TrendDetector, TrendOptions, cusum_arl, cusum_threshold,
                              load_case_statistics)

NAMES = ["root", "inner", "outer", "tip"]
G = np.array([[120, 30, 0, 0], [36, 100, 42, 0], [0, 30, 140, 33], [0, 0, 42, 110]], float)


# -- the run length ------------------------------------------------------------------------------
@pytest.mark.parametrize("k, h, mu, arl", [
    (0.5, 4.0, 0.0, 336.0), (0.5, 5.0, 0.0, 930.0), (0.5, 4.0, 1.0, 8.38), (0.5, 5.0, 1.0, 10.4)])
def test_the_run_length_of_a_cusum_is_the_textbook_one(k, h, mu, arl):
    """Page's CUSUM of N(μ, 1) with reference k and threshold h (Montgomery, Introduction to
    Statistical Quality Control, table 9.3: h = 4 and 5 with k = 0.5: 336 and 930 in control,
    8.38 and 10.4 at a 1σ shift)."""
    assert cusum_arl(h, [mu - k], [1.0]) == pytest.approx(arl, rel=0.01)


def test_a_mixture_of_flight_types_runs_as_long_as_its_simulation():
    means, stds, weights = [-2.0, -0.5], [2.0, 1.0], [0.3, 0.7]
    h = 3.0
    arl = cusum_arl(h, means, stds, weights)
    rng = np.random.default_rng(1)
    n = 4000
    S = np.zeros(n)
    alive = np.ones(n, bool)
    length = np.zeros(n)
    t = 0
    while alive.any():
        t += 1
        pick = rng.random(n) < weights[0]
        lam = np.where(pick, rng.normal(means[0], stds[0], n), rng.normal(means[1], stds[1], n))
        S = np.where(alive, np.maximum(0.0, S + lam), S)
        hit = alive & (S > h)
        length[hit] = t
        alive &= ~hit
    assert length.mean() == pytest.approx(arl, rel=0.06), (length.mean(), arl)
    # the threshold for a run length is the smallest that reaches it
    h = cusum_threshold(2000.0, means, stds, weights)
    assert cusum_arl(h, means, stds, weights) >= 2000.0 > cusum_arl(0.99 * h, means, stds, weights)
    assert cusum_threshold(10.0, [-50.0], [10.0]) == 0.0      # one flight's evidence is enough


# -- a flight's statistics -------------------------------------------------------------------------
def test_a_flights_end_points_and_flows_are_read_per_load_case_with_each_channels_delay():
    T = 0.002
    K = 100
    y = np.vstack([np.arange(K, dtype=float), 1000 + 2 * np.arange(K, dtype=float)])
    u = np.vstack([np.ones(K), np.where(np.arange(K) < 50, 2.0, -1.0)])
    p = 0.5 * u
    E, F, P = load_case_statistics(y, u, p, [20, 60, 90], [0, 10], T, window=2)
    assert E.tolist() == [[20.0, 60.0, 90.0], [1040.0, 1120.0, 1180.0]]   # means of ±2 cycles
    # channel 1's commands [0, 20) [20, 60) [60, 90); channel 2's 10 cycles earlier, [0, 10) [10, 50) [50, 80)
    assert F[0] == pytest.approx(T * np.array([20, 40, 30]))
    assert F[1] == pytest.approx(T * np.array([2 * 10, 2 * 40, -30]))
    assert P == pytest.approx(0.5 * F)


# -- the detector on flights whose truth is known --------------------------------------------------
class Flights:
    """Flights of two types on a rig with G: the flows the end points need through G⁻¹ plus a
    planned share, every valve's flow gain wandering together (``common_pct``, an AR(1)) and
    each its own (``valve_pct``), 1 kgf of noise on the end points; ``crack(i, f, from)``: from
    that flight channel i needs (1/f − 1) more of its own share of each step."""

    def __init__(self, seed: int, common_pct: float = 0.5, valve_pct: float = 0.2) -> None:
        rng = np.random.default_rng(100)
        self.levels = {t: np.cumsum(rng.uniform(-800, 800, (4, m)), axis=1) + 3000
                       for t, m in (("A", 8), ("B", 12))}
        self.rng = np.random.default_rng(seed)
        self.common_pct, self.valve_pct = common_pct, valve_pct
        self.common = 0.0
        self.changes: list[tuple[int, float, int]] = []

    def crack(self, channel: int, factor: float, from_flight: int) -> None:
        self.changes.append((channel, factor, from_flight))

    def flight(self, k: int) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
        t = "A" if k % 3 else "B"
        L = self.levels[t]
        E = L + self.rng.normal(0, 1.0, L.shape)
        steps = np.diff(np.concatenate([L[:, :1], E], axis=1), axis=1)
        P = np.linalg.solve(G, np.diff(np.concatenate([L[:, :1], L], axis=1), axis=1))
        self.common = 0.95 * self.common + self.rng.normal(0, self.common_pct * math.sqrt(1 - 0.95 ** 2))
        gain = 1 + (self.common + self.rng.normal(0, self.valve_pct, 4)) / 100
        F = np.linalg.solve(G, steps) / gain[:, None]
        for i, f, start in self.changes:
            if k >= start:
                F[i] += (1 / f - 1) * steps[i] / G[i, i]
        return t, E, F + self.rng.normal(0, 0.002, F.shape), P


def run(det: TrendDetector, flights: Flights, first: int, last: int, stop: bool = False):
    alarms = []
    for k in range(first, last + 1):
        a = det.add_flight(k, *flights.flight(k))
        if a is not None:
            alarms.append(a)
            if stop:
                break
    return alarms


def test_an_intact_structure_raises_no_alarm_and_a_softer_attachment_is_named_at_once():
    det = TrendDetector(NAMES, G, TrendOptions(learn_flights=20))
    flights = Flights(seed=3)
    assert run(det, flights, 1, 1000) == []
    assert set(det.armed_types()) == {"A", "B"} and det.thresholds.max() < 20
    # the learning flights are recorded but not tested
    assert [h.tested for h in det.history[:20]] == [False] * 20
    assert det.history[-1].tested and len(det.history[-1].z) == 4
    # inner's attachment 3 % softer from flight 1001: its valve needs 3.1 % more of its share
    flights.crack(1, 0.97, 1001)
    alarms = run(det, flights, 1001, 1100, stop=True)
    assert len(alarms) == 1
    a = alarms[0]
    assert (a.flight, a.channels, a.directions, a.since_flights) == (1001, ["inner"], ["soften"], [1001])
    assert a.flow_change_pct[0] == pytest.approx(100 * (1 / 0.97 - 1), abs=0.6)
    assert a.statistics[0] > a.thresholds[0] and a.action == "note"
    assert "flight 1001 (type A): channel inner needs" in a.message() and "a crack?" in a.message()
    assert det.history[-1].alarm == ["inner"]
    # latched: the next flights raise nothing more, until acknowledged
    assert run(det, flights, 1101, 1110) == []
    det.acknowledge()
    assert run(det, flights, 1111, 1112, stop=True)[0].channels == ["inner"]
    # relearned (a repair: the cracked structure is the new baseline): quiet again
    det.acknowledge(relearn=True)
    assert run(det, flights, 1113, 1400) == []


def test_every_valve_gaining_together_is_not_a_crack_but_one_valve_alone_is_named():
    det = TrendDetector(NAMES, G, TrendOptions(learn_flights=20))
    flights = Flights(seed=4, common_pct=0.0)       # learned without any common wander
    run(det, flights, 1, 60)
    flights.common_pct = 3.0                          # then every valve wanders together, 3 %
    assert run(det, flights, 61, 600) == []
    # a stiffer point (a jammed part): less flow at tip, named so
    flights.crack(3, 1.03, 601)
    a = run(det, flights, 601, 700, stop=True)[0]
    assert (a.channels, a.directions) == (["tip"], ["stiffen"])
    assert "less flow" in a.message() and "jammed" in a.message()
    assert det.expected_delay("tip", 1.0) > det.expected_delay("tip", 3.0) >= 1.0


def test_without_G_the_planned_flows_are_the_unit_and_a_crack_is_still_found():
    det = TrendDetector(NAMES, None, TrendOptions(learn_flights=20, sides="soften"))
    flights = Flights(seed=5)
    assert run(det, flights, 1, 400) == []
    flights.crack(0, 0.97, 401)
    a = run(det, flights, 401, 450, stop=True)[0]
    assert a.channels[0] == "root" and a.flight <= 403


def test_a_resumed_test_goes_on_with_the_same_statistic_bit_for_bit():
    options = TrendOptions(learn_flights=15, action="hold")
    flights_a, flights_b = Flights(seed=9), Flights(seed=9)
    flights_a.crack(2, 0.98, 260)
    flights_b.crack(2, 0.98, 260)
    whole = TrendDetector(NAMES, G, options)
    alarms_whole = run(whole, flights_a, 1, 300)
    first = TrendDetector(NAMES, G, options)
    run(first, flights_b, 1, 150)
    journal = json.loads(json.dumps(first.state(with_history=True)))   # through the journal's text
    resumed = TrendDetector.from_state(journal)
    alarms_resumed = run(resumed, flights_b, 151, 300)
    assert alarms_resumed == alarms_whole and alarms_whole and alarms_whole[0].action == "hold"
    assert resumed.state(with_history=True) == whole.state(with_history=True)
    assert [h.to_dict() for h in resumed.history] == [h.to_dict() for h in whole.history]
    assert TrendAlarm.from_dict(alarms_whole[0].to_dict()) == alarms_whole[0]


# -- refusals ----------------------------------------------------------------------------------
@pytest.mark.parametrize("options, says", [
    (TrendOptions(learn_flights=5), "learn_flights = 5: give at least 9"),
    (TrendOptions(shift_pct=0.0), "shift_pct = 0.0 must be a number in [0.01, 100]"),
    (TrendOptions(false_alarm_flights=float("inf")), "false_alarm_flights = inf"),
    (TrendOptions(confidence=1.0), "confidence = 1.0"),
    (TrendOptions(sides="up"), "sides = 'up': choose both or soften"),
    (TrendOptions(action="stop"), "action = 'stop': choose one of note, hold, unload"),
])
def test_options_that_cannot_be_used_are_refused_naming_the_key(options, says):
    with pytest.raises(ParameterError, match="trends: " + says.replace("[", r"\[").replace("]", r"\]")):
        TrendDetector(NAMES, G, options)


def test_a_flight_given_twice_or_out_of_shape_is_refused():
    det = TrendDetector(NAMES, G)
    E = np.ones((4, 6))
    det.add_flight(7, "A", E, E, E)
    for args, says in [((7, "A", E, E, E), "flight 7 after flight 7: each flight is added once"),
                       ((8, "A", E[:3], E[:3], E[:3]), r"end_points must be \(channels, load cases\)"),
                       ((8, "A", E, E * np.nan, E), "flows has a value that is not a finite number"),
                       ((8, "A", E, np.ones((4, 5)), E), "must have one shape"),
                       ((8, "A", np.ones((4, 5)),) * 1 + (np.ones((4, 5)),) * 2, "type 'A' has 6 load cases"),
                       ((8, "", E, E, E), "flight_type = '' must be a name")]:
        with pytest.raises(ParameterError, match=says):
            det.add_flight(*args)
    with pytest.raises(ParameterError, match="not tested yet"):
        det.evaluate("A", E, E)
    with pytest.raises(ParameterError, match="must be 4x4"):
        TrendDetector(NAMES, np.eye(3))


# -- on offline passes of the example rig ----------------------------------------------------------
@pytest.mark.slow
def test_offline_passes_whose_structure_softens_at_inner_mid_test_raise_the_alarm_on_inner():
    """Flights of types B and C (the benchmark's: ground, 1 g, cycles, 1 g, ground at 4000
    kgf/s) flown as offline passes one after the other on one stand clock, each valve's flow
    gain varying from flight to flight; the plant's inner attachment 3 % softer from a stand time
    inside flight 28 (``StructureChange`` on the plant model): no alarm before, the alarm on
    inner, softened, within 3 flights."""
    from benchmarks.crack import example_rig, real_sequence
    rig = example_rig(("B", "C"))
    alarm, from_s, det = real_sequence(rig, 34, 1, 28, seed=11, options=TrendOptions(learn_flights=10))
    assert from_s is not None and alarm is not None, det.text()
    tested = [h for h in det.history if h.tested and h.flight < 28]
    assert tested, "types tested before the crack"
    assert 28 <= alarm.flight <= 30, alarm.message()
    assert alarm.channels[0] == "inner" and alarm.directions[0] == "soften", alarm.message()
    assert alarm.flow_change_pct[0] > 1.5
    print(alarm.message(), f"(the change at {from_s:.1f} s of stand time)")
