"""The how-to pages read easily (issue 51): no paragraph over 150 words, a median sentence of
22 words at most, and all of them together no longer than half the lines they had when the
issue was filed (4,130). The generated reference, decisions.md (what was tried and why) and
benchmarks.md (what was measured) are not how-to pages. How it counts: tests/support/prose.py."""
from __future__ import annotations

import statistics
from pathlib import Path

import pytest

from tests.support.prose import count_words, read

ROOT = Path(__file__).resolve().parents[1]
NOT_HOW_TO = {"decisions.md", "benchmarks.md"}
PAGES = sorted(p for p in (ROOT / "docs").glob("*.md") if p.name not in NOT_HOW_TO)
MAX_PARAGRAPH_WORDS = 150
MAX_MEDIAN_SENTENCE_WORDS = 22
#: the how-to pages' lines when issue 51 was filed (docs/*.md less decisions.md, benchmarks.md)
LINES_WHEN_FILED = 4130


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_no_paragraph_is_over_150_words(page):
    long = [(count_words(p), p[:80]) for p in read(page).paragraphs if count_words(p) > MAX_PARAGRAPH_WORDS]
    assert not long, f"{page.name}: paragraphs over {MAX_PARAGRAPH_WORDS} words: {long}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_sentences_are_short(page):
    median = read(page).median_sentence
    assert median <= MAX_MEDIAN_SENTENCE_WORDS, f"{page.name}: median sentence {median:g} words"


def test_the_how_to_pages_are_half_as_long_as_they_were():
    lines = sum(read(p).lines for p in PAGES)
    words = [n for p in PAGES for n in read(p).sentences]
    assert statistics.median(words) <= MAX_MEDIAN_SENTENCE_WORDS
    assert lines <= LINES_WHEN_FILED // 2, f"{lines} lines in {len(PAGES)} pages"
