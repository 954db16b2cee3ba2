"""Every effect parameter's ``source`` is something a reader can open: a paper, a datasheet,
a measurement file, or a page of this repository that exists; our own guesses say "estimate"
(issue 20). ``list effects`` prints these strings."""

from __future__ import annotations

import re
from pathlib import Path

from tactile_bench.effects import EFFECTS

ROOT = Path(__file__).resolve().parents[1]
#: design briefs and notes that never ship: a user cannot open them
UNSHIPPED = re.compile(r"\bDESIGN(\.md)?\b|\bbrief\b|\bnotes?\.md\b", re.IGNORECASE)


def _sources() -> dict[str, str]:
    return {f"{name}.{q.name}": q.source for name, e in EFFECTS.items() for q in e.params}


def test_no_source_cites_a_document_that_does_not_ship() -> None:
    bad = {where: src for where, src in _sources().items() if UNSHIPPED.search(src)}
    assert not bad, bad


def test_every_markdown_page_a_source_cites_is_in_the_repository() -> None:
    cited = {
        page
        for src in _sources().values()
        for page in re.findall(r"[\w./-]+\.md\b", src)
        if not page.startswith("../")  # ../shared/...: measurement files beside the checkout
    }
    missing = sorted(page for page in cited if not (ROOT / page).is_file())
    assert not missing, missing


def test_every_source_says_something() -> None:
    short = {where: src for where, src in _sources().items() if len(src.split()) < 2}
    assert not short, short
