"""The handing's settings: a small tree of dataclasses with tagged variants (no pydrake).

In a scenario file (``fitter.handing``)::

    handing:
      floor_mu: 0.3                 # the operator's guess of the course's lowest friction
      unknown: !StatedFloor {}      # or !Conservative {sigmas: 2.0}, !Prior {}, !LastKnown {}
      unidentified: !Probe {}       # or !LowerBound {}, !Estimate {}
      confirm_rise_s: 1.0
      noise_hold_s: 1.0

The variants are ``typing.Union`` alternatives of dataclasses, tagged with the class name, the
way ``pydrake.common.yaml.yaml_load_typed`` reads Drake's scenario files. Every other number of
the rules is derived (from the planner's share of mu, passed in when the diagram is built) or a
module constant with its reason (``docs/handing.md``).

This module does not use ``from __future__ import annotations``: ``yaml_load_typed`` reads the
field types.
"""

import math
from dataclasses import dataclass, field


@dataclass
class Conservative:
    """The unknown context gets the lowest lower confidence bound ``mu - sigmas * std`` over the
    contexts fitted so far (a friction peak never below the friction its data used), at most
    ``floor_mu``: the floor is a ceiling here, not a promise."""

    sigmas: float = 2.0


@dataclass
class StatedFloor:
    """The unknown context gets ``floor_mu``, the operator's stated lowest friction, or less where
    a context was identified below it (the floor is a guess; a measured lower friction wins).
    The data driven on a new terrain before its id then count as a level tried at the floor, so
    the probe can take its first step on them, and the unknown value itself is probed one step."""


@dataclass
class Prior:
    """The unknown context gets the prior theta (optimistic on a low-friction world)."""


@dataclass
class LastKnown:
    """The unknown context gets the last fitted context's theta (wrong by the whole step after a
    transition)."""


@dataclass
class Estimate:
    """A context whose peak is not identifiable is handed its fit as it is."""


@dataclass
class LowerBound:
    """A context whose peak is not identifiable is handed the friction its data used, at least
    the floor and at most its fit."""


@dataclass
class Probe:
    """A context whose peak is not identifiable is explored (``pcvfe_drake.estimation.probe``):
    handed a level above the friction used, raised while its bends show no saturation, backed
    off at the first sign of it.

    Attributes:
        max_excess: the planner is never asked for more than this much more friction than the
            car has demonstrated on the context (about one step on a 0.45 terrain).
        fast_step_rel: the largest relative raise of one step, to the peak a level's bend
            implies.
        hold_s: the least time [s] a level is held before the next raise: long enough to drive
            a bend at it (``docs/handing.md``).
    """

    max_excess: float = 0.12
    fast_step_rel: float = 0.4
    hold_s: float = 3.0


UnknownPolicy = StatedFloor | Conservative | Prior | LastKnown
UnidentifiedPolicy = Probe | LowerBound | Estimate


@dataclass
class HandingConfig:
    """What the controller gets (``pcvfe_drake.handing.handing.Handing``).

    Attributes:
        floor_mu: the lowest friction expected on the course (an operator's guess): the
            unknown context's value (``unknown``) and where exploration starts.
        unknown: what the controller gets while the terrain is unknown (a noise frame, or a
            context with no fit yet).
        unidentified: what a fitted context whose friction peak is not identifiable gets.
        confirm_rise_s: a switch to a context with more friction waits until the new context
            has been seen this long [s] (less friction is always taken at once).
        noise_hold_s: how long [s] a noise frame may keep the last context's theta where that
            has less friction than the unknown value (more friction is never held).
    """

    floor_mu: float = 0.3
    unknown: UnknownPolicy = field(default_factory=Conservative)
    unidentified: UnidentifiedPolicy = field(default_factory=Estimate)
    confirm_rise_s: float = 1.0
    noise_hold_s: float = 1.0

    def __post_init__(self) -> None:
        where = "HandingConfig"
        _positive(self.floor_mu, f"{where}.floor_mu")
        for name in ("confirm_rise_s", "noise_hold_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{where}.{name} must be a number of seconds >= 0, got {value!r}")
        if not isinstance(self.unknown, UnknownPolicy.__args__):
            raise ValueError(
                f"{where}.unknown must be one of !StatedFloor, !Conservative, !Prior, "
                f"!LastKnown, got {self.unknown!r}"
            )
        if not isinstance(self.unidentified, UnidentifiedPolicy.__args__):
            raise ValueError(
                f"{where}.unidentified must be one of !Probe, !LowerBound, !Estimate, got "
                f"{self.unidentified!r}"
            )
        if isinstance(self.unknown, Conservative):
            sigmas = self.unknown.sigmas
            if not (math.isfinite(sigmas) and sigmas >= 0):
                raise ValueError(f"{where}.unknown.sigmas must be >= 0, got {sigmas!r}")
        if isinstance(self.unidentified, Probe):
            for name in ("max_excess", "fast_step_rel", "hold_s"):
                _positive(getattr(self.unidentified, name), f"{where}.unidentified.{name}")

    @property
    def probing(self) -> bool:
        return isinstance(self.unidentified, Probe)

    @property
    def floor_stated(self) -> bool:
        return isinstance(self.unknown, StatedFloor)


_DERIVED = "derived from the planner's share of mu or a constant (docs/handing.md)"
FLAT_FIELDS: dict[str, str] = {
    "noise_hold_s": "handing.noise_hold_s",
    "rise_confirm_s": "handing.confirm_rise_s",
    "unknown_context": "handing.unknown (!Conservative, !StatedFloor, !Prior, !LastKnown)",
    "unknown_floor_mu": "handing.floor_mu",
    "unknown_floor_stated": "handing.unknown: !StatedFloor {}",
    "unknown_sigmas": "handing.unknown: !Conservative {sigmas: ...}",
    "unknown_keeps_stiffness": "the behaviour (the small-slip stiffness is always kept)",
    "unidentified_mu": "handing.unidentified (!Probe, !LowerBound, !Estimate)",
    "probe_max_excess": "handing.unidentified: !Probe {max_excess: ...}",
    "probe_fast_step_rel": "handing.unidentified: !Probe {fast_step_rel: ...}",
    "probe_hold_s": "handing.unidentified: !Probe {hold_s: ...}",
    "probe_use_fraction": "the NMPC's speed_margin^2, passed in when the diagram is built",
    "probe_start_evidence": "the behaviour with handing.unknown: !StatedFloor {}",
    "probe_unknown": "the behaviour with handing.unknown: !StatedFloor {}",
    "probe_fit_target": "the behaviour of !Probe",
    "probe_min_force": "evidence relative to the level tried (docs/handing.md)",
    **dict.fromkeys(
        (
            "probe_step_rel",
            "probe_slip_fraction",
            "probe_window_s",
            "probe_linear_ratio",
            "probe_bend_limit",
            "probe_bend_margin",
        ),
        _DERIVED,
    ),
}
"""The flat ``LiveFitConfig`` fields the handing replaced, and where each went (a scenario that
names one gets this in its error)."""


def _positive(value, where: str) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise ValueError(f"{where} must be > 0, got {value!r}")
