"""Fixtures shared by the whole test suite."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def run_cache(tmp_path_factory, request) -> Path | None:
    """A folder shared by the workers of one parallel run (``pytest -n``), for
    :func:`lazy_diagnoses.shared`; None in a serial run, where a module fixture is made once
    anyway. Each run gets a fresh folder (pytest's numbered base temp), so nothing is reused
    from an earlier run of other code."""
    worker = getattr(request.config, "workerinput", None)
    if worker is None:
        return None
    # the workers' base temps are folders of one run's base temp (pytest-xdist)
    return tmp_path_factory.getbasetemp().parent / "shared"
