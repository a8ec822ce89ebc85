"""How readable a documentation page's prose is: its paragraphs, sentences and words, counted
the same way every time (issue 51's measures; tests/test_docs_prose.py holds them).

What counts as prose: the text outside fenced code blocks, HTML comments, tables and headings.
A paragraph is a run of non-blank lines; a list item (``* ``, ``- ``, ``1. ``) starts one of its
own. A sentence ends at ``.``, ``!`` or ``?`` followed by a space (or the paragraph's end), not
inside ``e.g.``, ``i.e.``, ``cf.``, ``vs.``, ``etc.`` nor a number (``0.5``). Words are runs of
letters, digits and ``_``/``-``/``'`` (a unit, a figure, an option each one word); inline code
counts as one word.
"""
from __future__ import annotations

import re
import statistics
from dataclasses import dataclass
from pathlib import Path

_FENCE = re.compile(r"^\s*(```|~~~)")
_ITEM = re.compile(r"^\s*(?:[*+-]|\d+\.)\s+")
_ABBREV = re.compile(r"\b(?:e\.g|i\.e|cf|vs|etc|approx|incl|resp)\.", re.IGNORECASE)
_CODE = re.compile(r"`[^`]*`")
_LINK = re.compile(r"\[([^\]]*)\]\([^)]*\)")
_WORD = re.compile(r"[\w][\w'’\-/.,%×·°µ]*")
_END = re.compile(r"(?<=[.!?])\s+")


@dataclass(frozen=True)
class Prose:
    path: Path
    lines: int
    paragraphs: list[str]
    sentences: list[int]               #: words per sentence

    @property
    def longest_paragraph(self) -> tuple[int, str]:
        words = [(count_words(p), p) for p in self.paragraphs]
        return max(words, default=(0, ""))

    @property
    def median_sentence(self) -> float:
        return statistics.median(self.sentences) if self.sentences else 0.0


def count_words(text: str) -> int:
    text = _CODE.sub(" code ", _LINK.sub(r"\1", text))
    return len(_WORD.findall(text))


def sentences(paragraph: str) -> list[str]:
    text = _ABBREV.sub(lambda m: m.group(0).replace(".", ""), _CODE.sub("code", paragraph))
    return [s for s in _END.split(text.strip()) if count_words(s)]


def paragraphs(text: str) -> list[str]:
    out, current, fenced, comment = [], [], False, False
    for line in text.splitlines():
        if _FENCE.match(line):
            fenced = not fenced
            continue
        if fenced:
            continue
        if "<!--" in line:
            comment = "-->" not in line
            continue
        if comment:
            comment = "-->" not in line
            continue
        bare = line.strip()
        if not bare or bare.startswith(("#", "|")):
            if current:
                out.append(" ".join(current))
            current = []
            continue
        if _ITEM.match(line) and current:
            out.append(" ".join(current))
            current = []
        current.append(_ITEM.sub("", bare, count=1))
    if current:
        out.append(" ".join(current))
    return [p for p in out if count_words(p)]


def read(path: Path) -> Prose:
    text = path.read_text(encoding="utf-8")
    paras = paragraphs(text)
    return Prose(path, len(text.splitlines()), paras,
                 [count_words(s) for p in paras for s in sentences(p)])
