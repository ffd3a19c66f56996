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

SCENARIO_DIR = Path(__file__).resolve().parent / "data" / "scenarios"
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
    log_period_s: float = 0.1
    """Period of the run log rows appended to the drive log."""
    plant_max_step_s: float = 0.01
    """Largest integrator step of the continuous plant."""


@dataclass
class CameraSettings:
    """Downward texture camera (sizes in pixels and metres)."""

    width_px: int = 224
    height_px: int = 224
    ground_size_m: float = 1.0
    """Side of the ground square seen by the camera [m]."""
    motion_blur: bool = True
    """Blur along the direction of travel, growing with speed."""
    noise_std: float = 0.01
    """Sensor noise standard deviation (image values in [0, 1])."""
    exposure_jitter: float = 0.05
    """Relative exposure change per frame (standard deviation)."""


@dataclass
class FeatureSettings:
    """Feature extractor: ``backend`` is ``"descriptor"`` or the path of a CLIP model folder."""

    backend: str = DESCRIPTOR_BACKEND
    lambda_c: float = 0.25
    """Weight of the mean RGB appended to the similarity vector (paper eq. 4)."""


@dataclass
class ClusteringSettings:
    """Context clustering (paper section IV-A, Algorithm 1); sizes in seconds of driving."""

    min_cluster_size_s: float = 3.0
    """Smallest cluster, in seconds of frames at the camera rate."""
    epsilon: float = 0.0
    """Centroid persistence threshold of Algorithm 1 (0: the clustering's own default)."""
    outlier_gate: float = 0.0
    """Gate of the online assignment between re-clusterings (0: the clustering's own default)."""


@dataclass
class FitterSettings:
    """Context fitter (paper eq. 5a-5d)."""

    horizon_steps: int = 10
    """Rollout window length H in samples."""
    stride_steps: int = 5
    """Window start stride in samples."""
    min_speed_mps: float = 1.0
    """Windows only from samples with v >= this speed (eq. 6)."""
    fit_stiffness: bool = False
    """Fit C_Sf, C_Sr too (needs priors, see params.py); default: mu only."""
    state_noise_std: float = 0.0
    """Standard deviation of the measurement noise added to the state the fitter sees (0: none)."""


@dataclass
class NmpcSettings:
    """Friction-aware NMPC."""

    horizon_s: float = 2.0
    """Prediction horizon [s]."""
    speed_margin: float = 0.8
    """Fraction of the friction-limited speed sqrt(mu_hat g / |kappa|) the reference uses."""
    max_speed_mps: float = 0.0
    """Cap on the reference speed (0: the course's own)."""


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
    need(
        _is_number(s.initial_speed_mps) and s.initial_speed_mps >= 0,
        "initial_speed_mps",
        s.initial_speed_mps,
        "must be >= 0",
    )
    for f in dataclasses.fields(Rates):
        value = getattr(s.rates, f.name)
        need(_is_number(value) and value > 0, f"rates.{f.name}", value, "must be a period > 0 s")
    if _is_number(s.rates.camera_period_s) and _is_number(s.rates.recluster_period_s):
        need(
            s.rates.recluster_period_s >= s.rates.camera_period_s,
            "rates.recluster_period_s",
            s.rates.recluster_period_s,
            "must not be shorter than rates.camera_period_s",
        )
    c = s.camera
    need(isinstance(c.width_px, int) and c.width_px >= 8, "camera.width_px", c.width_px, ">= 8")
    need(isinstance(c.height_px, int) and c.height_px >= 8, "camera.height_px", c.height_px, ">= 8")
    need(
        _is_number(c.ground_size_m) and c.ground_size_m > 0,
        "camera.ground_size_m",
        c.ground_size_m,
        "must be > 0",
    )
    need(_is_number(c.noise_std) and c.noise_std >= 0, "camera.noise_std", c.noise_std, ">= 0")
    need(
        _is_number(c.exposure_jitter) and c.exposure_jitter >= 0,
        "camera.exposure_jitter",
        c.exposure_jitter,
        "must be >= 0",
    )
    need(bool(s.features.backend.strip()), "features.backend", s.features.backend, "empty")
    need(
        _is_number(s.features.lambda_c) and s.features.lambda_c >= 0,
        "features.lambda_c",
        s.features.lambda_c,
        "must be >= 0",
    )
    k = s.clustering
    need(
        _is_number(k.min_cluster_size_s) and k.min_cluster_size_s > 0,
        "clustering.min_cluster_size_s",
        k.min_cluster_size_s,
        "must be > 0",
    )
    need(_is_number(k.epsilon) and k.epsilon >= 0, "clustering.epsilon", k.epsilon, ">= 0")
    need(
        _is_number(k.outlier_gate) and k.outlier_gate >= 0,
        "clustering.outlier_gate",
        k.outlier_gate,
        "must be >= 0",
    )
    fz = s.fitter
    need(
        isinstance(fz.horizon_steps, int) and fz.horizon_steps >= 1,
        "fitter.horizon_steps",
        fz.horizon_steps,
        "must be an integer >= 1",
    )
    need(
        isinstance(fz.stride_steps, int) and fz.stride_steps >= 1,
        "fitter.stride_steps",
        fz.stride_steps,
        "must be an integer >= 1",
    )
    need(
        _is_number(fz.min_speed_mps) and fz.min_speed_mps >= 0,
        "fitter.min_speed_mps",
        fz.min_speed_mps,
        "must be >= 0",
    )
    need(
        _is_number(fz.state_noise_std) and fz.state_noise_std >= 0,
        "fitter.state_noise_std",
        fz.state_noise_std,
        "must be >= 0",
    )
    n = s.nmpc
    need(_is_number(n.horizon_s) and n.horizon_s > 0, "nmpc.horizon_s", n.horizon_s, "> 0")
    need(
        _is_number(n.speed_margin) and 0 < n.speed_margin <= 1,
        "nmpc.speed_margin",
        n.speed_margin,
        "must be in (0, 1]",
    )
    need(
        _is_number(n.max_speed_mps) and n.max_speed_mps >= 0,
        "nmpc.max_speed_mps",
        n.max_speed_mps,
        "must be >= 0 (0: the course's own)",
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
