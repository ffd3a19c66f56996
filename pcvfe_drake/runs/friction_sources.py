"""Scenario settings of the friction source that feeds the NMPC's ``theta_hat`` (no pydrake).

The scenario field ``estimator`` picks it (``pcvfe simulate SCENARIO --estimator X`` overrides):

==============  ==========================================================================
``pcvfe``       the PC-VFE pipeline: features, context clustering, per-context fitter of
                the vehicle's calibrated effect model (``fitter.model``; docs/vehicles.md)
``pcvfe_paper`` the same pipeline with the paper's fitter: the single-track model, no effects
                (reproduces the paper's method and shows what the effect model buys)
``oracle``      the true mu under the car (simulation only: the upper bound)
``fixed``       a constant mu: ``fixed.use`` picks ``conservative`` (``fixed.conservative_mu``)
                or ``nominal`` (``fixed.nominal_mu``, default the vehicle's mu: optimistic)
``lookup``      terrain class of the frame -> mu table (``lookup.*``; ``estimation.lookup``)
``ukf``         unscented Kalman filter, mu a random-walk state (``estimation.ukf``)
``kmpc``        the kinematic NMPC (``nmpc.model = ks``): no friction input; its speed profile
                uses ``fixed.nominal_mu`` (what a friction-unaware controller assumes)
==============  ==========================================================================

This module has no ``from __future__ import annotations``: the scenario loader reads the field
types of these dataclasses.
"""

import dataclasses
import math
from dataclasses import dataclass, field

PAPER_FITTER = "pcvfe_paper"
"""The PC-VFE source with the paper's single-track fitter (``Scenario.fit_config``)."""
ESTIMATORS = ("pcvfe", PAPER_FITTER, "oracle", "fixed", "lookup", "ukf", "kmpc")
"""Values of the scenario's ``estimator`` field (the friction source; ``kmpc``: the kinematic
controller without a friction input)."""
PCVFE_SOURCES = ("pcvfe", PAPER_FITTER)
"""The sources built from the camera's contexts and the context fitter."""
FIXED_CHOICES = ("conservative", "nominal")

PAPER_LOOKUP_CLASSES = [
    "brick",
    "gravel",
    "sand",
    "concrete",
    "dry_soil",
    "mud",
    "leaves",
    "snow",
    "asphalt",
    "cobblestone",
    "mulch",
]
"""Default labelled subset of the lookup table: every texture of the library except
``patchy_grass`` (grass mixed with straw and bare soil: the surface of the paper's map that a
generic surface table does not have)."""


@dataclass
class FixedFrictionSettings:
    """The ``fixed`` source (and the speed profile of ``kmpc``)."""

    use: str = "conservative"
    """``conservative`` or ``nominal``."""
    conservative_mu: float = 0.3
    """The lowest friction expected on the course (the paper map's patchy grass)."""
    nominal_mu: float | None = None
    """The optimistic nominal (None: the vehicle's mu, 1.05 for the Ford Escort)."""


@dataclass
class LookupSettings:
    """The ``lookup`` source's table (see ``pcvfe_drake.estimation.lookup``): its mu per class
    are the texture library's literature values, not the world's (nor a scenario's overrides)."""

    classes: list[str] = field(default_factory=lambda: list(PAPER_LOOKUP_CLASSES))
    """Labelled subset of the texture library: the classes the table knows."""
    default_mu: float | None = None
    """mu of frames the table does not know (None: the lowest mu in the table)."""
    frames_per_class: int = 40
    """Camera frames rendered per class to make its prototype."""
    reject_factor: float = 1.5
    """Rejection radius: this times the 99th percentile of a class's own distances."""


def fixed_mu(settings: FixedFrictionSettings, vehicle_mu: float) -> float:
    """The constant mu of the ``fixed`` source."""
    if settings.use == "nominal":
        return float(vehicle_mu if settings.nominal_mu is None else settings.nominal_mu)
    return float(settings.conservative_mu)


def _positive(value) -> bool:
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(value)
        and value > 0
    )


def friction_source_problems(estimator: str, fixed, lookup) -> list[str]:
    """Every invalid value of the friction-source fields, as ``"field=value: reason"``."""
    out = []
    if estimator not in ESTIMATORS:
        out.append(f"estimator={estimator!r}: must be one of {ESTIMATORS}")
    if fixed.use not in FIXED_CHOICES:
        out.append(f"fixed.use={fixed.use!r}: must be one of {FIXED_CHOICES}")
    if not _positive(fixed.conservative_mu):
        out.append(f"fixed.conservative_mu={fixed.conservative_mu!r}: must be > 0")
    if fixed.nominal_mu is not None and not _positive(fixed.nominal_mu):
        out.append(f"fixed.nominal_mu={fixed.nominal_mu!r}: must be > 0 or null")
    if not lookup.classes:
        out.append("lookup.classes=[]: name at least one texture")
    if lookup.default_mu is not None and not _positive(lookup.default_mu):
        out.append(f"lookup.default_mu={lookup.default_mu!r}: must be > 0 or null")
    if not (isinstance(lookup.frames_per_class, int) and lookup.frames_per_class >= 2):
        out.append(f"lookup.frames_per_class={lookup.frames_per_class!r}: must be >= 2")
    if not _positive(lookup.reject_factor):
        out.append(f"lookup.reject_factor={lookup.reject_factor!r}: must be > 0")
    return out


def apply_overrides(scenario, overrides: dict | None):
    """A copy of ``scenario`` with dotted fields replaced (``{"fixed.use": "nominal",
    "nmpc.max_speed_mps": 12.0, "seed": 3}``). Unknown fields raise ValueError naming them."""
    for dotted, value in (overrides or {}).items():
        scenario = _replace_dotted(scenario, dotted.split("."), value, dotted)
    return scenario


def _replace_dotted(obj, path: list[str], value, dotted: str):
    name = path[0]
    if not dataclasses.is_dataclass(obj) or name not in {f.name for f in dataclasses.fields(obj)}:
        raise ValueError(f"override {dotted!r}: no field {name!r} in {type(obj).__name__}")
    if len(path) == 1:
        return dataclasses.replace(obj, **{name: value})
    inner = _replace_dotted(getattr(obj, name), path[1:], value, dotted)
    return dataclasses.replace(obj, **{name: inner})
