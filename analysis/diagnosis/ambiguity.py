"""What the data cannot tell apart, and the experiment that would.

Two explanations of the same error are *ambiguous* when these records cannot separate them:
look-alikes at a single command amplitude (a dead zone lowers the slope like another gain), under
a smooth command (a valve lag shifts it like more delay), candidates that leave about as little
error as the best (within :data:`AMBIGUITY_RATIO`), a parameter the data do not determine, or a
gain that changed between the runs where the runs' order and command levels rise together. Each
:class:`Ambiguity` names the experiment that separates them (:data:`SEPARATING_EXPERIMENT`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..identification.fit import FitResult
from ..records.record import Record
from .between_records import BetweenRecords
from .candidates import Candidate

#: a second candidate that leaves at most this times the error the best leaves is "not
#: separable" from it (comparing what is left, not what is removed: 63 % and 93 % removed leave
#: errors five times apart, which the data do separate)
AMBIGUITY_RATIO = 1.1

#: what separates a drift across the runs from an effect of the command level
REPEAT_FIRST_RUN = ("the first run repeated at the end of the campaign (the same command, "
                    "later): an effect of the command level gives it the first run's gain, a "
                    "drift across the runs the last run's")

#: what separates two explanations (unordered pair -> experiment)
SEPARATING_EXPERIMENT = {
    frozenset({"lag", "delay"}): "a meander (step commands) or P-feedback at several reference "
                                 "frequencies: a lag rounds the corners and its phase grows less "
                                 "than linearly with frequency; a delay only shifts",
    frozenset({"resonance", "lag"}): "a meander (command steps) at a small amplitude, or "
                                      "P-feedback at reference frequencies up to the suspected "
                                      "f_n: a lag never overshoots, a resonance rings after "
                                      "each step and peaks near f_n",
    frozenset({"resonance", "delay"}): "P-feedback at several reference frequencies, up to a "
                                       "third of the sample rate: far below f_n a resonance "
                                       "only adds the delay 2ζ/ω_n, near it the phase and gain "
                                       "change fast",
    frozenset({"slew", "lag"}): "the meander at several amplitudes (e.g. 5 and 20 %): a speed "
                                "limit rounds a step for |Δu|/R, four times as long at four "
                                "times the step, a lag for the same time constant at every step",
    frozenset({"slew", "delay"}): "the meander at several amplitudes: a speed-limited spool "
                                  "reaches the flow |Δu|/(2R) late, later for larger steps; a "
                                  "delay is the same at every amplitude",
    frozenset({"supply", "flow_curve"}): "a large command held for several seconds after a hold "
                                         "at zero: a sagging supply starts at the full slope and "
                                         "bends it down over its time constant, a flow curve "
                                         "has the lower slope from the first instant",
    frozenset({"supply", "saturation"}): "a large command held for several seconds after a "
                                         "hold at zero: a flow limit caps the slope at once, a "
                                         "sagging supply lowers it over its time constant",
    frozenset({"gain_drift", "supply"}): "a long run at one small command amplitude: a "
                                         "warming oil changes the gain whatever the flow drawn, "
                                         "a sagging supply hardly sags at small openings and "
                                         "recovers in every pause",
    frozenset({"null_drift", "gain_drift"}): "the meander at two amplitudes (e.g. 5 and 20 %), "
                                              "or holds at zero command early and late in a "
                                              "run: a drifting null adds the same kgf/s at "
                                              "every command and at zero, a drifting gain "
                                              "scales with |u|",
    frozenset({"null_drift", "trend"}): "one long run, or holds at zero command at its start "
                                        "and its end: the trend Δ is the same throughout, a "
                                        "drifting null moves it during the run",
    frozenset({"gain_drift", "gain"}): "two runs, one after the other, or one long run: a "
                                       "drifting gain differs between the starts and the ends "
                                       "of the runs, a wrong gain is wrong everywhere alike",
    frozenset({"deadzone", "gain"}): "the meander at several amplitudes (e.g. 5, 10, 15, 20 %): "
                                     "a dead zone lowers the slope by g·d at every amplitude, "
                                     "a lower gain in proportion to |u|",
    frozenset({"saturation", "gain"}): "the meander at several amplitudes, some beyond the "
                                       "suspected flow limit: the slope stops growing with |u|",
    frozenset({"asymmetry", "trend"}): "the meander at two amplitudes, or a hold at zero "
                                       "command: the trend Δ is the same at every |u|, an "
                                       "extend/retract asymmetry grows with |u|",
    frozenset({"leakage", "load_pressure"}): "meanders at two amplitudes, or a hold at zero "
                                             "command away from zero force: leakage drifts "
                                             "toward zero at any command, the load-pressure "
                                             "effect scales with |u|",
    frozenset({"leakage", "trend"}): "runs around two different force levels (e.g. meanders "
                                     "centred at +2000 and −2000 kgf): leakage drifts toward "
                                     "zero, the trend Δ does not depend on the force",
    frozenset({"load_pressure", "asymmetry"}): "runs at both positive and negative force "
                                               "levels: the load-pressure effect swaps "
                                               "extend/retract with the sign of the force",
    frozenset({"reversal", "lag"}): "the meander at several amplitudes and periods",
    frozenset({"reversal", "command_reversal"}): "the meander with a delay comparable to the "
                                                 "boost's decay: a boost timed from the command "
                                                 "already pushes the old direction during the "
                                                 "delay, one timed from the rod starts after it",
    frozenset({"reversal", "travel_reversal"}): "the meander at several amplitudes (e.g. 5 and "
                                                "20 %): a boost timed from the reversal lasts "
                                                "T_r at every amplitude, one that dies out over "
                                                "the travel lasts V_r/|u|, four times shorter at "
                                                "four times the command",
    frozenset({"command_reversal", "travel_reversal"}): "the meander at several amplitudes: a "
                                                        "boost timed from the command lasts T_r "
                                                        "at every amplitude and starts during "
                                                        "the delay, one that dies out over the "
                                                        "travel lasts V_r/|u| from the rod's "
                                                        "reversal",
    frozenset({"deadzone", "backlash"}): "P-feedback with a harmonic reference (a command that "
                                         "turns smoothly): a play delays the valve at every "
                                         "turning point of the command, a dead zone only cuts "
                                         "the flow near zero; square waves (meander, relay) "
                                         "cannot tell them apart",
    frozenset({"deadzone", "flow_curve"}): "the meander at three or more amplitudes (e.g. 5, 10, "
                                           "15, 20 %): two amplitudes fit both exactly; a dead "
                                           "zone lowers every slope by g·d, a flow curve bends "
                                           "the slopes as |u|^p",
    frozenset({"saturation", "flow_curve"}): "the meander at amplitudes below and beyond the "
                                             "suspected limit: a flow limit leaves the small "
                                             "amplitudes' slopes in proportion and flattens only "
                                             "above it, a flow curve bends them all",
    frozenset({"flow_curve", "gain"}): "the meander at several amplitudes: the ramp slopes grow "
                                       "as |u|^p instead of in proportion to |u|",
    frozenset({"backlash", "gain"}): "the meander at several amplitudes, or P-feedback with a "
                                     "harmonic reference",
    frozenset({"stiction", "delay"}): "the meander at two or more amplitudes (e.g. 5 and 20 %): a "
                                      "rod stuck after each reversal holds the force w/(g·|u|), longer "
                                      "at small amplitudes; a delay is the same at every amplitude",
    frozenset({"stiction", "backlash"}): "the meander (square waves): a play on the command is "
                                         "jumped at once by a step, a stuck rod still holds the "
                                         "force after each reversal",
    frozenset({"direction_delay", "trend"}): "meanders at two periods (e.g. 4 and 12 s): a "
                                             "trend Δ is the same at both, the flow's extra "
                                             "time at one command each period shrinks with a "
                                             "longer period",
    frozenset({"unloading", "asymmetry"}): "runs at both positive and negative force levels: "
                                           "an asymmetry keeps its fast direction, a specimen "
                                           "stiffer unloading swaps it with the sign of the force",
    frozenset({"unloading", "load_pressure"}): "runs at two force levels of the same sign (e.g. "
                                               "meanders centred at 2000 and 6000 kgf): the "
                                               "load-pressure effect grows with the force, the "
                                               "unloading stiffness only switches at zero force",
    frozenset({"lag", "sensor_lag"}): "the dynamometer's own filter setting (its configuration "
                                      "or data sheet) or a second force measurement; in a "
                                      "linear plant nothing on the command side separates "
                                      "them, behind a valve nonlinearity (dead zone, flow "
                                      "limit, reversal boost) meanders at amplitudes near it "
                                      "can",
}


def separating_experiment(a: str, b: str) -> str:
    return SEPARATING_EXPERIMENT.get(frozenset({a, b}),
                                     "the meander at several amplitudes and periods, plus relay "
                                     "and P-feedback runs (richer excitation)")


@dataclass
class Ambiguity:
    effects: list[str]            #: what cannot be told apart ("deadzone", "gain", ...)
    reason: str
    experiment: str               #: the experiment that would separate them

    def text(self) -> str:
        if len(self.effects) == 1:
            return f"{self.effects[0]}: {self.reason} To test it: {self.experiment}."
        return f"{' vs '.join(self.effects)}: {self.reason} To separate them: {self.experiment}."


@dataclass
class Excitation:
    """What the data contain, as far as separating effects is concerned."""

    levels: list[float]           #: distinct nonzero |u| levels (empty if continuous)
    continuous: bool              #: the command varies continuously (feedback with smooth r)
    has_steps: bool               #: the command jumps (meander, relay)
    has_zero_hold: bool           #: the command rests at 0 for ≥ 0.5 s somewhere
    single_frequency: bool        #: smooth command dominated by one frequency
    force_span_kgf: float
    both_force_signs: bool

    @classmethod
    def of(cls, records: Sequence[Record]) -> "Excitation":
        u = np.concatenate([r.u for r in records])
        y = np.concatenate([r.y for r in records])
        nz = np.abs(u[u != 0])
        levels = np.unique(np.round(nz, 2)) if len(nz) else np.array([])
        continuous = len(levels) > 6
        span = float(np.ptp(u)) or 1.0
        steps = any(np.any(np.abs(np.diff(r.u)) > 0.25 * span) for r in records)
        zero = False
        for r in records:
            z = np.concatenate([[0], (r.u == 0).astype(int), [0]])
            edges = np.flatnonzero(np.diff(z))
            runs = edges[1::2] - edges[::2]
            if len(runs) and runs.max() * r.dt >= 0.5:
                zero = True
        single = False
        if continuous and not steps:
            spec = np.abs(np.fft.rfft(u - u.mean())) ** 2
            k = int(np.argmax(spec[1:])) + 1
            single = spec[max(1, k - 3):k + 4].sum() > 0.8 * spec[1:].sum()
        return cls([float(v) for v in levels] if not continuous else [], continuous, steps, zero,
                   single, float(np.ptp(y)), bool(y.min() < -0.1 * np.ptp(y) and y.max() > 0.1 * np.ptp(y)))


def ambiguities(records: Sequence[Record], base_fit: FitResult, cands: Sequence[Candidate],
                best: Candidate | None) -> list[Ambiguity]:
    """What these records cannot tell apart among the candidates (``cands``, ranked; ``best``
    the one that earns, if any): look-alikes at a single command amplitude or under a smooth
    command, candidates that leave about as little error as the best, and parameters of the
    best that the data do not determine; each with the experiment that would separate them."""
    ex = Excitation.of(records)
    out: list[Ambiguity] = []
    names = {c.effect for c in cands}
    single = len(ex.levels) == 1 and not ex.continuous
    if single:
        lv = f"{ex.levels[0]:g} %"
        like_gain = {
            "deadzone": "a dead zone d only lowers the slope to g·(|u| − d)",
            "flow_curve": "a bent flow curve only changes the slope",
            "backlash": "a play of width w lowers the slope to g·(|u| − w/2)",
            "saturation": "a flow limit below it caps the slope",
        }
        for name, how in like_gain.items():
            if name in names:
                out.append(Ambiguity([name, "gain"],
                                     f"at a single command amplitude (|u| = {lv}) {how}: it looks "
                                     f"exactly like another gain g.",
                                     separating_experiment(name, "gain")))
        if "stiction" in names:
            out.append(Ambiguity(["stiction", "delay"],
                                 f"at a single command amplitude (|u| = {lv}) a rod that sticks "
                                 f"after each reversal holds the force the same w/(g·|u|) every time: "
                                 f"it looks like more delay (the fitted τ = "
                                 f"{base_fit.model.tau * 1e3:.1f} ms may include such a hold).",
                                 separating_experiment("stiction", "delay")))
        if "asymmetry" in names and not ex.has_zero_hold:
            d = base_fit.model.delta
            ramp = base_fit.model.g * ex.levels[0]
            hint = (f" The fitted trend Δ = {d:.3g} kgf/s is {abs(d) / ramp * 100:.1f} % of the "
                    f"ramp rate g·|u|; if the valve's null offset is known to be small, read it as "
                    f"an asymmetry a ≈ {d / ramp:+.3f} (retract {'slower' if d > 0 else 'faster'}).") \
                if ramp > 0 else ""
            out.append(Ambiguity(["asymmetry", "trend"],
                                 f"with the command always ±{lv}, a gain that differs between extend "
                                 f"and retract adds the same force rate as the trend Δ.{hint}",
                                 separating_experiment("asymmetry", "trend")))
        if {"leakage", "load_pressure"} <= names or (best and best.effect in ("leakage", "load_pressure")):
            out.append(Ambiguity(["leakage", "load_pressure"],
                                 "at a single command amplitude the orifice law's slow-down "
                                 "(∝ sign(u)·y) acts like a leak toward zero force.",
                                 separating_experiment("leakage", "load_pressure")))
    if ex.continuous and not ex.has_steps and "lag" in names and (best is None or best.effect != "lag"):
        what = "a smooth single-frequency signal" if ex.single_frequency else "smooth, without steps"
        out.append(Ambiguity(["lag", "delay"],
                             f"the command is {what}: a valve lag T shifts a slow command like "
                             f"extra delay, so mainly τ + T is determined (fitted τ = "
                             f"{base_fit.model.tau * 1e3:.1f} ms may include a lag).",
                             separating_experiment("lag", "delay")))
    if best is not None and best.effect in ("lag", "sensor_lag"):
        other = "sensor_lag" if best.effect == "lag" else "lag"
        alt = next((c for c in cands if c.effect == other), None)
        if alt is None or alt.objective_rmse <= AMBIGUITY_RATIO * best.objective_rmse:
            out.append(Ambiguity(
                [best.effect, other],
                "a first-order filter in the dynamometer acts on the measured force exactly "
                "like a valve lag on an integrating plant (the two commute), in open and closed "
                "loop alike, unless a valve nonlinearity sits between them: these data cannot "
                "tell where the lag is.", separating_experiment("lag", "sensor_lag")))
    if best is not None and best.effect == "supply":
        T = best.params.get("supply.time_constant", math.nan)
        out.append(Ambiguity(
            ["supply", "flow_curve"],
            f"at a held command the supply's sag settles at k·|u| and the gain at "
            f"√(1 − k·|u|/100), a degressive flow characteristic of its own: only the sag's "
            f"build-up over T (fitted {T:.3g} s) after |u| changes tells a sagging supply from a "
            f"bent flow curve (or a dead zone with one).",
            separating_experiment("supply", "flow_curve")))
    if "saturation" in names and best is None:
        top = max((abs(r.u).max() for r in records), default=0.0)
        if top < 100.0:
            out.append(Ambiguity(["saturation"],
                                 f"the command never exceeds {top:.3g} %: a flow limit above that "
                                 f"cannot show in these data.",
                                 "runs at larger command amplitudes"))
    # candidates the data do not separate (comparable error reductions)
    if best is not None:
        for c in cands:
            if c is best or not c.earns:
                continue
            if c.objective_rmse <= AMBIGUITY_RATIO * best.objective_rmse:
                pair = [best.effect, c.effect]
                if any(set(a.effects) == set(pair) for a in out):
                    continue
                out.append(Ambiguity(pair, f"+{c.effect} leaves about as little error as "
                                           f"+{best.effect} ({c.objective_rmse:.3g} vs "
                                           f"{best.objective_rmse:.3g} kgf).",
                                     separating_experiment(*pair)))
        # parameters of the best candidate the data do not determine
        if best.fit is not None:
            for name in best.fit.non_identifiable():
                out.append(Ambiguity([name], "this parameter is not determined by these data "
                                             "(it trades off against another one).",
                                     "the meander at several amplitudes and periods"))
    return out


def drift_or_level(best: Candidate | None, between: BetweenRecords) -> Ambiguity:
    """The records' own g or Δ explain the error as well as ``best`` (or a gain that depends on
    the command), and the records cannot tell a drift across the runs from a dependence on the
    command level."""
    return Ambiguity(
        effects=[best.effect if best is not None else "a gain that depends on the command",
                 f"a {between.varies} that changed between the runs"],
        reason=(f"the records' own {between.varies}s would explain the error as well, and "
                f"these records cannot tell a drift across the runs from a dependence on "
                f"the command level (their levels rise with their order, or they are few)."),
        experiment=REPEAT_FIRST_RUN)
