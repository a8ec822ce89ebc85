"""What a documented block printed, against the output the page shows after it.

The shown lines must be printed in that order, one after the other, anywhere in what the block
printed (other lines may come before and after). A line ``...`` stands for any number of printed
lines, ``...`` inside a line for any text. Whitespace runs are one space and blank lines are
left out. Each number must be within the tolerance of the one shown (a figure comes from one
run: seeds and hosts differ; :class:`~tests.support.docblocks.Tolerance`); the text around the
numbers must be the same.
"""
from __future__ import annotations

import difflib
import re
from dataclasses import dataclass

from tests.support.docblocks import Tolerance

ELLIPSIS = "..."
#: a number as the commands print it: a sign, thousands grouped with commas, decimals, exponent;
#: not the digits of a word (can0, u0, 0x1006's x1006)
NUMBER = r"[-+]?(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?:[eE][-+]?\d+)?"
_PIECE = re.compile(rf"(?P<ellipsis>\.\.\.)|(?<![\w.])(?P<number>{NUMBER})")


def normalize(line: str) -> str:
    return " ".join(line.replace("\u2212", "-").split())


@dataclass(frozen=True)
class ShownLine:
    """A shown line as a pattern: its text exact, each number captured, ``...`` any text."""

    text: str
    pattern: re.Pattern
    numbers: tuple[tuple[float, int], ...]     # (value, decimals shown)

    @classmethod
    def parse(cls, line: str) -> "ShownLine":
        text = normalize(line)
        regex, numbers, pos = [], [], 0
        for m in _PIECE.finditer(text):
            regex.append(_literal(text[pos:m.start()]))
            if m["ellipsis"]:
                regex.append(".*?")
            else:
                regex.append(f"({NUMBER})")
                numbers.append((_value(m["number"]), _decimals(m["number"])))
            pos = m.end()
        regex.append(_literal(text[pos:]))
        return cls(text, re.compile("".join(regex)), tuple(numbers))

    def mismatch(self, printed: str, tolerance: Tolerance) -> str | None:
        """Why ``printed`` is not this line (None: it is)."""
        m = self.pattern.fullmatch(normalize(printed))
        if m is None:
            return "the text differs"
        for (shown, decimals), got in zip(self.numbers, (_value(g) for g in m.groups())):
            if not tolerance.allows(shown, got, decimals):
                return f"{got:g} is off the shown {shown:g} by more than {tolerance}"
        return None


def _literal(text: str) -> str:
    return re.escape(text).replace(r"\ ", r"\s+")


def _value(number: str) -> float:
    return float(number.replace(",", ""))


def _decimals(number: str) -> int:
    mantissa = re.split("[eE]", number)[0]
    return len(mantissa.partition(".")[2])


def compare(shown: str, printed: str, tolerance: Tolerance) -> str | None:
    """None when ``printed`` holds ``shown`` (module doc), else what differs, with context."""
    out = [line for line in printed.splitlines() if line.strip()]
    segments: list[list[ShownLine]] = [[]]
    for line in shown.splitlines():
        if line.strip() == ELLIPSIS:
            segments.append([])
        elif line.strip():
            segments[-1].append(ShownLine.parse(line))
    at = 0
    for segment in (s for s in segments if s):
        found = _find(segment, out, at, tolerance)
        if found is None:
            return _explain(segment, out, at, tolerance)
        at = found + len(segment)
    return None


def _find(segment: list[ShownLine], out: list[str], start: int, tolerance: Tolerance) -> int | None:
    for i in range(start, len(out) - len(segment) + 1):
        if all(s.mismatch(out[i + k], tolerance) is None for k, s in enumerate(segment)):
            return i
    return None


def _explain(segment: list[ShownLine], out: list[str], start: int, tolerance: Tolerance) -> str:
    """The printed lines that come nearest the segment, and the first shown line they miss."""
    best, best_score = start, -1.0
    for i in range(start, max(start + 1, len(out) - len(segment) + 1)):
        score = 0.0
        for k, s in enumerate(segment):
            if i + k >= len(out):
                break
            score += 1.0 if s.mismatch(out[i + k], tolerance) is None else \
                difflib.SequenceMatcher(None, s.text, normalize(out[i + k])).ratio() * 0.9
        if score > best_score:
            best, best_score = i, score
    lines = [f"the printed output does not show these lines in order (numbers within {tolerance}):"]
    for k, s in enumerate(segment):
        got = out[best + k] if best + k < len(out) else None
        why = "nothing printed here" if got is None else s.mismatch(got, tolerance)
        lines.append(f"  shown:   {s.text}")
        lines.append(f"  printed: {normalize(got) if got is not None else ''}"
                     + (f"    <- {why}" if why else ""))
    if start:
        lines.append(f"(looked from printed line {start + 1} on, after the lines matched before)")
    return "\n".join(lines)
