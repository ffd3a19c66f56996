"""Scenario description of one closed-loop PC-VFE run (plain dataclasses, no pydrake).

A scenario says which vehicle drives which course in which world (``pcvfe_drake.worlds``: terrains,
their frictions, the course; docs/worlds.md), which truth model
simulates it, the rates of every periodic part of the loop, the feature backend, the settings of
clustering, fitter and controller, the seed and how long to run. Scenarios are YAML files; they
are loaded into these dataclasses by ``pcvfe_drake.diagrams.scenario_io.load_scenario`` with
``pydrake.common.yaml.yaml_load_typed`` (the core never imports pydrake, so the loader lives with
the diagrams). Every field has a default, so a YAML file names only what it changes. This module
does not use ``from __future__ import annotations``: ``yaml_load_typed`` reads the field types
from ``dataclasses.fields`` and needs real types there, not strings.

Shipped scenarios live in ``pcvfe_drake/data/scenarios/<name>.yaml``:

- ``paper_sim`` (default): the paper's simulation: Ford Escort in the ``paper`` world (slalom
  course, four terrain quadrants), one lap, single-track truth, descriptor feature backend.
- ``paper_sim_mb``: the same with CommonRoad's multi-body model as truth.
- ``roboracer``: the paper's RoboRacer (Table I) on the small-scale course.
"""

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field

from pcvfe_drake.contexts.clustering_params import ClusteringParams
from pcvfe_drake.control.nmpc_config import NmpcConfig
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.models.effect_model import EffectModel, resolve_model
from pcvfe_drake.estimation.ukf import UkfConfig
from pcvfe_drake.hardware.settings import HardwareSettings, hardware_problems
from pcvfe_drake.perception.camera import CameraConfig
from pcvfe_drake.perception.features import DESCRIPTOR_BACKEND
from pcvfe_drake.runs.bounds import scenario_bound_problems
from pcvfe_drake.runs.friction_sources import (
    FixedFrictionSettings,
    LookupSettings,
    friction_source_problems,
)
from pcvfe_drake.runs.scenario_files import (
    DEFAULT_SCENARIO,
    SCENARIO_DIR,
    resolve_scenario_path,
    shipped_scenarios,
)
from pcvfe_drake.vehicle.mb_truth import FRICTION_SCALINGS
from pcvfe_drake.vehicle.params import TRUTH_MODELS
from pcvfe_drake.vehicle.sensing import SensingConfig
from pcvfe_drake.worlds.world_file import TerrainOverride, mu_problem

__all__ = [
    "DEFAULT_SCENARIO",
    "DERIVED_FIELDS",
    "DESCRIPTOR_BACKEND",
    "SCENARIO_DIR",
    "REPLACED_FIELDS",
    "TRUTH_MODELS",
    "FeatureSettings",
    "Rates",
    "Scenario",
    "SimulatorSettings",
    "resolve_scenario_path",
    "scenario_problems",
    "shipped_scenarios",
]


@dataclass
class Rates:
    """Periods of the periodic parts of the loop [s] (a rate of 10 Hz is a period of 0.1 s).

    Every period of the diagram lives here, once: the configs embedded in the scenario that also
    carry a rate (``clustering.frame_rate_hz``, ``fitter.sample_period_s``, ``nmpc.dt_s``) get it
    from here (see :data:`DERIVED_FIELDS`).
    """

    camera_period_s: float = 0.1
    """Downward camera frame period (10 Hz); features and context ids follow each frame."""
    nmpc_period_s: float = 0.05
    """Controller update period (20 Hz); its actuation is held between updates."""
    fitter_period_s: float = 0.5
    """Context fitter refit period (2 Hz): a refit starts on the contexts whose data changed.
    A sample waits for a window holding it to complete and then for the next refit; at the
    effect fit's window stride (``fitter.effect_stride_s``, 0.5 s) each refit adds the window
    that has just completed (docs/realtime.md)."""
    fitter_latency_s: float = 0.0
    """Declared latency of a refit [s]: a refit started at t on the data up to t is handed to
    the controller at t + this, in simulated time (docs/realtime.md); below
    ``fitter_period_s``. 0: at once, in the event that starts it."""
    fitter_sample_period_s: float = 0.01
    """Period at which the fitter samples state and actuation into its buffers (100 Hz)."""
    recluster_period_s: float = 10.0
    """Unrestricted HDBSCAN re-clustering period (0.1 Hz, the paper's)."""
    log_period_s: float = 0.05
    """Period of the run log rows appended to the drive log (20 Hz, the NMPC's rate: each row's
    ``steer_rate`` and ``accel`` are the input held from that row to the next, which is what an
    offline fit of the drive log assumes; a log period longer than the NMPC period samples the
    input and biases such a fit)."""
    frame_log_period_s: float = 2.0
    """Period at which camera frames are saved with the drive log (``frames/``, for the
    figures). ``pcvfe replay`` does not need every frame: the drive log holds the features of
    every frame (docs/hardware.md, Replay)."""
    view_period_s: float = 0.1
    """Period of the Meshcat view's updates and of its recording's frames (10 Hz)."""
    clustering_frame_offset_s: float = 0.001
    """Offset of the clustering's per-frame assignment after each camera frame [s]. The camera
    takes its frame at offset 0; an assignment at the same instant would read the previous frame
    (simultaneous updates see the state before the step), adding a frame period to every
    latency. 1 ms later it assigns the frame just taken. Must be in [0, camera_period_s)."""


@dataclass
class SimulatorSettings:
    """Drake's ``pydrake.systems.analysis.SimulatorConfig``, field for field (pydrake stays out
    of the core; ``diagrams/run_simulation.py`` turns it into a ``SimulatorConfig`` and applies
    it with ``ApplySimulatorConfig``; a test checks the fields match Drake's). ``start_time`` is
    left out: a run starts at t = 0.

    Defaults: the fixed-step ``runge_kutta2`` at 10 ms (the 100 Hz fitter sampling forces 10 ms
    steps anyway, and it needs 2 derivative evaluations per step where the error-controlled
    ``runge_kutta3`` needs 3; final positions agree to a millimetre over 30 s). ``accuracy`` is
    used by error-controlled schemes only (1e-3: what ``ResetIntegratorFromFlags`` gave before).
    """

    integration_scheme: str = "runge_kutta2"
    """Scheme name (``pydrake.systems.analysis.GetIntegrationSchemes``)."""
    max_step_size: float = 0.01
    """Integrator step [s] (the largest step for error-controlled schemes)."""
    accuracy: float = 1e-3
    """Target accuracy of error-controlled schemes."""
    use_error_control: bool = True
    """Error control for schemes that support it (False: fixed steps of ``max_step_size``)."""
    target_realtime_rate: float = 0.0
    """Pace the simulation at this multiple of real time (0: as fast as possible)."""
    publish_every_time_step: bool = False
    """Publish after every integration step (the loop's publishes are periodic events)."""


@dataclass
class FeatureSettings:
    """Feature extractor: ``backend`` is ``"descriptor"`` or the path of a CLIP model folder."""

    backend: str = DESCRIPTOR_BACKEND
    lambda_c: float = 0.25
    """Weight of the mean RGB appended to the similarity vector (paper eq. 4)."""
    clip_threads: int = 2
    """onnxruntime threads of the CLIP backend (1 is safer on a loaded 2-core machine)."""


def _scenario_camera() -> CameraConfig:
    """The scenario's default camera: ``CameraConfig`` with the realistic effects switched on
    (motion blur from a 2 ms exposure, per-frame exposure changes, sensor noise; all seeded
    from the scenario's seed)."""
    return CameraConfig(exposure_s=0.002, exposure_jitter=0.05, noise_std=3.0)


DERIVED_FIELDS: dict[str, str] = {
    "clustering.frame_rate_hz": "rates.camera_period_s",
    "clustering.seed": "seed",
    "fitter.sample_period_s": "rates.fitter_sample_period_s",
    "nmpc.dt_s": "rates.nmpc_period_s",
    "ukf.period_s": "rates.fitter_sample_period_s",
}
"""Fields of the embedded configs that the scenario sets from another field (the value): a
scenario file must not name them, and :meth:`Scenario.clustering_params`,
:meth:`Scenario.fit_config`, :meth:`Scenario.nmpc_config`, :meth:`Scenario.ukf_config` fill them
in."""


@dataclass
class Scenario:
    """One closed-loop run. Every field has a default; YAML files name only what they change.

    ``camera``, ``clustering``, ``fitter``, ``nmpc`` and ``ukf`` are the core's own configs
    (``CameraConfig``, ``ClusteringParams``, ``LiveFitConfig``, ``NmpcConfig``, ``UkfConfig``):
    their fields, defaults, documentation and validation are those of the core, in one place.
    The camera's scenario default switches the realistic effects on (see ``_scenario_camera``).
    """

    name: str = DEFAULT_SCENARIO
    description: str = ""
    vehicle: str = "ford_escort"
    """Vehicle preset (see params.PRESETS) or a vehicle YAML file (relative to the scenario)."""
    world: str = "paper"
    """The world: a shipped world (``pcvfe_drake/data/worlds``: paper, paper_small,
    paper_no_strips) or a world file (relative to the scenario); docs/worlds.md."""
    terrains: dict[str, TerrainOverride] = field(default_factory=dict)
    """Per-terrain changes on top of the world's (``{patchy_grass: {mu: 0.22}}``), so that one
    world runs at many frictions. The truth, the oracle and the scores read them; the lookup
    baseline keeps its own table."""
    course: str = ""
    """A course (shipped name or file) to drive instead of the world's ("": the world's)."""
    truth_model: str = "st"
    """Truth plant model: "st" (single track) or "mb" (CommonRoad multi-body)."""
    seed: int = 0
    """Seed of every random choice in the run (camera noise, measurement noise, ...)."""
    laps: float | None = 1.0
    """Stop after this many laps (or at ``max_duration_s``); ignored when ``duration_s`` is set."""
    duration_s: float | None = None
    """Stop after this much simulated time [s]; takes precedence over ``laps``."""
    max_duration_s: float = 900.0
    """Safety cap on simulated time when running by laps [s]."""
    initial_speed_mps: float = 3.0
    """Speed at the start of the course [m/s]."""
    start_s_m: float = 0.0
    """Where the car starts: arc length along the course from the course's own start [m]
    (negative: before it, counted back around the loop)."""
    rates: Rates = field(default_factory=Rates)
    simulator: SimulatorSettings = field(default_factory=SimulatorSettings)
    camera: CameraConfig = field(default_factory=_scenario_camera)
    features: FeatureSettings = field(default_factory=FeatureSettings)
    clustering: ClusteringParams = field(default_factory=ClusteringParams)
    fitter: LiveFitConfig = field(default_factory=LiveFitConfig)
    nmpc: NmpcConfig = field(default_factory=NmpcConfig)
    hardware: HardwareSettings = field(default_factory=HardwareSettings)
    """LCM buses, channels and watchdog limits of the hardware station and the vehicle bridge
    (``pcvfe_drake.hardware.settings``; docs/hardware.md)."""
    friction_mapping: str = "peak_and_stiffness"
    """What a terrain's mu changes in the multi-body truth's tire
    (``pcvfe_drake.vehicle.mb_truth``): ``peak_and_stiffness``, ``peak``, or ``lateral_peak``
    (the public PC-VFE simulator's: only ``p_dy1 = mu``)."""
    sensing: SensingConfig = field(default_factory=SensingConfig)
    """State sensing: ``model: none`` (the true state) or ``ins`` (``vehicle/sensing.py``)."""
    estimator: str = "pcvfe"
    """The friction source feeding the NMPC: pcvfe | pcvfe_paper | oracle | fixed | lookup |
    ukf | kmpc (``pcvfe_drake.runs.friction_sources``; ``pcvfe`` fits the vehicle's
    calibrated effect model, ``pcvfe_paper`` the paper's single-track model)."""
    fixed: FixedFrictionSettings = field(default_factory=FixedFrictionSettings)
    lookup: LookupSettings = field(default_factory=LookupSettings)
    ukf: UkfConfig = field(default_factory=UkfConfig)
    """Tuning of the UKF friction source (``estimator: ukf``; ``pcvfe_drake.estimation.ukf``)."""
    stop_on_failure: bool = True
    """End the run at the first catastrophic failure (``pcvfe_drake.control.failure``)."""

    def validate(self, source: str = "scenario") -> "Scenario":
        """Check every value; raise ValueError naming ``source`` and the field. Returns self."""
        problems = scenario_problems(self)
        if problems:
            raise ValueError(f"{source}: invalid scenario: " + "; ".join(problems))
        return self

    def with_run_length(self, *, laps: float | None = None, duration_s: float | None = None):
        """A copy that stops after ``duration_s`` seconds or ``laps`` laps (one of them)."""
        if laps is not None and duration_s is not None:
            raise ValueError("give either laps or duration_s, not both")
        if duration_s is not None:
            return dataclasses.replace(self, duration_s=float(duration_s), laps=None)
        if laps is not None:
            return dataclasses.replace(self, laps=float(laps), duration_s=None)
        return dataclasses.replace(self)

    @property
    def uses_clip(self) -> bool:
        """True when the feature backend is a CLIP model folder."""
        return self.features.backend != DESCRIPTOR_BACKEND

    def stop_time_s(self) -> float:
        """Simulated time at which the run stops at the latest [s]."""
        if self.duration_s is not None:
            return float(self.duration_s)
        return float(self.max_duration_s)

    def clustering_params(self) -> ClusteringParams:
        """``clustering`` with its frame rate (from the camera period) and seed filled in."""
        return dataclasses.replace(
            self.clustering, frame_rate_hz=1.0 / self.rates.camera_period_s, seed=self.seed
        )

    def fit_config(self) -> LiveFitConfig:
        """``fitter`` with its data rate (``rates.fitter_sample_period_s``) and its effect model
        filled in: for ``estimator: pcvfe`` ``fitter.model`` as given, or the vehicle's
        calibrated model where it names none
        (``pcvfe_drake.models.effect_model.resolve_model``); for ``pcvfe_paper`` (the
        paper's fitter), and for the sources without a fitter, the single-track model."""
        if self.estimator != "pcvfe":
            model = EffectModel()
        else:
            model = resolve_model(
                self.fitter.model, self.vehicle, self.truth_model, self.friction_mapping
            )
        return dataclasses.replace(
            self.fitter, sample_period_s=self.rates.fitter_sample_period_s, model=model
        )

    def ukf_config(self) -> UkfConfig:
        """``ukf`` with its filter step (``rates.fitter_sample_period_s``) filled in."""
        return dataclasses.replace(self.ukf, period_s=self.rates.fitter_sample_period_s)

    def nmpc_config(self) -> NmpcConfig:
        """``nmpc`` with its step (``rates.nmpc_period_s``) filled in."""
        return dataclasses.replace(self.nmpc, dt_s=self.rates.nmpc_period_s)

    def to_yaml(self) -> str:
        """:meth:`to_dict` as YAML text (what a run folder's ``scenario.yaml`` holds)."""
        import yaml

        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    def to_dict(self) -> dict:
        """Every field as plain data, without the :data:`DERIVED_FIELDS` (a file that can be
        loaded again)."""
        data = dataclasses.asdict(self)
        variant_tags(self, data)
        for dotted in DERIVED_FIELDS:
            group, name = dotted.split(".")
            data[group].pop(name, None)
        return data


def variant_tags(obj, data: dict) -> dict:
    """Mark the variants in ``data`` (``dataclasses.asdict(obj)``) the way Drake's YAML does in
    plain data: a field typed as a union of dataclasses gets ``_tag: "!ClassName"`` in its
    mapping (``yaml_load_typed`` reads it; in a YAML file it is the ``!ClassName`` tag).
    Returns ``data``."""
    hints = typing.get_type_hints(type(obj))
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if not (dataclasses.is_dataclass(value) and isinstance(data.get(f.name), dict)):
            continue
        if typing.get_origin(hints[f.name]) in (typing.Union, types.UnionType):
            data[f.name]["_tag"] = "!" + type(value).__name__
        variant_tags(value, data[f.name])
    return data


def resolve_field_types(schema: type) -> type:
    """Replace the string annotations of ``schema``'s fields (and of the dataclasses in them)
    with the types they name; returns ``schema``.

    ``yaml_load_typed`` reads ``dataclasses.fields(schema)[i].type`` and needs real types there;
    the core's config modules use ``from __future__ import annotations``, which leaves strings.
    """
    hints = typing.get_type_hints(schema)
    for f in dataclasses.fields(schema):
        f.type = hints[f.name]
        for arg in (f.type, *typing.get_args(f.type)):
            if dataclasses.is_dataclass(arg) and isinstance(arg, type):
                resolve_field_types(arg)
    return schema


resolve_field_types(Scenario)


def _is_number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _config_problems(group: str, make) -> list[str]:
    """The core config's own validation (its ``__post_init__`` / ``validate``) as problems."""
    try:
        make()
    except (ValueError, TypeError) as exc:
        return [f"{group}: {exc}"]
    return []


def scenario_problems(scenario: Scenario) -> list[str]:
    """Every problem with the values of ``scenario``, as ``"field=value: reason"`` strings."""
    problems: list[str] = []

    def need(ok: bool, name: str, value, reason: str) -> None:
        if not ok:
            problems.append(f"{name}={value!r}: {reason}")

    s = scenario
    need(bool(s.name.strip()), "name", s.name, "must not be empty")
    need(bool(s.vehicle.strip()), "vehicle", s.vehicle, "must name a preset or a YAML file")
    need(bool(s.world.strip()), "world", s.world, "must name a world (shipped name or file)")
    for name, change in s.terrains.items():
        if change.mu is not None:
            why = mu_problem(change.mu)
            need(not why, f"terrains.{name}.mu", change.mu, why)
    need(
        s.truth_model in TRUTH_MODELS,
        "truth_model",
        s.truth_model,
        f"must be one of {TRUTH_MODELS}",
    )
    need(isinstance(s.seed, int) and s.seed >= 0, "seed", s.seed, "must be an integer >= 0")
    if s.duration_s is not None:
        need(
            _is_number(s.duration_s) and s.duration_s > 0, "duration_s", s.duration_s, "must be > 0"
        )
    if s.laps is not None:
        need(_is_number(s.laps) and s.laps > 0, "laps", s.laps, "must be > 0")
    if s.duration_s is None and s.laps is None:
        problems.append("laps and duration_s are both unset: give one of them")
    need(
        _is_number(s.max_duration_s) and s.max_duration_s > 0,
        "max_duration_s",
        s.max_duration_s,
        "must be > 0",
    )
    need(_is_number(s.start_s_m), "start_s_m", s.start_s_m, "must be a finite number")
    need(
        _is_number(s.initial_speed_mps) and s.initial_speed_mps >= 0,
        "initial_speed_mps",
        s.initial_speed_mps,
        "must be >= 0",
    )
    rates_ok = True
    within = {"fitter_latency_s": "fitter_period_s", "clustering_frame_offset_s": "camera_period_s"}
    for f in dataclasses.fields(Rates):
        if f.name in within:
            continue
        value = getattr(s.rates, f.name)
        ok = _is_number(value) and value > 0
        rates_ok &= ok
        need(ok, f"rates.{f.name}", value, "must be a period > 0 s")
    for name, period_name in within.items():  # a delay inside one period of its own rate
        value, period = getattr(s.rates, name), getattr(s.rates, period_name)
        need(
            _is_number(value) and value >= 0 and (not _is_number(period) or value < period),
            f"rates.{name}",
            value,
            f"must be >= 0 s and shorter than rates.{period_name}",
        )
    if _is_number(s.rates.camera_period_s) and _is_number(s.rates.recluster_period_s):
        need(
            s.rates.recluster_period_s >= s.rates.camera_period_s,
            "rates.recluster_period_s",
            s.rates.recluster_period_s,
            "must not be shorter than rates.camera_period_s",
        )
    sim = s.simulator
    need(
        bool(sim.integration_scheme.strip()),
        "simulator.integration_scheme",
        sim.integration_scheme,
        "must name a scheme (e.g. runge_kutta2)",
    )
    need(
        _is_number(sim.max_step_size) and sim.max_step_size > 0,
        "simulator.max_step_size",
        sim.max_step_size,
        "must be a step > 0 s",
    )
    need(
        _is_number(sim.accuracy) and sim.accuracy >= 0,
        "simulator.accuracy",
        sim.accuracy,
        "must be >= 0",
    )
    need(
        _is_number(sim.target_realtime_rate) and sim.target_realtime_rate >= 0,
        "simulator.target_realtime_rate",
        sim.target_realtime_rate,
        "must be >= 0 (0: as fast as possible)",
    )
    defaults = {
        "clustering": ClusteringParams(),
        "fitter": LiveFitConfig(),
        "nmpc": NmpcConfig(),
        "ukf": UkfConfig(),
    }
    for dotted, source in DERIVED_FIELDS.items():
        group, name = dotted.split(".")
        value = getattr(getattr(s, group), name)
        need(
            value == getattr(defaults[group], name),
            dotted,
            value,
            f"is set from {source}; change that instead",
        )
    problems += _config_problems("camera", lambda: dataclasses.replace(s.camera))
    if rates_ok:
        problems += _config_problems("clustering", s.clustering_params)
        problems += _config_problems("fitter", s.fit_config)
        problems += _config_problems("nmpc", lambda: s.nmpc_config().validate())
        problems += _config_problems("ukf", s.ukf_config)
    floor = s.fitter.handing.floor_mu
    need(
        _is_number(floor) and not mu_problem(floor),
        "fitter.handing.floor_mu",
        floor,
        mu_problem(floor) if _is_number(floor) else "must be a number",
    )
    need(bool(s.features.backend.strip()), "features.backend", s.features.backend, "empty")
    need(
        s.friction_mapping in FRICTION_SCALINGS,
        "friction_mapping",
        s.friction_mapping,
        f"must be one of {FRICTION_SCALINGS}",
    )
    problems += s.sensing.problems("sensing")
    problems += friction_source_problems(s.estimator, s.fixed, s.lookup)
    need(
        _is_number(s.features.lambda_c) and s.features.lambda_c >= 0,
        "features.lambda_c",
        s.features.lambda_c,
        "must be >= 0",
    )
    need(
        isinstance(s.features.clip_threads, int) and s.features.clip_threads >= 1,
        "features.clip_threads",
        s.features.clip_threads,
        "must be an integer >= 1",
    )
    problems.extend(hardware_problems(s.hardware))
    problems.extend(scenario_bound_problems(s))
    return problems


REPLACED_FIELDS: dict[str, str] = {
    "terrain_layout": "replaced by 'world': a shipped world (paper, paper_small, "
    "paper_no_strips) or a world file, see docs/worlds.md",
}
"""Scenario fields that no longer exist, with what replaced them (the loader's error says it)."""
