"""Scenario description of one closed-loop PC-VFE run (plain dataclasses, no pydrake).

A scenario says which vehicle drives which course over which terrain layout, which truth model
simulates it, the rates of every periodic part of the loop, the feature backend, the settings of
clustering, fitter and controller, the seed and how long to run. Scenarios are YAML files; they
are loaded into these dataclasses by ``pcvfe_drake.diagrams.scenario_io.load_scenario`` with
``pydrake.common.yaml.yaml_load_typed`` (the core never imports pydrake, so the loader lives with
the diagrams). Every field has a default, so a YAML file names only what it changes. This module
does not use ``from __future__ import annotations``: ``yaml_load_typed`` reads the field types
from ``dataclasses.fields`` and needs real types there, not strings.

Shipped scenarios live in ``pcvfe_drake/data/scenarios/<name>.yaml``:

- ``paper_sim`` (default): the paper's simulation: Ford Escort, slalom course, the four-terrain
  layout, one lap, single-track truth, descriptor feature backend.
- ``paper_sim_mb``: the same with CommonRoad's multi-body model as truth.
- ``roboracer``: the paper's RoboRacer (Table I) on the small-scale course.
"""

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

TRUTH_MODELS = ("st", "mb")
"""Truth plant models: our single-track model, or CommonRoad's multi-body model."""

DESCRIPTOR_BACKEND = "descriptor"
"""Feature backend name of the non-learned texture descriptor (any other value is a CLIP folder)."""

SCENARIO_DIR = Path(__file__).resolve().parents[1] / "data" / "scenarios"
"""Folder of the shipped scenario files."""

DEFAULT_SCENARIO = "paper_sim"


@dataclass
class Rates:
    """Periods of the periodic parts of the loop [s] (a rate of 10 Hz is a period of 0.1 s)."""

    camera_period_s: float = 0.1
    """Downward camera frame period (10 Hz); features and context ids follow each frame."""
    nmpc_period_s: float = 0.05
    """Controller update period (20 Hz); its actuation is held between updates."""
    fitter_period_s: float = 1.0
    """Context fitter refit period (1 Hz)."""
    fitter_sample_period_s: float = 0.01
    """Period at which the fitter samples state and actuation into its buffers (100 Hz)."""
    recluster_period_s: float = 10.0
    """Unrestricted HDBSCAN re-clustering period (0.1 Hz, the paper's)."""
    log_period_s: float = 0.05
    """Period of the run log rows appended to the drive log (20 Hz, the NMPC's rate: each row's
    ``steer_rate`` and ``accel`` are the input held from that row to the next, which is what an
    offline fit of the drive log assumes; a log period longer than the NMPC period samples the
    input and biases such a fit)."""
    view_period_s: float = 0.1
    """Period of the Meshcat view's updates and of its recording's frames (10 Hz)."""
    clustering_frame_offset_s: float = 0.001
    """Offset of the clustering's per-frame assignment after each camera frame [s]. The camera
    takes its frame at offset 0; an assignment at the same instant would read the previous frame
    (simultaneous updates see the state before the step), adding a frame period to every
    latency. 1 ms later it assigns the frame just taken. Must be in [0, camera_period_s)."""
    plant_max_step_s: float = 0.01
    """Integrator step of the continuous plant [s] (the largest step for error-controlled
    schemes)."""
    integrator: str = "runge_kutta2"
    """Integration scheme of the simulator (``pydrake.systems.analysis.GetIntegrationSchemes``):
    the fixed-step ``runge_kutta2`` at ``plant_max_step_s`` is the default (the 100 Hz fitter
    sampling forces 10 ms steps anyway, and it needs 2 derivative evaluations per step where the
    error-controlled ``runge_kutta3`` needs 3; final positions agree to a millimetre over 30 s)."""


@dataclass
class CameraSettings:
    """Downward texture camera (``pcvfe_drake.perception.camera.CameraConfig``; None: the camera's default).

    The scenario defaults switch the realistic effects on: motion blur from a 2 ms exposure,
    per-frame exposure changes and sensor noise, all seeded from the scenario's seed.
    """

    height_m: float | None = None
    fov_deg: float | None = None
    width_px: int | None = None
    height_px: int | None = None
    forward_offset_m: float | None = None
    exposure_s: float | None = 0.002
    """Exposure time [s]; motion blur is ``v * exposure_s`` metres long."""
    exposure_jitter: float | None = 0.05
    """Standard deviation of the log exposure gain per frame."""
    noise_std: float | None = 3.0
    """Sensor noise standard deviation on the 0-255 scale."""


@dataclass
class FeatureSettings:
    """Feature extractor: ``backend`` is ``"descriptor"`` or the path of a CLIP model folder."""

    backend: str = DESCRIPTOR_BACKEND
    lambda_c: float = 0.25
    """Weight of the mean RGB appended to the similarity vector (paper eq. 4)."""
    clip_threads: int = 2
    """onnxruntime threads of the CLIP backend (1 is safer on a loaded 2-core machine)."""


@dataclass
class ClusteringSettings:
    """Context clustering (``pcvfe_drake.contexts.clustering.ClusteringParams``; None: its default).

    Durations are seconds of driving at the camera rate (converted to frame counts there).
    """

    min_cluster_duration_s: float | None = None
    min_samples_duration_s: float | None = None
    noise_memory_s: float | None = None
    max_stored: int | None = None
    gate_scale: float | None = None
    persistence_scale: float | None = None
    persistence_epsilon: float | None = None


@dataclass
class FitterSettings:
    """Context fitter (``pcvfe_drake.estimation.context_estimator.LiveFitConfig``; None: its default)."""

    horizon_steps: int | None = None
    """Rollout window length H in samples (paper eq. 5b-5c)."""
    stride_steps: int | None = None
    """Window start stride in samples."""
    min_speed_mps: float | None = None
    """Windows only from samples with v >= this speed (eq. 6)."""
    fit_stiffness: bool | None = None
    """Fit C_Sf, C_Sr too, with priors (see params.py); default: mu only."""
    min_windows: int | None = None
    """Fewer usable windows than this: the context keeps the prior."""
    buffer_s: float | None = None
    """Seconds of data kept per context."""
    noise_hold_s: float | None = None
    """Noise this long [s] after a known context keeps its estimate; then the prior."""


@dataclass
class NmpcSettings:
    """Friction-aware NMPC (``pcvfe_drake.control.nmpc.NmpcConfig``; None: its default)."""

    horizon_s: float | None = None
    """Prediction horizon [s] (steps = horizon_s / rates.nmpc_period_s)."""
    model: str | None = None
    """Prediction model: "st" (single track with theta_hat) or "ks" (kinematic baseline)."""
    speed_margin: float | None = None
    """Fraction of the friction-limited speed sqrt(mu_hat g / |kappa|) the reference uses."""
    max_speed_mps: float | None = None
    """Cap on the reference speed (None: the course's planned speed)."""


@dataclass
class Scenario:
    """One closed-loop run. Every field has a default; YAML files name only what they change."""

    name: str = DEFAULT_SCENARIO
    description: str = ""
    vehicle: str = "ford_escort"
    """Vehicle preset (see params.PRESETS) or a vehicle YAML file (relative to the scenario)."""
    course: str = "slalom"
    """Course name (see course.py)."""
    terrain_layout: str = "paper"
    """Terrain layout name (see terrain.py)."""
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
    camera: CameraSettings = field(default_factory=CameraSettings)
    features: FeatureSettings = field(default_factory=FeatureSettings)
    clustering: ClusteringSettings = field(default_factory=ClusteringSettings)
    fitter: FitterSettings = field(default_factory=FitterSettings)
    nmpc: NmpcSettings = field(default_factory=NmpcSettings)

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

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _is_number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def scenario_problems(scenario: Scenario) -> list[str]:
    """Every problem with the values of ``scenario``, as ``"field=value: reason"`` strings."""
    problems: list[str] = []

    def need(ok: bool, name: str, value, reason: str) -> None:
        if not ok:
            problems.append(f"{name}={value!r}: {reason}")

    s = scenario
    need(bool(s.name.strip()), "name", s.name, "must not be empty")
    need(bool(s.vehicle.strip()), "vehicle", s.vehicle, "must name a preset or a YAML file")
    need(bool(s.course.strip()), "course", s.course, "must name a course")
    need(bool(s.terrain_layout.strip()), "terrain_layout", s.terrain_layout, "must name a layout")
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
    for f in dataclasses.fields(Rates):
        if f.name in ("integrator", "clustering_frame_offset_s"):
            continue
        value = getattr(s.rates, f.name)
        need(_is_number(value) and value > 0, f"rates.{f.name}", value, "must be a period > 0 s")
    offset = s.rates.clustering_frame_offset_s
    need(
        _is_number(offset)
        and offset >= 0
        and (not _is_number(s.rates.camera_period_s) or offset < s.rates.camera_period_s),
        "rates.clustering_frame_offset_s",
        offset,
        "must be >= 0 s and shorter than rates.camera_period_s",
    )
    if _is_number(s.rates.camera_period_s) and _is_number(s.rates.recluster_period_s):
        need(
            s.rates.recluster_period_s >= s.rates.camera_period_s,
            "rates.recluster_period_s",
            s.rates.recluster_period_s,
            "must not be shorter than rates.camera_period_s",
        )
    for group in ("camera", "clustering", "fitter", "nmpc"):
        settings = getattr(s, group)
        for f in dataclasses.fields(settings):
            value = getattr(settings, f.name)
            if value is None or isinstance(value, bool | str):
                continue
            need(
                _is_number(value) and value >= 0,
                f"{group}.{f.name}",
                value,
                "must be a finite number >= 0",
            )
    if s.nmpc.model is not None:
        need(s.nmpc.model in ("st", "ks"), "nmpc.model", s.nmpc.model, "must be 'st' or 'ks'")
    need(bool(s.features.backend.strip()), "features.backend", s.features.backend, "empty")
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
    return problems


def shipped_scenarios() -> list[str]:
    """Names of the scenarios shipped in ``pcvfe_drake/data/scenarios``."""
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))


def resolve_scenario_path(path_or_name: str | Path | None) -> Path:
    """The YAML file of a scenario given as a file path or a shipped scenario name.

    None means the default scenario. Raises FileNotFoundError naming the input and the shipped
    scenarios when neither exists.
    """
    if path_or_name is None:
        path_or_name = DEFAULT_SCENARIO
    candidate = Path(path_or_name).expanduser()
    if candidate.is_file():
        return candidate.resolve()
    shipped = SCENARIO_DIR / f"{path_or_name}.yaml"
    if shipped.is_file():
        return shipped
    raise FileNotFoundError(
        f"scenario {str(path_or_name)!r} is neither a file nor a shipped scenario "
        f"(shipped: {', '.join(shipped_scenarios())})"
    )


# ------------------------------------------------------------------ building from a scenario
TERRAIN_LAYOUTS: dict[str, dict] = {
    "paper": {},
    "paper_small": {"strip_width_m": 0.6},
    "paper_no_strips": {"strip_width_m": 0.0},
}
"""Terrain layouts by name: keyword arguments of ``terrain.default_terrain_map``. ``paper`` is
the paper's four quadrants with 3 m transition strips; ``paper_small`` the same with 0.6 m
strips for the 1/5-scale course; ``paper_no_strips`` without strips."""

TRANSITION_TERRAINS = ("gravel", "dry_soil")
"""Terrains of the paper layouts' transition strips: left out of the context scores."""


def build_terrain_map(scenario: Scenario):
    """The scenario's ``TerrainMap``; unknown layout names raise ValueError listing the known."""
    from pcvfe_drake.perception.terrain import default_terrain_map

    layout = scenario.terrain_layout
    if layout not in TERRAIN_LAYOUTS:
        raise ValueError(
            f"scenario {scenario.name!r}: terrain_layout={layout!r} is unknown "
            f"(known: {', '.join(sorted(TERRAIN_LAYOUTS))})"
        )
    return default_terrain_map(**TERRAIN_LAYOUTS[layout])


def excluded_terrains(scenario: Scenario) -> tuple[str, ...]:
    """Terrain names left out of the context scores (the layout's transition strips)."""
    if TERRAIN_LAYOUTS.get(scenario.terrain_layout, {}).get("strip_width_m", 1.0) == 0.0:
        return ()
    return TRANSITION_TERRAINS


def settings_kwargs(settings) -> dict:
    """The fields of a settings dataclass that are set (not None), as keyword arguments."""
    return {
        f.name: getattr(settings, f.name)
        for f in dataclasses.fields(settings)
        if getattr(settings, f.name) is not None
    }
