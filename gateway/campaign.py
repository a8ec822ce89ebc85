r"""A station's identification campaign, run in ONE gateway session: the paper's whole
experimental program on a stand, or the meanders that identify a rig's G.

::

    from gateway import Gateway, GatewayConfig
    from gateway.campaign import CampaignPlan, run_campaign

    with Gateway(GatewayConfig(bus="udp_loopback:stand0", lockstep=True)) as gw:
        result = run_campaign(gw, CampaignPlan.default(), "campaigns/c1")
    print(result.stand_s, result.wall_s)

**The paper's program** (:class:`CampaignPlan`, dataclasses, defaults from the paper):

* **meander** (Figs. 3-12): u0 = 5, 10, 15, 20 %, period 4 s, 4 periods each;
* **pfeedback** (Figs. 13-18): k = 0.005 %/kgf, ω = 0.3142, 0.6283, 1.2566, 2.5133 rad/s ×
  A_r = 1000, 2000, 3000 kgf, 10 s for the loop's transient plus 2 periods each;
* **relay** (Figs. 19-23): u0 = 5, 10, 15, 20 % × r = −2500 … 2500 kgf in steps of 500, 3 s of
  limit cycle each; r runs up for one amplitude and down for the next, so the force never has
  to travel far between runs.

Every experiment starts with the set-point approach and guards the force limit. Each writes its
own run directory ``OUT/runs/NN-label``; the campaign writes ``OUT/campaign.json``.

**A rig's G** (:class:`GPlan`, docs/rig.md, "Identifying G"):
* **per column**: one run per channel, that channel a meander (``±u0``, period ``P``), every
  other valve at a zero command; run ``k`` is column ``k`` of G;
* **simultaneous**: one run, every channel a meander of its own period (periods that tell the
  channels apart: :func:`analysis.rig.periods.separating_periods`, chosen by the caller), as
  many whole periods as fit in the duration (:class:`~gateway.experiments.each_channel.EachChannel`);
* **one run**: every channel a ±u0 meander whose signs follow its row of a Hadamard matrix, all
  switching on one grid (:class:`~gateway.experiments.one_run.OneRun`), its slot and length
  planned for the accuracy asked before anything moves (:func:`rig.excitation.plan_one_run`,
  :class:`rig.excitation.OneRunDesign`): the run does not grow with N beyond the 2·m slots of
  the Hadamard pattern (m ≥ N).

The runs are written as ``OUT/NN-LABEL`` (rig runs: every channel, a capture per bus) beside
``OUT/rig-campaign.json``, so ``stand estimate OUT --save rig.toml`` reads the directory as it is.
**Before anything moves**, when the rig file gives the structure G, each channel's planned
swing is checked: a meander that starts a quarter period in swings each force by at most

.. math::  s_i = \sum_j |G_{ij}|\,u_{0,j}\,P_j/4

about where it started (per column only the moving channel's term; one run: the largest
excursion of ``Σ_j G_ij u_j`` integrated over the slots, :func:`rig.excitation.swings_kgf`). Over
:data:`SWING_SHARE` of the channel's force limit (room for where the force starts and its
trend) the plan is refused with the amplitude that would fit. Each meander still stops itself
at 90 % of its channel's limit (the experiment's guard).

Either way the campaign file holds the plan, every run's outcome (with the channels it drove),
the stand and wall time. An experiment that stopped itself (force near the limit, set point not
reached) is recorded and the campaign goes on; any other stop (supervisor: force limit, lost
heartbeat, EMCY, ...) ends the campaign.
"""
from __future__ import annotations

import datetime as _dt
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

from tqdm import tqdm

import numpy as np

from core.durable import write_json
from rig.excitation import OneRunDesign, swings_kgf

from .errors import ParameterError, StandError
from .experiments import Meander, make_experiment
from .experiments.each_channel import EachChannel
from .experiments.one_run import OneRun
from .experiments.phases import FORCE_NEAR_LIMIT, SET_POINT_NOT_REACHED
from .runs import TRUTH_FILE
from .session import Gateway

CAMPAIGN_FILE = "campaign.json"
RUNS_DIR = "runs"
FORMAT = "hydrostand-campaign/1"
#: a rig's G: its campaign file and format
G_CAMPAIGN_FILE = "rig-campaign.json"
G_FORMAT = "hydrostand-rig-campaign/1"
#: the share of a channel's force limit a planned meander may swing its force (module docstring)
SWING_SHARE = 0.6
#: experiment-level stops after which the campaign goes on with the next experiment
CONTINUE_AFTER = (FORCE_NEAR_LIMIT, SET_POINT_NOT_REACHED)
#: stand time assumed for a set-point approach when planning (s)
APPROACH_GUESS_S = 1.0


@dataclass
class MeanderPlan:
    """Open-loop square waves, one run per amplitude (paper Figs. 3-12)."""

    amplitudes_pct: tuple[float, ...] = (5.0, 10.0, 15.0, 20.0)
    period_s: float = 4.0
    cycles: int = 4
    set_point_kgf: float = 0.0


@dataclass
class PFeedbackPlan:
    """P feedback with a harmonic reference, one run per (ω, A_r) (paper Figs. 13-18)."""

    gain: float = 0.005
    omegas_rad_s: tuple[float, ...] = (0.3142, 0.6283, 1.2566, 2.5133)
    amplitudes_kgf: tuple[float, ...] = (1000.0, 2000.0, 3000.0)
    periods: float = 2.0
    transient_s: float = 10.0
    offset_kgf: float = 0.0


@dataclass
class RelayPlan:
    """Relay feedback, one run per (u0, r) (paper Figs. 19-23)."""

    amplitudes_pct: tuple[float, ...] = (5.0, 10.0, 15.0, 20.0)
    references_kgf: tuple[float, ...] = tuple(float(r) for r in range(-2500, 2501, 500))
    duration_s: float = 3.0            #: length of each relay phase, s
    hysteresis_kgf: float = 0.0


@dataclass
class PlannedRun:
    index: int
    experiment: str
    params: dict[str, Any]
    label: str                      #: run directory name, e.g. ``07-relay-u10-r-500``
    nominal_s: float                #: expected stand time (main phase + an approach guess), s
    #: a rig's channels the experiment drives (None: a stand's channel, or every channel for a
    #: rig experiment)
    channels: list[str] | None = None
    #: the experiment itself where it is no registered ``stand run`` experiment
    made: Any = field(default=None, repr=False)

    def make(self):
        return self.made if self.made is not None else make_experiment(self.experiment, self.params)


@dataclass
class CampaignPlan:
    """Which experiments, with which grids. None leaves an experiment out."""

    meander: MeanderPlan | None = field(default_factory=MeanderPlan)
    pfeedback: PFeedbackPlan | None = field(default_factory=PFeedbackPlan)
    relay: RelayPlan | None = field(default_factory=RelayPlan)
    settle_max_s: float = 10.0

    @classmethod
    def default(cls) -> "CampaignPlan":
        return cls()

    @classmethod
    def quick(cls) -> "CampaignPlan":
        """A short campaign (about a minute of stand time): two points of every grid."""
        return cls(meander=MeanderPlan(amplitudes_pct=(5.0, 20.0), period_s=4.0, cycles=2),
                   pfeedback=PFeedbackPlan(omegas_rad_s=(1.2566, 2.5133), amplitudes_kgf=(2000.0,),
                                           periods=1.5, transient_s=9.0),
                   relay=RelayPlan(amplitudes_pct=(5.0, 20.0), references_kgf=(-500.0, 500.0),
                                   duration_s=2.0))

    def only(self, names: list[str]) -> "CampaignPlan":
        """The plan restricted to some experiments."""
        known = ("meander", "pfeedback", "relay")
        bad = [n for n in names if n not in known]
        if bad:
            raise ParameterError(f"unknown experiment(s) {', '.join(bad)}; choose from {', '.join(known)}")
        return CampaignPlan(**{n: (getattr(self, n) if n in names else None) for n in known},
                            settle_max_s=self.settle_max_s)

    #: where the campaign writes its file and its runs
    file, format, runs_dir = CAMPAIGN_FILE, FORMAT, RUNS_DIR

    def runs(self, names: Sequence[str] | None = None) -> list[PlannedRun]:
        out: list[PlannedRun] = []
        settle = {"settle_max_s": self.settle_max_s}

        def add(name: str, params: dict, label: str) -> None:
            exp = make_experiment(name, {**params, **settle})   # validates now, not mid-campaign
            out.append(PlannedRun(len(out) + 1, name, {**params, **settle},
                                  f"{len(out) + 1:02d}-{label}", exp.duration_s + APPROACH_GUESS_S))

        if self.meander:
            m = self.meander
            for u0 in m.amplitudes_pct:
                add("meander", {"amplitude_pct": u0, "period_s": m.period_s, "cycles": m.cycles,
                                "set_point_kgf": m.set_point_kgf}, f"meander-u{u0:g}")
        if self.pfeedback:
            p = self.pfeedback
            for w in p.omegas_rad_s:
                for a in p.amplitudes_kgf:
                    add("pfeedback", {"gain": p.gain, "amplitude_kgf": a, "omega_rad_s": w,
                                      "periods": p.periods, "transient_s": p.transient_s,
                                      "offset_kgf": p.offset_kgf}, f"pfeedback-w{w:g}-a{a:g}")
        if self.relay:
            rp = self.relay
            for i, u0 in enumerate(rp.amplitudes_pct):
                refs = list(rp.references_kgf) if i % 2 == 0 else list(reversed(rp.references_kgf))
                for r in refs:
                    add("relay", {"amplitude_pct": u0, "reference_kgf": r, "duration_s": rp.duration_s,
                                  "hysteresis_kgf": rp.hysteresis_kgf}, f"relay-u{u0:g}-r{r:g}")
        if not out:
            raise ParameterError("the campaign plan has no experiment")
        return out

    def nominal_stand_s(self) -> float:
        return sum(r.nominal_s for r in self.runs())

    def check(self, gw: Gateway) -> None:
        """The paper's program drives one stand."""
        if gw.rig is not None:
            raise ParameterError("the paper's campaign drives one stand; a rig's campaign identifies G "
                                 "(stand campaign --rig)")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class GPlan:
    """The meanders that identify a rig's G (module docstring): ``periods_s`` one per channel
    (simultaneous) or one for all (per column), or ``one_run``'s Hadamard meanders
    (:meth:`one`)."""

    simultaneous: bool
    amplitude_pct: float = 5.0
    periods_s: list[float] = field(default_factory=lambda: [8.0])
    #: per column: periods per run; simultaneous: the run's length (each channel as many whole
    #: periods as fit, at least 2)
    cycles: int = 4
    duration_s: float = 120.0
    #: the one-run design (None: per column or simultaneous)
    one_run: OneRunDesign | None = None

    file, format, runs_dir = G_CAMPAIGN_FILE, G_FORMAT, ""

    @classmethod
    def one(cls, design: OneRunDesign) -> "GPlan":
        """The one-run campaign of a planned design (:func:`rig.excitation.plan_one_run`)."""
        return cls(False, min(design.amplitude_pct), [2 * design.slot_s], 1, design.duration_s,
                   design)

    def runs(self, names: Sequence[str]) -> list[PlannedRun]:
        """One run per column (the channel named drives, the others hold a zero command), or
        one simultaneous run (every channel its own meander: a rig experiment), or the one
        run of Hadamard meanders."""
        names = list(names)
        if self.one_run is not None:
            d = self.one_run
            if d.channels != len(names):
                raise ParameterError(f"a one-run design for {d.channels} channels, the rig has {len(names)}")
            exp = OneRun(names, d.amplitude_pct, d.slot_s, d.repeats)
            return [PlannedRun(1, exp.name, exp.params(), "01-one-run",
                               exp.duration_s + APPROACH_GUESS_S, None, exp)]
        if self.simultaneous:
            if len(self.periods_s) != len(names):
                raise ParameterError(f"{len(self.periods_s)} periods for {len(names)} channels")
            exps = [Meander(self.amplitude_pct, p, max(2, int(self.duration_s // p))) for p in self.periods_s]
            each = EachChannel(names, exps)
            return [PlannedRun(1, "meander", {"periods_s": list(self.periods_s)}, "01-simultaneous",
                               each.duration_s + APPROACH_GUESS_S, None, each)]
        out = []
        for k, n in enumerate(names, start=1):
            m = Meander(self.amplitude_pct, self.periods_s[0], self.cycles)
            out.append(PlannedRun(k, "meander", m.params(), f"{k:02d}-column-{n}", m.duration_s + APPROACH_GUESS_S,
                                  [n], m))
        return out

    def swings_kgf(self, G: np.ndarray) -> np.ndarray:
        """Each channel's largest planned swing (kgf) over the runs (module docstring)."""
        n = G.shape[0]
        if self.one_run is not None:
            d = self.one_run
            return swings_kgf(G, d.amplitude_pct, d.signs(), d.slot_s)
        reach = np.abs(G) * self.amplitude_pct
        if self.simultaneous:
            return reach @ (np.asarray(self.periods_s, float) / 4)
        return np.max(reach * (self.periods_s[0] / 4), axis=1) if n else np.zeros(0)

    def check_rig(self, rig) -> None:
        """Refuse, before anything moves, a plan whose swing the rig's G says is too large."""
        if not (0 < self.amplitude_pct <= 100):
            raise ParameterError(f"--amplitude-pct {self.amplitude_pct:g}: it must be from 0 to 100 %")
        if rig.G is None:
            return
        swings = self.swings_kgf(np.asarray(rig.G, float))
        limits = np.array([c.limit_kgf for c in rig.channels])
        share = swings / (SWING_SHARE * limits)
        i = int(np.argmax(share))
        if share[i] > 1:
            how = ("the largest excursion of Σ_j G_ij·u_j over the slots" if self.one_run is not None
                   else "Σ|G_ij|·u0·P_j/4")
            what = ("or a shorter slot (--duration-s)" if self.one_run is not None
                    else "or the meander period")
            raise ParameterError(
                f"{rig.where}: channel {rig.names[i]} would swing ±{swings[i]:.0f} kgf ({how} "
                f"with the rig file's G), over {SWING_SHARE:.0%} of its force limit "
                f"±{limits[i]:.0f} kgf; nothing was started. Lower --amplitude-pct to "
                f"{self.amplitude_pct / share[i]:.2g} {what}")

    def check(self, gw: Gateway) -> None:
        if gw.rig is None:
            raise ParameterError("a rig campaign needs a rig (--rig RIG.toml)")
        self.check_rig(gw.rig)

    def nominal_stand_s(self, names: Sequence[str]) -> float:
        return sum(r.nominal_s for r in self.runs(names))

    def to_dict(self) -> dict:
        out = asdict(self)
        if self.one_run is not None:      # JSON has no NaN (an accuracy not planned)
            out["one_run"] = {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                              for k, v in out["one_run"].items()}
            out["one_run"].update(slots=self.one_run.slots, duration_s=self.one_run.duration_s)
        return out


@dataclass
class CampaignRun:
    """One experiment of the campaign as it went."""

    label: str
    experiment: str
    params: dict[str, Any]
    path: str
    status: str                     #: "complete" | "stopped"
    reason: str | None
    message: str | None
    cycles: int
    stand_s: float
    wall_s: float
    #: the channels it drove (a rig's; empty: a stand's one channel)
    driven: list[str] = field(default_factory=list)


@dataclass
class CampaignResult:
    out_dir: Path
    runs: list[CampaignRun]
    stand_s: float
    wall_s: float
    status: str                     #: "complete" | "partial" (some runs stopped) | "stopped" | "interrupted"
    stopped_by: str | None = None   #: message when the campaign ended early

    @property
    def speedup(self) -> float:
        return self.stand_s / self.wall_s if self.wall_s > 0 else float("nan")

    @property
    def run_dirs(self) -> list[Path]:
        return [Path(r.path) for r in self.runs]


def run_campaign(gw: Gateway, plan: CampaignPlan | GPlan, out_dir: str | Path, progress: bool | None = None,
                 truth: dict[str, Any] | None = None,
                 on_run: Callable[[CampaignRun], None] | None = None) -> CampaignResult:
    """Run every experiment of ``plan`` through the connected gateway ``gw`` (module docstring).

    ``truth`` (the emulator's: :meth:`PlantConfig.to_dict`, or a rig's
    :func:`rig.emulated.rig_truth`) is written into every run directory as ``truth.json``; the
    estimators never read it. ``progress``: a bar over the whole campaign's stand time (None:
    when stderr is a terminal)."""
    plan.check(gw)
    out = Path(out_dir)
    rig = gw.rig
    if out.exists() and any(p.name != "rig.toml" for p in out.iterdir()):
        raise StandError(f"{out} exists and is not empty; choose a new --out directory")
    planned = plan.runs(rig.names if rig is not None else None)
    (out / plan.runs_dir).mkdir(parents=True, exist_ok=True)
    period = gw.config.period_s
    started = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    wall0 = time.monotonic()
    done: list[CampaignRun] = []
    state = {"status": "running", "stopped_by": None}

    def save() -> None:
        stand = sum(r.stand_s for r in done)
        wall = time.monotonic() - wall0
        write_json(out / plan.file, {
            "format": plan.format, "status": state["status"], "stopped_by": state["stopped_by"],
            **({"rig": rig.name} if rig is not None else {"bus": gw.config.bus}),
            "clock": "lockstep" if gw.config.lockstep else "realtime",
            "period_s": period, "started": started,
            "ended": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "stand_s": stand, "wall_s": wall, "speedup": stand / wall if wall > 0 else None,
            "plan": plan.to_dict(), "planned_runs": len(planned),
            "runs": [asdict(r) for r in done], "emulated": truth is not None})

    total = sum(p.nominal_s for p in planned)
    bar = tqdm(total=round(total, 1), unit="s", desc="campaign", disable=None if progress is None else not progress,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} s stand time "
                          "[{elapsed}<{remaining}] {postfix}")
    save()
    try:
        for i, p in enumerate(planned):
            experiment = p.make()
            base = sum(r.stand_s for r in done)
            bar.set_postfix_str(f"{p.index}/{len(planned)} {p.label}")

            def tick(t: float, base: float = base) -> None:
                if base + t - bar.n >= 0.5:
                    bar.update(base + t - bar.n)

            t0 = time.monotonic()
            result = gw.run(experiment, out / plan.runs_dir / p.label, progress=False, on_progress=tick,
                            channels=p.channels)
            if truth is not None:
                write_json(result.path / TRUTH_FILE, truth)
            stats = result.outcome.stats
            driven = p.channels or (list(rig.names) if rig is not None else [])
            run = CampaignRun(p.label, p.experiment, p.params, str(result.path), result.status,
                              result.reason, result.outcome.message, stats.cycles, stats.cycles * period,
                              time.monotonic() - t0, driven)
            done.append(run)
            # re-plan the bar: what is done plus what is still to come
            bar.total = round(sum(r.stand_s for r in done) + sum(q.nominal_s for q in planned[i + 1:]), 1)
            bar.update(sum(r.stand_s for r in done) - bar.n)
            if on_run is not None:
                on_run(run)
            save()
            if result.reason is not None and result.reason not in CONTINUE_AFTER:
                state["status"] = "stopped"
                state["stopped_by"] = f"{p.label}: {result.reason}: {result.outcome.message}"
                break
        else:
            state["status"] = "partial" if any(r.status != "complete" for r in done) else "complete"
    except BaseException:
        state["status"] = "interrupted"
        state["stopped_by"] = "the campaign was interrupted"
        raise
    finally:
        bar.close()
        save()
    stand = sum(r.stand_s for r in done)
    return CampaignResult(out, done, stand, time.monotonic() - wall0, state["status"], state["stopped_by"])
