"""Model-discrepancy workbench: compare the ST model with a drive log, see where it fails,
learn which physical effect is missing, add it and watch the held-out error fall.

Python API::

    from pcvfe_drake.workbench import load, diagnose, WorkbenchModel

    data = load("drive.csv")                      # validated drive log
    report, wb = diagnose(data, add=["drag"])     # ranking + before/after (JSON-ready dict)
    model = WorkbenchModel("ford_escort").with_effects("drag", "steering_lag")
    result = wb.fit_model(model)                  # fit any composed model on the training split

See ``docs/workbench.md``.
"""

from pcvfe_drake.models.data import DriveData, load, prepare
from pcvfe_drake.models.effects import (
    Effect,
    EffectParam,
    StepContext,
    get_effect,
    known_effects,
    register_effect,
)
from pcvfe_drake.models.model import WorkbenchModel
from pcvfe_drake.workbench.ranking import DiagnoseConfig, Workbench
from pcvfe_drake.workbench.report import diagnose, write_report

__all__ = [
    "DiagnoseConfig",
    "DriveData",
    "Effect",
    "EffectParam",
    "StepContext",
    "Workbench",
    "WorkbenchModel",
    "diagnose",
    "get_effect",
    "known_effects",
    "load",
    "prepare",
    "register_effect",
    "write_report",
]
