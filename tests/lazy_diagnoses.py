"""Diagnoses of named drive logs, each made the first time a test reads it.

A diagnosis of a 90 s log costs seconds of CPU; a module fixture that made them all at once
made every worker of a parallel run (``pytest -n``) pay for all of them. With this mapping a
worker makes only those its own tests read, and a serial run makes each one once, as before."""

from __future__ import annotations

from pcvfe_drake.models.data import prepare
from pcvfe_drake.workbench.report import diagnose


class LazyDiagnoses(dict):
    """``name -> diagnose(prepare(logs[name], name))[0]``, made on first access."""

    def __init__(self, logs: dict):
        super().__init__()
        self.logs = logs

    def __missing__(self, name: str) -> dict:
        report = self[name] = diagnose(prepare(self.logs[name], name))[0]
        return report
