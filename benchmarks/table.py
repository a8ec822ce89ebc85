"""One row of the benchmark table and its printing."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Row:
    benchmark: str
    figure: str            #: what we measured, with units
    reference: str = ""    #: the alternative / target beside it
    ratio: str = ""        #: figure relative to the reference, when meaningful
    note: str = ""


def format_table(rows: list[Row]) -> str:
    head = ("benchmark", "measured", "reference / target", "ratio", "note")
    data = [head] + [(r.benchmark, r.figure, r.reference, r.ratio, r.note) for r in rows]
    widths = [max(len(str(row[i])) for row in data) for i in range(len(head))]
    line = lambda row: "| " + " | ".join(str(c).ljust(w) for c, w in zip(row, widths)) + " |"
    sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    return "\n".join([line(head), sep] + [line(r) for r in data[1:]])
