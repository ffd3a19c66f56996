"""The context fitter's model of the car: which effects, the values held and their uncertainty.

The live fitter (``LiveFitConfig.model``) fits one friction per context on the single-track
model plus *effects* of the workbench's library (``pcvfe_drake.estimation.effect_fit``). Every
effect parameter is held at a value that belongs to the car, not to a course: the fitter then
has one unknown per context, the friction, and a constant fitted on an evaluation lap cannot
leak into the estimate. The values come from two places:

* the car's own data (:func:`vehicle_constants`): ``track_slip``'s width ``t`` is the
  vehicle's front track (``VehicleParams.track``); ``roll_camber``'s step offsets are the
  CommonRoad tyre's sign-of-camber constants (``f0 = -p_vy1``, ``s0 = p_hy1``, ``f1 = 0``:
  that model's tyre code switches the magic formula's constant offsets with the camber's
  sign, a step no real tyre has, so a car without a CommonRoad tyre set gets no
  ``roll_camber``);
* ``pcvfe calibrate`` (``pcvfe_drake.workbench.calibration``): the workbench's loop on a
  calibration drive selects and fits the rest (e.g. ``axle_stiffness``) from what a car
  measures, and writes a *model file*.

A model file is YAML::

    vehicle: ford_escort
    effects:
      - {name: peak_tyre, fixed: {k_s: 0.0}, std: {k_s: 0.0}}
      - {name: axle_stiffness, fixed: {k_f: 1.02, k_r: 1.2}, std: {k_f: 0.01, k_r: 0.02}}
    model_error_rel: 0.05
    calibrated_mu: 1.05
    calibration: {...}          # what the calibration measured (not read by the fitter)

Where the fitter finds a car's model (:func:`vehicle_model_path`): a vehicle given as a YAML
file ``cars/my_car.yaml`` has it in ``cars/my_car_model.yaml``; a shipped vehicle simulated by
the multi-body truth has one file per friction mapping in ``pcvfe_drake/data/vehicles``
(``<vehicle>_<mapping>_model.yaml``: the mapping says how the simulated tyre's stiffness follows
the terrain, which one surface cannot show). A car simulated by the single-track truth *is* the
single-track model: its model has no effects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

from pcvfe_drake.models.effects import get_effect
from pcvfe_drake.yaml_unique import load_unique

MODEL_DIR = Path(__file__).resolve().parents[1] / "data" / "vehicles"
"""Folder of the shipped vehicles' model files."""

MODEL_SUFFIX = "_model.yaml"
"""A vehicle file ``NAME.yaml``'s model file is ``NAME_model.yaml`` beside it."""

STIFFNESS_LAW = {"lateral_peak": 0.0, "peak": 0.0, "peak_and_stiffness": 1.0}
"""``peak_tyre``'s exponent ``k_s`` under each friction mapping of the multi-body truth
(``pcvfe_drake.vehicle.mb_truth``): 1 where a terrain's mu scales the tyre's stiffness with its
peak, 0 where only the peak changes. A calibration on one surface cannot see how the stiffness
follows the friction, so the simulated car's mapping states it."""

MODEL_KEYS = (
    "vehicle",
    "effects",
    "model_error_rel",
    "calibrated_mu",
    "checked_mu",
    "calibration",
)


@dataclass
class FitterEffect:
    """One effect of the context fitter's model (scenario ``fitter.effects`` entry).

    Attributes:
        name: the effect's name in the workbench library (``pcvfe diagnose --list``).
        fixed: parameter values held fixed (short names, e.g. ``{tau: 0.15}``; as found by
            ``pcvfe diagnose`` or ``pcvfe calibrate``); the effect's other parameters are
            fitted per context.
        std: the held values' standard deviations (short names; a subset of ``fixed``), as
            the calibration measured them (0: a constant of the car's data, exact).
    """

    name: str = ""
    fixed: dict[str, float] = field(default_factory=dict)
    std: dict[str, float] = field(default_factory=dict)


def parse_effects(entries) -> list[FitterEffect]:
    """``FitterEffect`` list from names, ``"name:param=value,..."`` strings, dicts or
    FitterEffects; unknown effects and parameters are reported by name."""
    out = []
    for entry in entries or ():
        if isinstance(entry, FitterEffect):
            spec = entry
        elif isinstance(entry, dict):
            spec = FitterEffect(
                str(entry.get("name", "")),
                dict(entry.get("fixed", {}) or {}),
                dict(entry.get("std", {}) or {}),
            )
        else:
            text = str(entry).strip()
            name, _, rest = text.partition(":")
            fixed = {}
            for item in filter(None, (s.strip() for s in rest.split(","))):
                key, eq, value = item.partition("=")
                if not eq:
                    raise ValueError(
                        f"effect {text!r}: fixed parameters are written name:param=value,... "
                        f"(got {item!r})"
                    )
                fixed[key.strip()] = float(value)
            spec = FitterEffect(name.strip(), fixed)
        effect = get_effect(spec.name)  # unknown names fail here, with the library listed
        names = {q.name: q for q in effect.params}
        for key, value in spec.fixed.items():
            if key not in names:
                raise ValueError(
                    f"effect {spec.name}: no parameter {key!r} to fix (its parameters: "
                    f"{', '.join(names) or 'none'})"
                )
            q = names[key]
            if not (math.isfinite(value) and q.lower <= value <= q.upper):
                raise ValueError(
                    f"effect {spec.name}: fixed {key} = {value!r} is outside its bounds "
                    f"[{q.lower}, {q.upper}] {q.unit}"
                )
        for key, value in spec.std.items():
            if key not in spec.fixed:
                raise ValueError(
                    f"effect {spec.name}: std given for {key!r}, which is not held (held: "
                    f"{', '.join(spec.fixed) or 'none'})"
                )
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"effect {spec.name}: std of {key} = {value!r} must be >= 0")
        out.append(
            FitterEffect(
                effect.name,
                {k: float(v) for k, v in spec.fixed.items()},
                {k: float(v) for k, v in spec.std.items()},
            )
        )
    return out


@dataclass
class EffectModel:
    """The effect model of the context fitter (``fitter.model`` of a scenario).

    Attributes:
        file: a model file (written by ``pcvfe calibrate``) to read the model from; "" : the
            ``effects`` below. A scenario that names neither gets the vehicle's own model
            (:func:`resolve_model`).
        effects: the effects with their held values and standard deviations (empty: the
            single-track model, the paper's fitter).
        model_error_rel: model-error budget added to mu's std, relative to mu
            (``sqrt(std^2 + (model_error_rel mu)^2)``; 0: none): the error the held model
            makes on the car that no covariance of one context's data sees.
        calibrated_mu: the friction of the surface the model was calibrated on (None: not
            calibrated); fits far from it rely on the model beyond its calibration.
        checked_mu: the friction of a second surface where the held model was checked (only mu
            fitted, its offset from the known friction inside ``model_error_rel``; None: no
            check): between the two frictions the budget was measured, beyond them it is
            extrapolated (``ModelError``).
    """

    file: str = ""
    effects: list[FitterEffect] = field(default_factory=list)
    model_error_rel: float = 0.0
    calibrated_mu: float | None = None
    checked_mu: float | None = None

    def __post_init__(self) -> None:
        self.effects = parse_effects(self.effects)
        if self.file and self.effects:
            raise ValueError("EffectModel: give a model file or effects, not both")
        if not (
            isinstance(self.model_error_rel, int | float)
            and math.isfinite(self.model_error_rel)
            and self.model_error_rel >= 0
        ):
            raise ValueError(
                f"EffectModel.model_error_rel must be >= 0, got {self.model_error_rel!r}"
            )
        for name in ("calibrated_mu", "checked_mu"):
            value = getattr(self, name)
            if value is not None and not (
                isinstance(value, int | float) and math.isfinite(value) and value > 0
            ):
                raise ValueError(f"EffectModel.{name} must be > 0, got {value!r}")

    @property
    def measured_mu_range(self) -> tuple[float, float] | None:
        """The frictions (low, high) over which the model's error was measured: the
        calibration surface's and the checked surface's (None: not calibrated)."""
        if self.calibrated_mu is None:
            return None
        values = [self.calibrated_mu] + ([self.checked_mu] if self.checked_mu else [])
        return (float(min(values)), float(max(values)))

    @property
    def stiffness_law(self) -> float:
        """How the tyre's small-slip stiffness follows the friction: ``peak_tyre``'s exponent
        ``k_s`` (stiffness proportional to ``mu^k_s``), 0 for a model without ``peak_tyre``
        (the handing then keeps the prior's small-slip stiffness at every friction)."""
        for effect in self.effects:
            if effect.name == "peak_tyre":
                return float(effect.fixed.get("k_s", 0.0))
        return 0.0

    @property
    def single_track(self) -> bool:
        """True for the bare single-track model (no file, no effects)."""
        return not self.file and not self.effects

    def to_dict(self) -> dict:
        """The model as plain data (the keys of a model file, without ``calibration``)."""
        out: dict = {
            "effects": [
                {"name": e.name, "fixed": dict(e.fixed), "std": dict(e.std)} for e in self.effects
            ],
            "model_error_rel": float(self.model_error_rel),
        }
        for name in ("calibrated_mu", "checked_mu"):
            if getattr(self, name) is not None:
                out[name] = float(getattr(self, name))
        return out


def load_model_file(path: str | Path) -> EffectModel:
    """The :class:`EffectModel` of a model file; ValueError naming the file on bad content."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file {path}: no such file")
    try:
        data = load_unique(path.read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f"model file {path}: not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"model file {path}: expected a mapping with 'effects'")
    unknown = sorted(set(data) - set(MODEL_KEYS))
    if unknown:
        raise ValueError(f"model file {path}: unknown key(s) {unknown}; known: {list(MODEL_KEYS)}")
    if "effects" not in data:  # e.g. a vehicle file given as a model file
        raise ValueError(
            f"model file {path}: no 'effects' list (write 'effects: []' for the single-track model)"
        )
    if not isinstance(data["effects"], list):
        raise ValueError(f"model file {path}: 'effects' must be a list")
    try:
        return EffectModel(
            effects=list(data.get("effects") or []),
            model_error_rel=float(data.get("model_error_rel", 0.0)),
            calibrated_mu=(
                None if data.get("calibrated_mu") is None else float(data["calibrated_mu"])
            ),
            checked_mu=None if data.get("checked_mu") is None else float(data["checked_mu"]),
        )
    except (TypeError, ValueError) as exc:
        raise ValueError(f"model file {path}: {exc}") from exc


def write_model_file(
    path: str | Path, model: EffectModel, vehicle: str, header: str, calibration: dict
) -> Path:
    """Write ``model`` as a model file (``header``: comment lines; ``calibration``: what the
    calibration measured, kept for the reader); returns the path."""
    import yaml

    path = Path(path)
    body = {"vehicle": vehicle, **model.to_dict(), "calibration": calibration}
    lines = [f"# {line}".rstrip() for line in header.strip().splitlines()]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n" + yaml.safe_dump(body, sort_keys=False))
    return path


def vehicle_constants(vehicle: str, params) -> dict[str, dict[str, float]]:
    """The effect parameters the car's own data give (module docstring): ``{effect: {param:
    value}}``; ``vehicle`` the preset name or file, ``params`` its ``VehicleParams``."""
    from pcvfe_drake.vehicle.mb_truth import MB_VEHICLES, commonroad_parameters

    out: dict[str, dict[str, float]] = {}
    if params.track is not None:
        out["track_slip"] = {"t": float(params.track)}
    if str(vehicle) in MB_VEHICLES:
        tyre = commonroad_parameters(str(vehicle)).tire
        out["roll_camber"] = {"f0": -float(tyre.p_vy1), "f1": 0.0, "s0": float(tyre.p_hy1)}
    return out


def vehicle_model_path(vehicle: str, truth_model: str, friction_mapping: str) -> Path | None:
    """Where the vehicle's model file is (module docstring); None: the single-track model (a
    preset simulated by the single-track truth)."""
    spec = Path(str(vehicle)).expanduser()
    if spec.suffix in (".yaml", ".yml", ".json"):
        return spec.with_name(spec.stem + MODEL_SUFFIX)
    if truth_model != "mb":
        return None
    return MODEL_DIR / f"{vehicle}_{friction_mapping}{MODEL_SUFFIX}"


def resolve_model(
    model: EffectModel, vehicle: str, truth_model: str, friction_mapping: str
) -> EffectModel:
    """The model the fitter uses: ``model``'s effects, else its file, else the vehicle's own
    model file (:func:`vehicle_model_path`). A missing file raises ValueError (a scenario
    problem) naming it and the command that writes it."""
    if model.effects:
        return replace(model)  # validated again (a YAML loader may set fields directly)
    if model.file:
        if not Path(model.file).expanduser().is_file():
            raise ValueError(f"fitter.model.file {model.file!r}: no such model file")
        return load_model_file(Path(model.file).expanduser())
    path = vehicle_model_path(vehicle, truth_model, friction_mapping)
    if path is None:
        return EffectModel()
    if path.parent != MODEL_DIR and not Path(str(vehicle)).expanduser().is_file():
        return EffectModel()  # a vehicle file not found (yet): the scenario loader says so
    if not path.is_file():
        mapping = f" --mapping {friction_mapping}" if truth_model == "mb" else ""
        raise ValueError(
            f"vehicle {vehicle}: no calibrated model {path} (write it with `pcvfe calibrate "
            f"--simulate {vehicle}{mapping} --out {path}` or from a drive log, name one in "
            "fitter.model.file, or use estimator pcvfe_paper)"
        )
    return load_model_file(path)
