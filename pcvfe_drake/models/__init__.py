"""The vehicle model shared by the context fitter and the workbench: the single-track model with
effects (:class:`~pcvfe_drake.models.model.WorkbenchModel`), the effect library (importing this
package registers every shipped effect), the least-squares core, the data windows a fit runs on
(:class:`~pcvfe_drake.models.data.DriveData`) and synthetic drives with a planted truth.

``pcvfe_drake.estimation`` (live friction fitting) and ``pcvfe_drake.workbench`` (diagnosis) both
build on this package; neither imports the other.
"""

from pcvfe_drake.models import (  # noqa: F401  (registers them)
    chassis_effects,
    sensor_effects,
    tyre_effects,
)
