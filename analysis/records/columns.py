"""Which column of a table is which signal, and in which unit.

A recording from another logger rarely says ``t,u,y``: it says ``time [ms]``, ``force_N``,
``command (%)`` or nothing at all. :func:`map_header` finds the time, valve command, force
and (optional) reference columns by name, reads a unit written after the name (``name [unit]``,
``name (unit)``, ``name_unit``, ``name/unit``, ``name unit``, ``name, unit``) and gives the
factor that converts it to the analysis's units: s, % of the valve's full command, kgf.
Names and units are known in English, Russian (``Время, с``, ``Усилие, кгс``,
``Управление, %``: the language of the stand's paper and its labs) and German (``Zeit [ms]``,
``Kraft [kN]``).

Columns it does not recognise are ignored (a logger's extra channels). A column that names
a signal in a unit it does not know is not guessed at: if that signal has no other column,
the error names the column and the units it knows.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

#: standard gravity: 1 kgf = 9.80665 N
G0 = 9.80665

_FORCE_UNITS = {"kgf": 1.0, "kp": 1.0, "N": 1.0 / G0, "daN": 10.0 / G0, "kN": 1000.0 / G0,
                "tf": 1000.0,
                # as Russian logs write them (the stand's paper, its users)
                "кгс": 1.0, "Н": 1.0 / G0, "даН": 10.0 / G0, "кН": 1000.0 / G0, "тс": 1000.0}

#: signal -> (what it is, the names it goes by, unit -> factor to the analysis's unit);
#: the first unit is the analysis's own
SIGNALS: dict[str, tuple[str, tuple[str, ...], dict[str, float]]] = {
    "t": ("time", ("t", "time", "time_s", "время", "zeit"),
          {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "min": 60.0,
           "с": 1.0, "сек": 1.0, "мс": 1e-3, "мкс": 1e-6, "мин": 60.0}),
    "u": ("valve command", ("u", "cmd", "command", "valve", "valve_command", "valve_cmd",
                            "valve_drive", "drive", "spool_command",
                            "управление", "команда", "сигнал_управления", "управляющий_сигнал",
                            "ventil", "stellsignal", "ventilsignal"),
          # the valve's command voltage: ±10 V is ±100 % of the full command
          {"%": 1.0, "pct": 1.0, "percent": 1.0, "V": 10.0, "mV": 0.01, "В": 10.0, "мВ": 0.01}),
    "y": ("force", ("y", "force", "load", "force_measured", "measured_force",
                    "усилие", "сила", "нагрузка", "измеренное_усилие", "kraft"),
          _FORCE_UNITS),
    "r": ("force reference", ("r", "ref", "reference", "setpoint", "demand", "target",
                              "задание", "уставка", "заданное_усилие", "программа",
                              "sollwert", "sollkraft"),
          _FORCE_UNITS),
}

REQUIRED = ("t", "u", "y")

# a name of letters (any script), '_' and blanks; then a unit in brackets or after '_', '/',
# ',', a blank or ' in ' ("Время, с" as Russian logs write it)
_CELL = re.compile(r"^(?P<name>(?:[^\W\d]| )*?[^\W\d_])\s*"
                   r"(?:[\[(]\s*(?P<bracketed>[^\])]*?)\s*[\])]|(?:[_ /,]+|\s+in\s+)(?P<suffix>(?:[^\W\d_]|%)+))?$")


class ColumnError(ValueError):
    """The header does not say where t, u and y are; the message says what to write."""


@dataclass(frozen=True)
class Column:
    """One signal's column: its position, its header text and the factor to s, % or kgf."""
    index: int
    header: str
    scale: float
    unit: str


def _parse(cell: str) -> tuple[str, str | None]:
    """``'Force [kN]'`` -> ``('force', 'kn')``; a cell that is a bare name -> ``(name, None)``."""
    text = cell.strip().lstrip("\ufeff").strip('"').strip().lower()
    if text.endswith("%") and not re.search(r"[\[(]", text):
        text = text[:-1].rstrip(" _") + " %"
    m = _CELL.match(text)
    if m is None:
        return text, None
    unit = m.group("bracketed") or m.group("suffix")
    return m.group("name").strip().replace(" ", "_"), unit


def _lookup(name: str, unit: str | None) -> tuple[str | None, str | None]:
    """The signal a parsed cell names and the unit written (None: none), or ``(None, None)``.
    A whole name comes first: ``valve_command`` is the command, not a valve in "command"."""
    for signal, (_, names, _) in SIGNALS.items():
        if unit is not None and f"{name}_{unit}" in names:
            return signal, None
    for signal, (_, names, _) in SIGNALS.items():
        if name in names:
            return signal, unit
    return None, None


def written_unit(cell: str) -> str | None:
    """The unit a header cell writes after a signal's name (None: none, or not a signal)."""
    return _lookup(*_parse(cell))[1]


def map_header(header: list[str]) -> tuple[dict[str, Column], list[str]]:
    """The columns of t, u, y and (if present) r in ``header``, and notes on any conversion.

    Raises :class:`ColumnError` if t, u or y cannot be found, or is found twice."""
    found: dict[str, list[Column]] = {}
    unknown_units: dict[str, list[str]] = {}
    for index, cell in enumerate(header):
        name, unit = _parse(cell)
        signal, unit = _lookup(name, unit)
        if signal is None:
            continue
        units = SIGNALS[signal][2]
        spelled = next(iter(units)) if unit is None else {k.lower(): k for k in units}.get(unit)
        if spelled is None:
            unknown_units.setdefault(signal, []).append(cell.strip())
            continue
        found.setdefault(signal, []).append(Column(index, cell.strip(), units[spelled], spelled))
    problems = []
    for signal in SIGNALS:
        what, names, units = SIGNALS[signal]
        cols = found.get(signal, [])
        if len(cols) > 1:
            problems.append(f"{what} is in {len(cols)} columns ({', '.join(c.header for c in cols)}); "
                            "keep one")
        elif not cols and signal in REQUIRED:
            hint = (f"column {', '.join(repr(c) for c in unknown_units[signal])} is in a unit "
                    f"not known for the {what} (known: {', '.join(units)})"
                    if signal in unknown_units else
                    f"name it {' or '.join(repr(n) for n in names[:3])}")
            problems.append(f"no {what} column: {hint}")
    if problems:
        raise ColumnError("; ".join(problems) + f" (header: {','.join(h.strip() for h in header)}). "
                          "Expected columns t,u,y[,r] in s, % of the full valve command, kgf; "
                          "a unit may follow the name, as in 'time [ms]' or 'force_N'")
    columns = {s: cols[0] for s, cols in found.items()}
    notes = [f"column {c.header!r} read as {SIGNALS[s][0]} in {c.unit} "
             f"(× {c.scale:.6g} to {next(iter(SIGNALS[s][2]))})"
             for s, c in columns.items() if c.scale != 1.0]
    return columns, notes


def positional(n_columns: int) -> dict[str, Column]:
    """A table without a header: its columns are t, u, y[, r] in that order (s, %, kgf)."""
    if n_columns not in (3, 4):
        raise ColumnError(f"no header and {n_columns} columns: the columns cannot be told apart; "
                          "add a header line naming t,u,y[,r] (s, % of the full valve command, kgf)")
    return {s: Column(i, s, 1.0, next(iter(SIGNALS[s][2])))
            for i, s in enumerate(("t", "u", "y", "r")[:n_columns])}
