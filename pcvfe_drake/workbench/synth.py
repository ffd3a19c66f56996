"""Synthetic drive logs from a richer truth than the ST model, with planted effects.

The truth plant here is written independently of the workbench's effect code (plain per-axle
forces, a true dead-time on the command history, the lag as an ODE state, a brush tire), so
that recovering a planted parameter is a real test of the workbench and not of one function
against itself.

Driving (the excitation), chosen so every library effect is identifiable:

* speed: segments of 3-7 s alternating between accelerating to a new target speed (targets
  5-25 m/s, so v^2 varies ~25x and drag separates from rolling resistance), braking to a lower
  one, cruising, and coasting (zero command: the deceleration is then drag + rolling
  resistance alone). A proportional speed controller produces step-like changes of the
  acceleration command, which reveal a dead time;
* steering: sinusoidal sweeps whose frequency changes per segment (0.15-0.6 Hz, phase lag
  reveals a steering lag) and whose amplitude targets a lateral acceleration that changes per
  segment (targets alternating low and high between 0.5 and 6.5 m/s^2, so every ~12 s has
  both; halved while braking): small slips fix the cornering stiffness, large ones the
  friction peak. A slow mean turn (0.07 rad/s) sweeps the heading through all directions,
  which separates a road grade from rolling resistance. The driver counter-steers on side
  slip. The steering rate stays inside the vehicle's limit.

Measurement noise (``pcvfe_drake.models.synthetic_drive.SURVEY_INS_NOISE``, a
``MeasurementNoise``): independent Gaussian noise per state with the accuracy of a survey-grade
GNSS/INS (e.g. a dual-antenna RTK INS) and a steering encoder; inputs are the recorded commands
and are noise-free.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pcvfe_drake.vehicle.measurement_noise import SURVEY_INS_NOISE, MeasurementNoise
from pcvfe_drake.vehicle.params import VehicleParams, load_vehicle
from pcvfe_drake.workbench import synth_kernel


@dataclass(frozen=True)
class Truth:
    """Physical truth of a synthetic drive (defaults: exactly the ST model).

    Attributes:
        mu: friction coefficient scaling the cornering stiffness (None: the vehicle's).
        CdA: drag area [m^2].
        c_rr: rolling resistance coefficient [-].
        steer_tau: steering lag time constant [s] (0: none).
        accel_delay: dead time of the acceleration command [s].
        mu_peak: peak friction of a brush tire (inf: linear tire).
        grade: road rise per metre along world x and y [-].
        p_max_kw: drive power limit [kW] (inf: none).
        steer_offset: steering-encoder offset: wheel angle minus measured angle [rad].
        gyro_bias: yaw-rate gyro bias (measured minus true) [rad/s].
        speed_scale: speed sensor reading / true speed [-].
        mu_speed_slope: friction falls by this fraction per m/s above 15 m/s [s/m].
        mu_load_sens: friction falls by this fraction per unit relative axle-load increase.
        mf_peak: peak friction of a magic-formula tire (inf: none): the lateral force is
            ``D sin(C atan(K alpha / (C D)))`` with ``D = mf_peak Fz`` and the stiffness
            ``K = mu C_S Fz (mf_peak / mu)^mf_stiffness_exponent`` (friction factors of
            speed and load scale both).
        mf_shape: its shape factor C [-].
        mf_stiffness_exponent: how its stiffness follows the peak (0: not at all) [-].
        axle_stiffness: factors on the front and rear cornering stiffness [-].
        rotating_mass_kg: rotating mass equivalent of the wheels [kg]: the car accelerates
            by ``a m / (m + m_rot)`` for a command ``a``.
        front_forces: (drive share, brake share, drag factor): the front wheels push with
            ``m a share`` along their heading (``sin(delta)`` of it sideways) and the front
            lateral force brakes the car by ``factor F_yf sin(delta)``.
        pitch_mode: (time constant tau [s], damping ratio [-]) of the body's pitch: the axle
            loads follow the car's longitudinal acceleration through
            ``tau^2 q'' + 2 zeta tau q' + q = a_x`` (tau 0: instantly).
        roll_camber: (f0 [-], f1 [-], s0 [rad]) of wheels cambered by roll: with the
            steady lateral acceleration ``a = v r`` and the cornering direction
            ``c = tanh(a / 0.5 m/s^2)`` every tyre sees the slip ``alpha + s0 c`` and gets
            the side force ``Fz (f0 c + f1 a / g)`` on top of its law.
        track: (t_f [m], t_r [m], k_lt [-]): the front and rear axles' two wheels ``t``
            apart, each at its own slip (the axle's velocities at the wheels), the outer one
            with ``(1 + k_lt v r / g) / 2`` of the axle's load; the axle's force is their sum.
        wheel_camber: (f0 [-], s0 [rad], k_xf [-], k_xr [-], tau [s]): each wheel's camber
            sign ``tanh((a_roll +- k_x a_x) / 0.1 m/s^2)`` (left +, right -; ``a_roll`` the
            lateral acceleration ``(F_yf + F_yr) / m`` lagged by ``tau``, ``a_x`` the
            longitudinal one): the wheel sees the slip ``alpha + s0 sign`` and the axle gets
            ``Fz f0`` times the mean of its wheels' signs on top (f0 = s0 = 0: none).
    """

    mu: float | None = None
    CdA: float = 0.0
    c_rr: float = 0.0
    steer_tau: float = 0.0
    accel_delay: float = 0.0
    mu_peak: float = math.inf
    grade: tuple[float, float] = (0.0, 0.0)
    p_max_kw: float = math.inf
    steer_offset: float = 0.0
    gyro_bias: float = 0.0
    speed_scale: float = 1.0
    mu_speed_slope: float = 0.0
    mu_load_sens: float = 0.0
    mf_peak: float = math.inf
    mf_shape: float = 1.35
    mf_stiffness_exponent: float = 0.0
    axle_stiffness: tuple[float, float] = (1.0, 1.0)
    rotating_mass_kg: float = 0.0
    front_forces: tuple[float, float, float] = (0.0, 0.0, 0.0)
    pitch_mode: tuple[float, float] = (0.0, 0.3)
    roll_camber: tuple[float, float, float] = (0.0, 0.0, 0.0)
    track: tuple[float, float, float] = (0.0, 0.0, 0.0)
    wheel_camber: tuple[float, float, float, float, float] = (0.0, 0.0, 0.39, -0.095, 0.08)


PLANTED: dict[str, tuple[Truth, str, float]] = {
    "drag": (Truth(CdA=0.75), "CdA", 0.75),
    "rolling_resistance": (Truth(c_rr=0.015), "c_rr", 0.015),
    "steering_lag": (Truth(steer_tau=0.15), "tau", 0.15),
    "input_delay": (Truth(accel_delay=0.17), "T", 0.17),
    "tire_saturation": (Truth(mu_peak=0.8), "mu_peak", 0.8),
    "grade": (Truth(grade=(0.03, -0.02)), "gx", 0.03),
    "motor_power_limit": (Truth(p_max_kw=40.0), "P_max", 40.0),
    "steering_offset": (Truth(steer_offset=0.01), "d0", 0.01),
    "gyro_bias": (Truth(gyro_bias=0.005), "b", 0.005),
    "speed_scale": (Truth(speed_scale=1.03), "k", 1.03),
    "friction_speed": (Truth(mu_speed_slope=0.03), "k_v", 0.03),
    "friction_load": (Truth(mu_load_sens=0.5), "k_z", 0.5),
    "peak_tyre": (Truth(mf_peak=0.7), "k_s", 0.0),
    "axle_stiffness": (Truth(axle_stiffness=(0.93, 1.12)), "k_r", 1.12),
    "rotating_inertia": (Truth(rotating_mass_kg=60.0), "m_rot", 60.0),
    "wheel_force_steer": (Truth(front_forces=(1.0, 0.76, 1.0)), "k_drag", 1.0),
    "suspension_lag": (Truth(pitch_mode=(0.125, 0.2)), "tau", 0.125),
    "roll_camber": (Truth(roll_camber=(-0.037, -0.08, 0.0)), "f1", -0.08),
    "track_slip": (Truth(track=(1.39, 1.42, 0.0)), "t", 1.39),
    "wheel_camber": (Truth(wheel_camber=(-0.037, 0.0, 0.39, -0.095, 0.08)), "k_xf", 0.39),
}
"""Realistic planted magnitudes per effect: (truth, the parameter's name, its planted value).
Ford Escort class car: CdA 0.75 m^2 (Cd 0.36 x 2.1 m^2), c_rr 0.015, steering lag 0.15 s,
powertrain dead time 0.17 s, peak friction 0.8 (damp asphalt), 3 % / -2 % grade,
40 kW drive power, 0.01 rad (0.6 deg) steering-encoder offset, 0.005 rad/s (0.3 deg/s) gyro
bias, a 3 % speed-sensor scale error, friction falling 3 % per m/s of speed (wet asphalt), a load
sensitivity of 0.5, a magic-formula tyre (shape 1.35) whose friction peak is 0.7 (wet asphalt)
with the nominal small-slip stiffness (stiffness exponent 0: the public PC-VFE simulator's
friction mapping; its planted value is 0, so it is checked with an absolute tolerance), axle
cornering stiffnesses 0.93 / 1.12 x nominal, a 60 kg rotating mass and front wheels taking all
the drive and 76 % of the brake force, turned with the steering (CommonRoad's Ford Escort;
the values the workbench reads on its multi-body model), and a pitch mode of 1.27 Hz with
damping ratio 0.2 (tau 0.125 s; near the multi-body Ford Escort's 1.4 Hz and 0.22, fitted to a
braking step by ``studies/mb_suspension/mb_suspension.py``), and roll camber: a camber thrust of -8
% of the load per g of lateral acceleration (wheels leaning out with the body's roll, ~0.1 rad per
g, on a tyre with a camber stiffness of ~0.8 Fz per rad; checked: ``f1``) and a step side
force of -3.7 % of the load switching with the cornering direction (CommonRoad's multi-body
tyre: ``p_vy1`` by the camber's sign); its slip shift is not planted: on the linear tyre it is
the same as a force), and that step per wheel (``wheel_camber``: -3.7 % of the load by each
wheel's camber sign, the camber geometry of the multi-body Ford Escort, ``k_xf`` 0.39, ``k_xr``
-0.095, roll lag 0.08 s; checked: ``k_xf``, as ``f0`` and the unplanted slip shift are one force
on the linear tyre)."""


LATERAL_PATTERN_MPS2 = np.array([1.0, 5.5, 2.5, 6.0, 3.5, 5.0])
"""Cycle of lateral-acceleration targets of the steering sweep segments [m/s^2]."""
HEADING_RATE_RADPS = 0.07
"""Mean yaw rate of the driving program [rad/s]: one full turn of the heading in ~90 s."""
COUNTER_STEER = 1.0
"""Steering angle [rad] the driver adds per radian of side slip (steering into a slide)."""
BACK_OFF_SLIP_RAD = 0.06
BRAKE_CIRCLE_MPS2 = 6.0
"""The driver keeps braking and lateral acceleration inside a circle of this radius [m/s^2]."""
"""Side slip [rad] above which the driver reduces the steering sweep (to 20 % at +0.048 rad)."""


@dataclass(frozen=True)
class Excitation:
    """Driving program at the log rate: speed targets, coasting flags and steering sweep."""

    v_ref: np.ndarray
    coast: np.ndarray
    phase: np.ndarray
    freq_hz: np.ndarray
    lat_target: np.ndarray


def design_excitation(
    vehicle: VehicleParams, duration_s: float, dt: float, seed: int = 0, v_ref_factor: float = 1.0
) -> Excitation:
    """The driving program described in the module docstring (deterministic in ``seed``);
    ``v_ref_factor`` scales its speed targets (below 1: slow, tight bends)."""
    rng = np.random.default_rng(seed)
    n = int(round(duration_s / dt)) + 1
    t = np.arange(n) * dt
    v_ref = np.empty(n)
    coast = np.zeros(n, bool)
    kinds = ["accelerate", "coast", "brake", "accelerate", "cruise", "brake", "coast"]
    k, i, target = 0, 0, 12.0
    while i < n:
        length = int(rng.uniform(3.0, 7.0) / dt)
        kind = kinds[k % len(kinds)]
        if kind == "accelerate":
            target = rng.uniform(max(target + 3.0, 14.0), 25.0)
        elif kind == "brake":
            target = rng.uniform(5.0, max(6.0, target - 4.0))
        v_ref[i : i + length] = target
        coast[i : i + length] = kind == "coast"
        i += length
        k += 1
    # steering sweep: per-segment frequency and lateral-acceleration target, smoothly joined
    seg = int(6.0 / dt)
    n_seg = n // seg + 2
    freq_knots = rng.uniform(0.15, 0.6, n_seg)
    # lateral-acceleration targets alternate low and high (plus jitter) so that every
    # stretch of ~12 s, training or held-out, has both small and large tire slips
    lat_knots = np.resize(LATERAL_PATTERN_MPS2, n_seg) + rng.uniform(-0.5, 0.5, n_seg)
    knots_t = np.arange(n_seg) * seg * dt
    freq = np.interp(t, knots_t, freq_knots)
    lat = np.interp(t, knots_t, lat_knots)
    phase = 2.0 * np.pi * np.cumsum(freq) * dt
    return Excitation(v_ref * v_ref_factor, coast, phase, freq, lat)


def driver_commands(
    vp: VehicleParams, ex: Excitation, k: int, x: np.ndarray, grip_scale: float = 1.0
):
    """Commands (steer_rate (B,), accel (B,)) of the driving program at sample k for true
    single-track states x (B, 7): a steering sweep tracked by a P loop and a P speed loop.
    ``grip_scale`` scales the lateral-acceleration targets, the braking circle and (below 1) the
    largest braking and driving accelerations (a driver
    who knows the surface drives each one as close to its limit)."""
    v = x[:, 3]
    wheelbase = vp.lf + vp.lr
    steer_limit = 0.95 * min(abs(vp.delta_dot_min), vp.delta_dot_max)
    lat_target = grip_scale * ex.lat_target[k]
    amp = np.minimum(lat_target * wheelbase / np.maximum(v, 4.0) ** 2, 0.3)
    # like a driver, corner less while braking hard (avoids spinning a saturated car)
    braking = (~ex.coast[k]) & (ex.v_ref[k] < v - 2.0)
    amp = np.where(braking, 0.5 * amp, amp)
    # and back off the sweep when the car starts to slide (|beta| above 0.06 rad)
    amp = amp * np.clip(1.0 - (np.abs(x[:, 6]) - BACK_OFF_SLIP_RAD) / 0.06, 0.2, 1.0)
    # a slow turn (HEADING_RATE) on top, so that the heading sweeps through all directions,
    # and a counter-steer: the wheels turn toward the direction of travel (psi + beta), as a
    # driver catching a slide
    d_des = (
        amp * np.sin(ex.phase[k])
        + wheelbase * HEADING_RATE_RADPS / np.maximum(v, 4.0)
        + COUNTER_STEER * x[:, 6]
    )
    d_rate = amp * 2.0 * np.pi * ex.freq_hz[k] * np.cos(ex.phase[k])
    steer = np.clip(d_rate + 3.0 * (d_des - x[:, 2]), -steer_limit, steer_limit)
    # brake within a friction circle: less braking while cornering hard
    lat = np.abs(v * x[:, 5])
    circle = grip_scale * BRAKE_CIRCLE_MPS2
    brake_max = np.clip(np.sqrt(np.maximum(circle**2 - lat**2, 0.0)), 1.0, 3.5 * min(grip_scale, 1))
    acc = np.where(
        ex.coast[k], 0.0, np.clip(0.8 * (ex.v_ref[k] - v), -brake_max, 2.5 * min(grip_scale, 1.0))
    )
    return steer, acc


def _truth_rates(vp, tr, s, steer_cmd, acc_cmd):
    """Truth plant derivative (B, columns of s); s = (B, 11) [sx, sy, delta, v, psi, r, beta,
    delta_w, q, q', a_roll] (q: the acceleration the axle loads follow through the pitch mode;
    rows without a pitch mode use a_x itself; a_roll: the lagged lateral acceleration the
    wheels' cambers follow; s may stop after 8 or 10 columns: no pitch mode, no wheel camber);
    ``tr`` the truths' columns by name (:func:`truth_columns`; a column left out takes its
    null value). The physics: the compiled kernel (``synth_kernel.rates``), one row each."""
    s = np.ascontiguousarray(s, dtype=float)
    out = np.empty_like(s)
    n = s.shape[0]
    steer = np.broadcast_to(np.asarray(steer_cmd, dtype=float), (n,)).copy()
    acc = np.broadcast_to(np.asarray(acc_cmd, dtype=float), (n,)).copy()
    synth_kernel.rates_rows(s, steer, acc, truth_matrix(tr, n), vehicle_vector(vp), out)
    return out


def truth_matrix(tr: dict[str, np.ndarray], n: int) -> np.ndarray:
    """The columns ``tr`` (by name) as the kernel's (n, columns) matrix, in the order of
    ``synth_kernel.TRUTH_COLUMNS``; a column left out takes its null value."""
    unknown = set(tr) - {name for name, _ in synth_kernel.TRUTH_COLUMNS}
    if unknown:
        raise KeyError(f"not truth columns: {sorted(unknown)}")
    if "mu" not in tr:
        raise KeyError("the truth columns must give mu")
    return np.ascontiguousarray(
        np.stack(
            [
                np.broadcast_to(np.asarray(tr.get(name, null), dtype=float), (n,))
                for name, null in synth_kernel.TRUTH_COLUMNS
            ],
            axis=1,
        )
    )


def vehicle_vector(vp: VehicleParams) -> np.ndarray:
    """The vehicle's parameters the kernel reads (``synth_kernel.VEHICLE_FIELDS``)."""
    return np.array([float(getattr(vp, name)) for name in synth_kernel.VEHICLE_FIELDS])


def truth_columns(vp: VehicleParams, truths: list[Truth]) -> dict[str, np.ndarray]:
    """The truths' parameters as the columns :func:`_truth_rates` reads: one array per key, an
    entry per truth (``mu`` None becomes the vehicle's)."""

    def col(fn):
        return np.array([fn(t) for t in truths], dtype=float)

    return {
        "mu": col(lambda t: vp.mu if t.mu is None else t.mu),
        "CdA": col(lambda t: t.CdA),
        "c_rr": col(lambda t: t.c_rr),
        "steer_tau": col(lambda t: t.steer_tau),
        "mu_peak": col(lambda t: t.mu_peak),
        "gx": col(lambda t: t.grade[0]),
        "gy": col(lambda t: t.grade[1]),
        "p_max_kw": col(lambda t: t.p_max_kw),
        "mu_speed_slope": col(lambda t: t.mu_speed_slope),
        "mu_load_sens": col(lambda t: t.mu_load_sens),
        "mf_peak": col(lambda t: t.mf_peak),
        "mf_shape": col(lambda t: t.mf_shape),
        "mf_exp": col(lambda t: t.mf_stiffness_exponent),
        "k_f": col(lambda t: t.axle_stiffness[0]),
        "k_r": col(lambda t: t.axle_stiffness[1]),
        "m_rot": col(lambda t: t.rotating_mass_kg),
        "ff_drive": col(lambda t: t.front_forces[0]),
        "ff_brake": col(lambda t: t.front_forces[1]),
        "ff_drag": col(lambda t: t.front_forces[2]),
        "pitch_tau": col(lambda t: t.pitch_mode[0]),
        "pitch_zeta": col(lambda t: t.pitch_mode[1]),
        "cam_f0": col(lambda t: t.roll_camber[0]),
        "cam_f1": col(lambda t: t.roll_camber[1]),
        "cam_s0": col(lambda t: t.roll_camber[2]),
        "track_f": col(lambda t: t.track[0]),
        "track_r": col(lambda t: t.track[1]),
        "track_k_lt": col(lambda t: t.track[2]),
        "wcam_f0": col(lambda t: t.wheel_camber[0]),
        "wcam_s0": col(lambda t: t.wheel_camber[1]),
        "wcam_kf": col(lambda t: t.wheel_camber[2]),
        "wcam_kr": col(lambda t: t.wheel_camber[3]),
        "wcam_tau": col(lambda t: t.wheel_camber[4]),
    }


def simulate_truths(
    truths: list[Truth],
    vehicle: VehicleParams | str | None = None,
    duration_s: float = 120.0,
    rate_hz: float = 20.0,
    seed: int = 0,
    noise: MeasurementNoise | None = SURVEY_INS_NOISE,
    substeps: int = 5,
    v0_mps: float = 10.0,
    v_ref_factor: float = 1.0,
    noise_seeds: list[int] | None = None,
) -> list[pd.DataFrame]:
    """Drive logs (drive-log DataFrames) of several truths at once, same driving program.

    The commands are computed at the log rate by the speed controller and steering tracker
    from each plant's true state and held until the next sample; the plant is integrated with
    RK4 at ``substeps`` steps per sample (the compiled ``synth_kernel.advance``; each truth is
    its own plant, so a log is the same in any batch). Noise seeds differ per log
    (``seed + 1 + i``, or ``noise_seeds[i]``: a log keeps its noise in another batch).
    ``v_ref_factor`` scales the program's speed targets (``design_excitation``).
    """
    if noise_seeds is not None and len(noise_seeds) != len(truths):
        raise ValueError(
            f"simulate_truths: {len(noise_seeds)} noise seeds for {len(truths)} truths"
        )
    vp = vehicle if isinstance(vehicle, VehicleParams) else load_vehicle(vehicle)
    dt = 1.0 / rate_hz
    ex = design_excitation(vp, duration_s, dt, seed, v_ref_factor)
    n = ex.v_ref.size
    b = len(truths)

    q = truth_matrix(truth_columns(vp, truths), b)
    vv = vehicle_vector(vp)
    delay = np.array([t.accel_delay for t in truths], dtype=float)
    s = np.zeros((b, 11))
    s[:, 3] = v0_mps
    states = np.empty((n, b, 7))
    steer_log = np.empty((n, b))
    acc_log = np.empty((n, b))
    for k in range(n):
        states[k] = s[:, :7]
        steer_log[k], acc_log[k] = driver_commands(vp, ex, k, s[:, :7])
        if k == n - 1:
            break
        synth_kernel.advance(s, q, vv, steer_log[k], acc_log, delay, k, dt, substeps)
        if not np.all(np.isfinite(s)):
            raise RuntimeError(f"truth simulation diverged at t={k * dt:.2f} s")
    seeds = [seed + 1 + i for i in range(b)] if noise_seeds is None else list(noise_seeds)
    return [
        _to_log(states[:, i], steer_log[:, i], acc_log[:, i], dt, noise, seeds[i], truths[i])
        for i in range(b)
    ]


MB_GRIP_FRACTION = 0.85
"""The multi-body driver's largest lateral-acceleration target as a fraction of mu g (the
excitation's pattern, 1.0-6.5 m/s^2, is scaled to reach it on every surface)."""


def simulate_multibody(
    vehicle: str = "ford_escort",
    duration_s: float = 60.0,
    rate_hz: float = 20.0,
    seed: int = 0,
    noise: MeasurementNoise | None = SURVEY_INS_NOISE,
    mu: float | None = None,
    v0_mps: float = 10.0,
    friction_mapping: str = "peak_and_stiffness",
    terrains: dict[str, float] | None = None,
    segment_s: float = 10.0,
    grip_fraction: float | None = None,
) -> pd.DataFrame:
    """A drive log of CommonRoad's multi-body model (``pcvfe_drake.vehicle.mb_truth.MbTruth``:
    Pacejka tires with combined slip, load transfer, suspension, wheel spin) under the same
    driving program, integrated with LSODA between samples.

    Args:
        friction_mapping: what a terrain's mu changes in the MB tyre
            (``mb_truth.FRICTION_SCALINGS``: ``peak_and_stiffness``, ``peak``,
            ``lateral_peak``).
        mu: one friction level for the whole log (default: the tyre's nominal 1.0489).
        terrains: instead, ``{name: mu}``: the car drives ``segment_s`` on each in turn
            (cycling), and the log gets a ``terrain`` column (one workbench context each).
        grip_fraction: the driver scales the excitation's lateral-acceleration targets so
            that the largest is this fraction of ``mu g`` on each surface, and brakes within
            the same fraction (None: the planted-effect program unscaled when ``mu`` and
            ``terrains`` are None, else ``MB_GRIP_FRACTION``).
    """
    from pcvfe_drake.vehicle.mb_truth import MbTruth, st_state

    vp = load_vehicle(vehicle)
    truth = MbTruth(vehicle, friction_scaling=friction_mapping)
    if terrains is not None and mu is not None:
        raise ValueError("simulate_multibody: give mu or terrains, not both")
    if terrains is not None and not terrains:
        raise ValueError("simulate_multibody: terrains must name at least one surface")
    scaled = grip_fraction is not None or mu is not None or terrains is not None
    fraction = MB_GRIP_FRACTION if grip_fraction is None else float(grip_fraction)
    surfaces = (
        dict(terrains)
        if terrains is not None
        else {"": truth.mu_nominal if mu is None else float(mu)}
    )
    names = list(surfaces)
    dt = 1.0 / rate_hz
    ex = design_excitation(vp, duration_s, dt, seed)
    n = ex.v_ref.size
    seg = max(1, int(round(segment_s / dt)))
    surface = np.array([names[(k // seg) % len(names)] for k in range(n)])
    top = float(np.max(LATERAL_PATTERN_MPS2)) + 0.5
    x_mb = truth.initial_state(np.array([0.0, 0.0, 0.0, v0_mps, 0.0, 0.0, 0.0]))
    states = np.empty((n, 7))
    steer_log = np.empty(n)
    acc_log = np.empty(n)
    for k in range(n):
        mu_k = surfaces[surface[k]]
        grip = fraction * mu_k * vp.g / top if scaled else 1.0
        states[k] = st_state(x_mb)
        steer, acc = driver_commands(vp, ex, k, states[k][None, :], grip)
        steer_log[k], acc_log[k] = steer[0], acc[0]
        if k < n - 1:
            x_mb = truth.integrate(x_mb, [steer_log[k], acc_log[k]], mu_k, dt)
    df = _to_log(states, steer_log, acc_log, dt, noise, seed + 101)
    if terrains is not None:
        df["terrain"] = surface
    return df


def _to_log(states, steer, acc, dt, noise, seed, truth: Truth | None = None) -> pd.DataFrame:
    n = states.shape[0]
    t = np.arange(n) * dt
    x = states.copy()
    if truth is not None:  # sensor errors: what the sensors report about the true state
        x[:, 2] = x[:, 2] - truth.steer_offset
        x[:, 3] = x[:, 3] * truth.speed_scale
        x[:, 5] = x[:, 5] + truth.gyro_bias
    if noise is not None:
        rng = np.random.default_rng(seed)
        x = x + rng.standard_normal(x.shape) * noise.sigma
    x[:, 4] = np.pi - np.mod(np.pi - x[:, 4], 2.0 * np.pi)
    return pd.DataFrame(
        {
            "t": t,
            "sx": x[:, 0],
            "sy": x[:, 1],
            "delta": x[:, 2],
            "v": x[:, 3],
            "psi": x[:, 4],
            "psi_dot": x[:, 5],
            "beta": x[:, 6],
            "steer_rate": steer,
            "accel": acc,
        }
    )
