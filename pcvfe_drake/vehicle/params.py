"""Vehicle parameters of the single-track (ST) model, with presets.

Units are SI throughout: masses in kg, lengths in m, angles in rad, rates in rad/s, speeds in m/s,
accelerations in m/s^2.

Friction parameters and identifiability
---------------------------------------
The ST model's friction parameters are theta = [mu, C_Sf, C_Sr] (in that order everywhere in this
project). ``C_Sf`` and ``C_Sr`` are *normalised* cornering stiffnesses [1/rad]: the lateral tire
force is ``F_y = mu * C_S * F_z * alpha``. In the ST equations mu appears only in the products
``mu * C_Sf`` and ``mu * C_Sr``, so (mu, C_Sf, C_Sr) = (1, 20, 25) and (0.5, 40, 50) produce
identical trajectories: from ST data alone only the two products are identifiable. The fitter
therefore fits mu with the stiffnesses held at their nominal values by default (the choice of the
public PC-VFE implementation); joint fits need priors on the stiffnesses.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pcvfe_drake.yaml_unique import load_unique

G_MPS2 = 9.81
"""Gravitational acceleration used by the CommonRoad models [m/s^2]."""

THETA_NAMES = ("mu", "C_Sf", "C_Sr")
TRUTH_MODELS = ("st", "mb")
"""Truth plant models: our single-track model (``single_track.py``), or CommonRoad's multi-body
model (``mb_truth.py``): the scenario's ``truth_model`` and ``VehiclePlant``'s ``truth``."""
"""Order of the friction parameter vector theta used everywhere in the project."""


PHYSICAL_RANGES: dict[str, tuple[float, float]] = {
    "m": (0.1, 1e5),
    "I_z": (1e-4, 1e7),
    "lf": (0.01, 10.0),
    "lr": (0.01, 10.0),
    "h": (0.0, 3.0),
    "mu": (0.01, 3.0),
    "C_Sf": (0.01, 100.0),
    "C_Sr": (0.01, 100.0),
    "delta_min": (-1.6, 0.0),
    "delta_max": (0.0, 1.6),
    "delta_dot_min": (-7.0, 0.0),
    "delta_dot_max": (0.0, 7.0),
    "v_min": (-100.0, 0.0),
    "v_max": (0.1, 100.0),
    "v_switch": (0.01, 100.0),
    "a_max": (0.01, 50.0),
    "length": (0.05, 30.0),
    "width": (0.05, 5.0),
    "g": (1.0, 30.0),
    "track": (0.05, 5.0),
}
"""Plausible range of every vehicle field [SI units], inclusive: from a 1/10-scale car to a
truck. Beyond them a value is a wrong unit or a typo (a steering limit in degrees, a centre of
gravity in cm, g = 0): the drive-log format's unit checks use the same magnitudes (steering
within 1.6 rad, steering rates within 7 rad/s, speeds within 100 m/s, accelerations within
5 g, mu within 3), g spans the Moon (1.6) to Jupiter (25), and a top speed below 0.1 m/s is
a car that cannot drive a course."""


def vehicle_problems(p: VehicleParams) -> list[str]:
    """Every field of ``p`` outside its type or :data:`PHYSICAL_RANGES`, and the pairs out of
    order, as ``"field=value: reason"`` strings."""
    out = []
    if not isinstance(p.name, str) or not p.name.strip():
        out.append(f"name={p.name!r} must be a non-empty string")
    for f in dataclasses.fields(p):
        if f.name == "name" or (f.name == "track" and p.track is None):
            continue
        value = getattr(p, f.name)
        if isinstance(value, bool) or not isinstance(value, int | float):
            out.append(f"{f.name}={value!r} must be a number")
            continue
        if not math.isfinite(value):
            out.append(f"{f.name}={value!r} is not finite")
            continue
        lo, hi = PHYSICAL_RANGES[f.name]
        if not lo <= value <= hi:
            out.append(f"{f.name}={value!r} is outside the physical range [{lo:g}, {hi:g}]")
    if out:
        return out
    for lo, hi in (
        ("delta_min", "delta_max"),
        ("delta_dot_min", "delta_dot_max"),
        ("v_min", "v_max"),
    ):
        if not getattr(p, lo) < getattr(p, hi):
            out.append(f"{lo}={getattr(p, lo)!r} must be below {hi}={getattr(p, hi)!r}")
    if p.lf + p.lr > p.length:
        out.append(
            f"lf + lr={p.lf + p.lr:g} m (the wheelbase) must fit within length={p.length:g} m"
        )
    return out


@dataclass(frozen=True)
class VehicleParams:
    """Parameters of the CommonRoad single-track model (reference point: centre of gravity).

    Attributes (SI units):
        name: a label for reports.
        m: vehicle mass [kg].
        I_z: yaw moment of inertia [kg m^2].
        lf: distance from the centre of gravity to the front axle [m].
        lr: distance from the centre of gravity to the rear axle [m].
        h: height of the centre of gravity used for load transfer [m] (CommonRoad ``h_s``).
        mu: tire-road friction coefficient [-].
        C_Sf: normalised front cornering stiffness [1/rad].
        C_Sr: normalised rear cornering stiffness [1/rad].
        delta_min, delta_max: steering angle limits [rad].
        delta_dot_min, delta_dot_max: steering rate limits [rad/s].
        v_min, v_max: speed limits [m/s].
        v_switch: speed above which the positive acceleration limit falls as
            ``a_max * v_switch / v`` [m/s].
        a_max: maximum absolute longitudinal acceleration [m/s^2].
        length, width: body size, for drawing and course margins [m].
        g: gravitational acceleration [m/s^2].
        track: front track width, wheel centre to wheel centre [m] (None: not given). The
            context fitter's ``track_slip`` effect holds its width at this value
            (``pcvfe_drake.models.effect_model``); a car that does not give it has the
            width calibrated from its drive instead.
    """

    name: str
    m: float
    I_z: float
    lf: float
    lr: float
    h: float
    mu: float
    C_Sf: float
    C_Sr: float
    delta_min: float
    delta_max: float
    delta_dot_min: float
    delta_dot_max: float
    v_min: float
    v_max: float
    v_switch: float
    a_max: float
    length: float = 4.3
    width: float = 1.7
    g: float = G_MPS2
    track: float | None = None

    def __post_init__(self) -> None:
        problems = vehicle_problems(self)
        if problems:
            raise ValueError(f"VehicleParams '{self.name}': " + "; ".join(problems))

    @property
    def L(self) -> float:
        """Wheelbase lf + lr [m]."""
        return self.lf + self.lr

    @property
    def theta(self) -> np.ndarray:
        """Friction parameters [mu, C_Sf, C_Sr] (see module docstring on identifiability)."""
        return np.array([self.mu, self.C_Sf, self.C_Sr])

    def with_theta(self, theta) -> VehicleParams:
        """A copy with friction parameters replaced by ``theta = [mu, C_Sf, C_Sr]``."""
        mu, c_sf, c_sr = (float(t) for t in np.asarray(theta, dtype=float).reshape(3))
        return dataclasses.replace(self, mu=mu, C_Sf=c_sf, C_Sr=c_sr)

    def replace(self, **changes) -> VehicleParams:
        """A copy with the given fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> VehicleParams:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown vehicle parameter(s) {unknown}; known: {sorted(known)}")
        missing = sorted(
            f.name
            for f in dataclasses.fields(cls)
            if f.name not in data and f.default is dataclasses.MISSING
        )
        if missing:
            raise ValueError(f"missing vehicle parameter(s) {missing}")
        wrong = [
            f"{k}={v!r} must be a number"
            for k, v in data.items()
            if k != "name"
            and not (k == "track" and v is None)
            and (isinstance(v, bool) or not isinstance(v, int | float))
        ]
        if wrong:
            raise ValueError("; ".join(wrong))
        values = {
            k: (v if k == "name" or (k == "track" and v is None) else float(v))
            for k, v in data.items()
        }
        return cls(**values)

    @classmethod
    def from_commonroad(cls, p, name: str = "commonroad") -> VehicleParams:
        """Build from a ``vehiclemodels`` parameter set (e.g. ``parameters_vehicle1()``).

        mu is ``p.tire.p_dy1``, C_Sf = C_Sr = ``-p.tire.p_ky1 / p.tire.p_dy1``, h is ``p.h_s``,
        the track the front one ``p.T_f``.
        """
        mu = float(p.tire.p_dy1)
        c_s = float(-p.tire.p_ky1 / p.tire.p_dy1)
        return cls(
            name=name,
            m=float(p.m),
            I_z=float(p.I_z),
            lf=float(p.a),
            lr=float(p.b),
            h=float(p.h_s),
            mu=mu,
            C_Sf=c_s,
            C_Sr=c_s,
            delta_min=float(p.steering.min),
            delta_max=float(p.steering.max),
            delta_dot_min=float(p.steering.v_min),
            delta_dot_max=float(p.steering.v_max),
            v_min=float(p.longitudinal.v_min),
            v_max=float(p.longitudinal.v_max),
            v_switch=float(p.longitudinal.v_switch),
            a_max=float(p.longitudinal.a_max),
            length=float(p.l),
            width=float(p.w),
            track=float(p.T_f),
        )


def ford_escort() -> VehicleParams:
    """The Ford Escort (CommonRoad vehicle 1), the car of the paper's simulation."""
    from vehiclemodels.parameters_vehicle1 import parameters_vehicle1

    return VehicleParams.from_commonroad(parameters_vehicle1(), name="ford_escort")


def bmw_320i() -> VehicleParams:
    """The BMW 320i (CommonRoad vehicle 2)."""
    from vehiclemodels.parameters_vehicle2 import parameters_vehicle2

    return VehicleParams.from_commonroad(parameters_vehicle2(), name="bmw_320i")


def vw_vanagon() -> VehicleParams:
    """The VW Vanagon (CommonRoad vehicle 3)."""
    from vehiclemodels.parameters_vehicle3 import parameters_vehicle3

    return VehicleParams.from_commonroad(parameters_vehicle3(), name="vw_vanagon")


def roboracer() -> VehicleParams:
    """The paper's R5 RoboRacer (1/5 scale), Table I.

    Table I gives m, I_z, lf, lr, h_cg and C_S = 2.0; it lists the wheelbase as 0.8 m although
    lf + lr = 0.532 m: we keep lf and lr, so L = 0.532 m. Table I has no friction, steering or
    speed limits; those are F1TENTH-class values (mu 1.0, |delta| <= 0.4189 rad,
    |delta_dot| <= 3.2 rad/s, v in [-5, 20] m/s, v_switch 7.319 m/s, a_max 9.51 m/s^2).
    """
    return VehicleParams(
        name="roboracer",
        m=15.32,
        I_z=0.643,
        lf=0.2735,
        lr=0.2585,
        h=0.1875,
        mu=1.0,
        C_Sf=2.0,
        C_Sr=2.0,
        delta_min=-0.4189,
        delta_max=0.4189,
        delta_dot_min=-3.2,
        delta_dot_max=3.2,
        v_min=-5.0,
        v_max=20.0,
        v_switch=7.319,
        a_max=9.51,
        length=0.75,
        width=0.42,
    )


PRESETS = {
    "ford_escort": ford_escort,
    "bmw_320i": bmw_320i,
    "vw_vanagon": vw_vanagon,
    "roboracer": roboracer,
}


def load_vehicle(spec: str | Path | None = None) -> VehicleParams:
    """A vehicle from a preset name or a YAML/JSON file of VehicleParams fields.

    ``None`` gives the Ford Escort, the paper's simulated car.
    """
    if spec is None:
        return ford_escort()
    key = str(spec)
    if key in PRESETS:
        return PRESETS[key]()
    path = Path(key)
    if not path.exists():
        raise ValueError(
            f"vehicle '{key}' is neither a preset ({', '.join(sorted(PRESETS))}) nor a file"
        )
    import yaml

    try:
        data = load_unique(path.read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f"vehicle file {path}: not valid YAML/JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"vehicle file {path}: expected a mapping of parameter names to values")
    data.setdefault("name", path.stem)
    try:
        return VehicleParams.from_dict(data)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"vehicle file {path}: {exc}") from exc
