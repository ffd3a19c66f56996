"""Expensive test data made once per test run: drive logs and their diagnoses.

A diagnosis of a 90 s log costs seconds of CPU; a module fixture that made them all at once
made every worker of a parallel run (``pytest -n``) pay for all of them. :class:`LazyDiagnoses`
makes a diagnosis only when a test reads it, and :func:`shared` (the ``run_cache`` fixture of
``conftest.py``) lets the workers of one run share what one of them made: the tests of one
module are spread over the workers, and each would otherwise remake the module's logs and the
diagnoses that several of its tests read."""

from __future__ import annotations

import fcntl
import pickle
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pcvfe_drake.models.data import prepare
from pcvfe_drake.workbench.report import diagnose


def shared(folder: Path | None, key: str, make: Callable[[], Any]) -> Any:
    """``make()``, made once per test run: the first worker to ask makes it and pickles it to
    ``folder/key.pkl`` while holding a lock on ``folder/key.lock``; a worker that asks later
    (or meanwhile: it waits for the lock) reads the file. ``folder`` None: just ``make()``.
    ``key`` must name everything ``make`` depends on (module and arguments)."""
    if folder is None:
        return make()
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{key}.pkl"
    with open(folder / f"{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if path.exists():
            return pickle.loads(path.read_bytes())
        value = make()
        tmp = path.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps(value))
        tmp.replace(path)
        return value


class LazyDiagnoses(dict):
    """``name -> diagnose(prepare(logs[name], name))[0]``, made on first access (once per run
    when given the ``run_cache`` folder and a ``prefix`` naming the logs)."""

    def __init__(self, logs: dict, folder: Path | None = None, prefix: str = ""):
        super().__init__()
        self.logs = logs
        self.folder = folder
        self.prefix = prefix

    def __missing__(self, name: str) -> dict:
        def make() -> dict:
            return diagnose(prepare(self.logs[name], name))[0]

        report = self[name] = shared(self.folder, f"{self.prefix}report-{name}", make)
        return report
