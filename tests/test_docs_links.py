"""README.md and docs/ read as reference: links resolve, no commit hashes, a short README.

A relative link that points nowhere sends a reader to a 404; a commit hash in reference text
dates it to one moment of the history (the history is in CHANGELOG.md and studies/); a README
longer than a few screens is not read.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [
    ROOT / "README.md",
    ROOT / "benchmarks" / "README.md",
    ROOT / "validation" / "README.md",
    *sorted((ROOT / "docs").glob("*.md")),
]
"""Reference pages: links resolve and no commit hash."""
NOTES = [ROOT / "CHANGELOG.md", *sorted((ROOT / "studies").rglob("*.md"))]
"""History and studies: links resolve (hashes are part of their record)."""
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
HASH = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b")
README_MAX_LINES = 220
DOC_MAX_LINES = 500
"""A docs page is reference text; one much over 500 lines holds a study (move it to studies/)."""


def relative_links(text: str) -> list[str]:
    """Targets of the Markdown links and images of ``text`` that are paths in this repository
    (no scheme, no pure anchor), without their ``#anchor``."""
    out = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue
        out.append(target.split("#", 1)[0])
    return out


@pytest.mark.parametrize("page", PAGES + NOTES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    missing = [t for t in relative_links(page.read_text()) if not (page.parent / t).exists()]
    assert not missing, f"{page.relative_to(ROOT)}: links to missing files {missing}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_commit_hash(page):
    found = HASH.findall(page.read_text())
    assert not found, f"{page.relative_to(ROOT)}: commit hashes {found} (history: CHANGELOG.md)"


def test_readme_is_short():
    n = len((ROOT / "README.md").read_text().splitlines())
    assert n <= README_MAX_LINES, f"README.md has {n} lines (at most {README_MAX_LINES})"


@pytest.mark.parametrize("page", sorted((ROOT / "docs").glob("*.md")), ids=lambda p: p.name)
def test_docs_pages_are_reference_sized(page):
    n = len(page.read_text(encoding="utf-8").splitlines())
    assert n <= DOC_MAX_LINES, f"{page.name} has {n} lines: move its investigations to studies/"


def test_the_checks_of_this_file():
    assert relative_links("[a](docs/x.md#y) ![b](fig.png) [c](https://x.org) [d](#e)") == [
        "docs/x.md",
        "fig.png",
    ]
    assert HASH.findall("main at 0949dac, 12 seeds, 0985046305, abcdefab") == ["0949dac"]
