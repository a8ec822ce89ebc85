"""Check a rig before anything moves (``stand rig check RIG.toml``).

:func:`check_rig` reads nothing from a bus: it looks at the rig file as loaded
(:func:`rig.config.load_rig_file` refuses what cannot be read at all) and finds what would go
wrong once it runs:

* **problems** (the check fails): a bus loaded beyond the rig's limit, worst case (with what
  would fit, :mod:`rig.budget`); two buses that are one python-can bus (same interface and
  channel); a bus whose interface python-can does not know here; a bus whose spec sets a bit
  rate or CAN FD other than the rig file says (the budget would count the wrong bus); a
  structure no symmetric positive definite stiffness gives, or a given K that is not
  symmetric (:mod:`rig.structure`);
  an emulated plant whose dynamometer range differs from its channel's, or that starts beyond
  its channel's force limit;
* **notes** (said, not failed): no structure given (the channels are taken as uncoupled), a
  structure that is not diagonally dominant (per-channel PI is then not the easy case:
  decouple through G⁻¹, ../shared/notes/rig.md), some channels without an emulated plant (the
  emulator then cannot run the rig), a bus that carries no channel.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from standbus.spec import BusSpec, known_interfaces

from .budget import BusBudget, bus_budgets
from .config import RigConfig
from .emulated import change_dict, sensor_range_conflict
from .structure import StructureVerdict, judge_structure


@dataclass(frozen=True)
class RigCheck:
    """What :func:`check_rig` found."""

    rig: RigConfig
    budgets: list[BusBudget]
    #: the structure's verdict (its ``check`` None: the rig gives no structure)
    structure: StructureVerdict
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def to_dict(self) -> dict[str, Any]:
        """The check as ``stand rig check --json`` prints it."""
        rig = self.rig
        structure = None
        check = self.structure.check
        if rig.G is not None and check is not None:
            structure = {"from": rig.structure_from, "G": rig.G.tolist(),
                         "K": rig.K.tolist() if rig.K is not None else None,
                         "physical": self.structure.physical, "reason": self.structure.reason,
                         "asymmetry": check.asymmetry,
                         "min_eigenvalue_ratio": check.min_eigenvalue_ratio,
                         "changes": [change_dict(rig, c) for c in rig.changes],
                         "G_changed": rig.G_changed.tolist()}
        return {
            "rig": rig.name,
            "path": str(rig.path) if rig.path is not None else None,
            "period_ms": 1e3 * rig.period_s,
            "heartbeat_ms": rig.heartbeat_ms,
            "bus_load_limit_pct": 100 * rig.bus_load_limit,
            "buses": [b.to_dict() for b in self.budgets],
            "channels": [{"name": c.name, "bus": c.bus, "valve_id": c.valve_id,
                          "dynamometer_id": c.dynamometer_id, "range_kgf": c.range_kgf,
                          "force_limit_kgf": c.limit_kgf,
                          "plant": c.plant.model.spec if c.plant is not None else None}
                         for c in rig.channels],
            "structure": structure,
            "problems": list(self.problems),
            "notes": list(self.notes),
            "ok": self.ok,
        }

    def text(self) -> str:
        """The check as ``stand rig check`` prints it."""
        rig = self.rig
        out = [f"rig {rig.name!r}" + (f" ({rig.path})" if rig.path is not None else "")
               + f": {len(rig.channels)} channel(s) on {len(rig.buses)} bus(es), period "
               f"{1e3 * rig.period_s:g} ms, heartbeats {rig.heartbeat_ms} ms"]
        out.append("")
        out.append(f"buses (load worst case, limit {100 * rig.bus_load_limit:g} %)")
        rows = [("name", "spec", "bit rate", "kind", "load", "channels")]
        for b in self.budgets:
            kind = (f"CAN FD, data {_rate(b.bus.data_bitrate or b.bus.bitrate)}" if b.bus.fd
                    else "classic")
            rows.append((b.bus.name, b.bus.spec, _rate(b.bus.bitrate), kind,
                         f"{b.load.load_pct:.1f} %", ", ".join(b.channels) or "-"))
        out += _table(rows, right={4})
        out.append("")
        out.append("channels")
        rows = [("name", "bus", "valve", "dynamometer", "range kgf", "limit kgf", "emulated plant")]
        for c in rig.channels:
            plant = "-"
            if c.plant is not None:
                m = c.plant.model
                plant = f"{m.spec} (τ {1e3 * m.tau:g} ms, Δ {m.delta:g} kgf/s)"
            rows.append((c.name, c.bus, str(c.valve_id), str(c.dynamometer_id),
                         f"{c.range_kgf:g}", f"{c.limit_kgf:g}", plant))
        out += _table(rows, right={2, 3, 4, 5})
        out.append("")
        check = self.structure.check
        if rig.G is None or check is None:
            out.append("structure: none given")
        else:
            source = {"G": "G as given", "K": "K with the flow gains, G = K·diag(c/A)",
                      "plants": "the plants' own g, uncoupled"}.get(rig.structure_from,
                                                                    rig.structure_from)
            out.append(f"structure G, kgf/(%·s) (from {source})")
            rows = [("",) + tuple(rig.names)]
            rows += [(name,) + tuple(f"{v:g}" for v in row) for name, row in zip(rig.names, rig.G)]
            out += _table(rows, right=set(range(1, len(rig.names) + 1)))
            out.append(f"  {check.text()}")
            if check.physical and self.structure.reason:
                out.append(f"  but {self.structure.reason}")
            if rig.changes:
                out.append("")
                out.append("structure changes (stand emulate --rig; stand time since the "
                           "emulator started)")
                out += [f"  {rig.change_text(c)}" for c in rig.changes]
                out.append("G once every change is complete, kgf/(%·s) (a compliance at each "
                           "changed point: its row and column times its factor)")
                rows = [("",) + tuple(rig.names)]
                rows += [(name,) + tuple(f"{v:.4g}" for v in row)
                         for name, row in zip(rig.names, rig.G_changed)]
                out += _table(rows, right=set(range(1, len(rig.names) + 1)))
        out.append("")
        if self.problems:
            out.append(f"problems ({len(self.problems)})")
            out += [f"  - {p}" for p in self.problems]
        else:
            out.append("problems: none")
        if self.notes:
            out.append("notes")
            out += [f"  - {n}" for n in self.notes]
        return "\n".join(out)


def check_rig(rig: RigConfig) -> RigCheck:
    """Every problem (and note) of ``rig`` that can be found before anything moves (see the
    module docstring)."""
    budgets = bus_budgets(rig)
    problems: list[str] = []
    notes: list[str] = []
    problems += [p for p in (b.problem() for b in budgets) if p]
    problems += _bus_problems(rig)
    notes += [f"bus {b.bus.name} carries no channel" for b in budgets if not b.channels]
    verdict = judge_structure(rig)
    if rig.G is None:
        notes.append("no structure given ([structure] G, or K with flow_gain_mm_per_pct_s, or a "
                     "plant for every channel): the channels are taken as uncoupled")
    else:
        if verdict.reason:
            problems.append(f"the structure (from {rig.structure_from}) is not one a structure "
                            f"can give: {verdict.reason}")
        notes += _dominance_notes(rig)
    problems += _plant_problems(rig)
    missing = [c.name for c in rig.channels if c.plant is None]
    if missing and len(missing) < len(rig.channels):
        notes.append(f"channel(s) {', '.join(missing)} have no emulated plant: `stand emulate "
                     "--rig` needs one for every channel")
    return RigCheck(rig, budgets, verdict, problems, notes)


def _bus_problems(rig: RigConfig) -> list[str]:
    out = []
    known = set(known_interfaces())
    seen: dict[tuple[str, str | None], str] = {}
    for bus in rig.buses:
        spec = BusSpec.parse(bus.spec)
        key = (spec.interface, spec.channel)
        if key in seen:
            out.append(f"buses {seen[key]} and {bus.name} are the same python-can bus "
                       f"({spec.interface}:{spec.channel}): their frames would meet on one bus "
                       "and the budget counts two; give each bus its own spec")
        else:
            seen[key] = bus.name
        if spec.interface not in known:
            out.append(f"bus {bus.name}: python-can knows no interface {spec.interface!r} here "
                       f"(known: {', '.join(sorted(known))})")
        out += _option_conflicts(bus.name, spec, {"bitrate": bus.bitrate, "fd": bus.fd,
                                                  "data_bitrate": bus.data_bitrate})
    return out


def _option_conflicts(name: str, spec: BusSpec, rig_says: dict[str, Any]) -> list[str]:
    """A spec option (what the bus is opened with) that contradicts the rig file's word (what
    the budget counts)."""
    out = []
    for key, value in rig_says.items():
        if key not in spec.options:
            continue
        given = spec.options[key]
        same = (bool(given) == bool(value)) if key == "fd" else (
            value is not None and isinstance(given, (int, float)) and float(given) == float(value))
        if not same:
            out.append(f"bus {name}: its spec opens it with {key}={given} but the rig file says "
                       f"{key} = {value}: the budget counts the rig file's; make them agree")
    return out


def _dominance_notes(rig: RigConfig) -> list[str]:
    G = np.asarray(rig.G, float)
    off = np.abs(G).sum(axis=1) - np.abs(np.diag(G))
    weak = [n for n, d, o in zip(rig.names, np.diag(G), off) if o >= abs(d)]
    if not weak:
        return []
    return [f"G is not diagonally dominant for {', '.join(weak)} (the others' flows move their "
            "force as much as their own): one PI per channel is not the easy case; decouple "
            "through G⁻¹"]


def _plant_problems(rig: RigConfig) -> list[str]:
    out = []
    for c in rig.channels:
        conflict = sensor_range_conflict(c)
        if conflict:
            out.append(conflict)
        if c.plant is not None and abs(c.plant.initial_force_kgf) > c.limit_kgf:
            out.append(f"channel {c.name}: its plant starts at {c.plant.initial_force_kgf:g} kgf, "
                       f"beyond its force limit {c.limit_kgf:g} kgf: the supervisor would stop "
                       "the first cycle")
    return out


def _rate(bits_s: float) -> str:
    if bits_s >= 1e6 and math.isclose(bits_s % 1e6, 0.0, abs_tol=1.0):
        return f"{bits_s / 1e6:g} Mbit/s"
    return f"{bits_s / 1e3:g} kbit/s"


def _table(rows: list[tuple[str, ...]], right: set[int] = frozenset()) -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return ["  " + "  ".join(cell.rjust(w) if i in right else cell.ljust(w)
                             for i, (cell, w) in enumerate(zip(row, widths))).rstrip()
            for row in rows]
