"""Shipped scenario and experiment files are configs: a short header pointing to the docs."""

from __future__ import annotations

from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[1] / "pcvfe_drake" / "data"
FILES = sorted([*(DATA / "scenarios").rglob("*.yaml"), *(DATA / "experiments").rglob("*.yaml")])
MAX_BLOCK = 5


def comment_blocks(text: str) -> list[list[str]]:
    """Runs of consecutive whole-line comments."""
    blocks, run = [], []
    for line in text.splitlines():
        if line.lstrip().startswith("#"):
            run.append(line)
        elif run:
            blocks.append(run)
            run = []
    return blocks + ([run] if run else [])


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(DATA)))
def test_header_says_what_it_is_and_points_to_the_docs(path):
    text = path.read_text()
    assert text.startswith("#"), f"{path.name}: no header comment"
    header = comment_blocks(text)[0]
    assert len(header) <= MAX_BLOCK, f"{path.name}: header of {len(header)} lines"
    assert "docs/" in "\n".join(header), f"{path.name}: the header names no doc"
    long = [b for b in comment_blocks(text) if len(b) > MAX_BLOCK]
    assert not long, f"{path.name}: a comment block of {len(long[0])} lines"


DATA_FILES = sorted(p for p in DATA.rglob("*.yaml") if p not in FILES)


@pytest.mark.parametrize("path", DATA_FILES, ids=lambda p: str(p.relative_to(DATA)))
def test_other_shipped_data_files_hold_no_lab_notes(path):
    """Worlds, courses, vehicles and the rest: data, with at most a short comment."""
    long = [b for b in comment_blocks(path.read_text()) if len(b) > MAX_BLOCK]
    assert not long, f"{path.name}: a comment block of {len(long[0])} lines"
