"""Friction-aware model predictive path tracking: a real-time-iteration LTV QP solved with OSQP.

Formulation (one controller update, period ``dt_s``; see ``docs/nmpc.md``)
--------------------------------------------------------------------------
States are **world-frame ST states** (``pcvfe_drake.vehicle.single_track`` order) predicted over
``horizon``
steps of ``dt_s`` (default 40 x 0.05 s = 2 s). Each update is one real-time iteration (RTI) of
sequential quadratic programming in multiple-shooting form:

1. *Linearisation trajectory* ``(xbar_k, ubar_k)``: the previous optimal plan shifted by one step
   (``xbar_0`` replaced by the measured state), or, on a cold start, the course's reference
   states driven at the planned speed.
2. *Reference*: each predicted position ``xbar_k`` (k >= 1) is projected onto the course, giving
   the arc length s_k, the path normal n_k, heading and curvature. The lateral error
   ``e_k = n_k . (p_k - c_k)`` is then linear in the position (exact to first order), so the cost
   penalises only the cross-track component and longitudinal progress is left to speed tracking
   against the friction-limited speed profile ``v_ref(s_k)`` (``course.speed_profile`` with the
   friction the controller believes).
3. *Dynamics*: exact Jacobians ``A = df/dx``, ``B = df/du`` of the prediction model (the ST model
   with theta_hat, ``st_jacobians``, or a kinematic single-track model for the KMPC baseline),
   evaluated in one batched call over the horizon at speeds clamped to >= ``v_lin_min_mps``, and
   discretised exactly for a zero-order-held input with the matrix exponential of the augmented
   matrix ``[[A, B, f], [0, 0, 0]] dt`` (one batched ``expm``). The ST model's yaw/slip modes
   scale like 1/v (Ford Escort: about -215 1/s at 1 m/s), so an explicit RK4 step of 50 ms is
   unstable below about 4 m/s; the exponential is exact for the linear model at every speed and
   costs about a third of four RK4 sub-steps with Jacobians.
4. *QP* in deviations ``dz = (dx_0..dx_N, du_0..du_{N-1}, slacks)`` with
   ``dx_{k+1} = Ad_k dx_k + Bd_k du_k + (defect)``, ``dx_0 = 0``; bounds on steering rate,
   acceleration (CommonRoad's limits) and steering angle; a soft friction polygon per stage
   (8 half-planes of radius ``friction_margin * mu_hat * g`` around the linearised
   ``(a_x, a_y) = (accel, v * psi_dot)``); a soft corridor ``|e_k| <= corridor_fraction *
   half_width``. Slacks carry linear and quadratic penalties, so the QP is always feasible.
   Cost: lateral error, course-angle error (``psi + beta`` vs path heading), speed error,
   optionally yaw rate, inputs and input changes, with a terminal factor on the last stage.
5. *Sparse structure built once*: P (upper triangle) and A are CSC matrices whose sparsity never
   changes; each update writes the new numbers into a value vector in a fixed order and permutes
   it into the CSC data (``Px``, ``Ax``), then ``osqp.update`` and a primal/dual warm start from
   the shifted previous solution.

Safe fallback: when OSQP does not return a solved status (or the update raises, or the state is
not finite), the controller never raises. It applies the previous successful plan shifted by the
number of steps since it was computed (up to ``fallback_shift_steps``), then brakes at
``brake_fraction * mu_hat * g`` with zero steering rate (stopping at v = 0). Every fallback is
counted in the diagnostics, and the next update starts cold.

KMPC baseline: ``NmpcConfig(model="ks")`` predicts with a kinematic single-track model (no tire
slip; ``psi_dot`` and ``beta`` relax to their kinematic values with ``ks_relax_s``) from the same
code; combine it with a fixed theta to ignore the friction estimate.

This module is pydrake-free; ``pcvfe_drake.systems.nmpc.Nmpc`` wraps it as a LeafSystem.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import osqp
import scipy.sparse as sp

from pcvfe_drake.control.course import Course, SpeedProfile, speed_profile
from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import (
    BETA,
    DELTA,
    NU,
    NX,
    PSI,
    PSI_DOT,
    SX,
    SY,
    V,
    constrain_inputs,
    rk4_step,
    st_jacobians,
    wrap_angle,
)

MODELS = ("st", "ks")
_ACCEPTED = ("solved", "solved inaccurate")
_MU_RANGE = (0.05, 2.0)
_NO_TIME_LIMIT = 1e10  # OSQP's own default: no wall-clock limit
_PROJ = ("s", "lateral_error", "heading_error", "x", "y", "heading", "curvature")


@dataclass(frozen=True)
class NmpcConfig:
    """Settings of the tracking NMPC (SI units; scales are Bryson-rule tolerances: the weight of
    a term is 1 / scale^2; ``None`` derives a scale from the vehicle, see :meth:`resolved`).

    Attributes:
        horizon: prediction steps N.
        dt_s: step and controller period [s].
        model: prediction model, ``"st"`` (single track with theta_hat) or ``"ks"`` (kinematic,
            the KMPC baseline).
        lateral_scale_m: lateral error tolerance [m] (None: 0.08 * wheelbase).
        course_angle_scale_rad: course-angle error tolerance [rad].
        speed_scale_mps: speed error tolerance [m/s] (None: 0.35 * sqrt(wheelbase)).
        yaw_rate_scale_radps: yaw-rate error tolerance [rad/s] vs v_ref * kappa (None: off).
        steer_rate_scale_radps: steering-rate tolerance [rad/s] (None: the vehicle's limit).
        accel_scale_mps2: acceleration tolerance [m/s^2].
        steer_rate_change_scale_radps: change of steering rate per step [rad/s] (None: 0.25 *
            the vehicle's steering-rate limit).
        accel_change_scale_mps2: change of acceleration per step [m/s^2].
        terminal_factor: weight multiplier of the last stage's state terms.
        speed_margin: reference speed <= speed_margin * sqrt(mu_hat g / |kappa|).
        long_fraction: acceleration/braking limit of the speed profile, fraction of mu_hat g.
        max_speed_mps: cap on the reference speed (None or 0: the course's planned speed).
        friction_margin: radius of the QP's friction polygon, fraction of mu_hat g.
        corridor_fraction: soft corridor half-width, fraction of the course half-width.
        slack_linear, slack_quadratic: penalties on the slacks (per unit, per unit^2).
        v_lin_min_mps: the linearisation speed is clamped to at least this [m/s].
        ks_relax_s: relaxation time of psi_dot and beta to their kinematic values (KMPC) [s].
        max_iter, eps_abs, eps_rel: OSQP settings; ``max_iter`` is the deterministic budget of
            one update (an unsolved QP after it triggers the fallback).
        time_limit_s: optional wall-clock limit of one OSQP solve [s] (e.g. 0.04 on hardware at
            20 Hz). None (default) keeps simulations deterministic: a wall-clock limit makes
            the result depend on the machine's load.
        fallback_shift_steps: how many steps of a stale plan the fallback may use.
        brake_fraction: braking deceleration of the fallback, fraction of mu_hat g.
        cold_start_distance_m: a plan whose first state is farther than this from the measured
            position is discarded (cold start).
    """

    horizon: int = 40
    dt_s: float = 0.05
    model: str = "st"
    lateral_scale_m: float | None = None
    course_angle_scale_rad: float = 0.06
    speed_scale_mps: float | None = None
    yaw_rate_scale_radps: float | None = None
    steer_rate_scale_radps: float | None = None
    accel_scale_mps2: float = 3.0
    steer_rate_change_scale_radps: float | None = None
    accel_change_scale_mps2: float = 0.5
    terminal_factor: float = 5.0
    speed_margin: float = 0.8
    long_fraction: float = 0.5
    max_speed_mps: float | None = None
    friction_margin: float = 0.9
    corridor_fraction: float = 0.5
    slack_linear: float = 100.0
    slack_quadratic: float = 1000.0
    v_lin_min_mps: float = 1.0
    ks_relax_s: float = 0.1
    max_iter: int = 1000
    eps_abs: float = 1e-3
    eps_rel: float = 1e-3
    time_limit_s: float | None = None
    fallback_shift_steps: int = 20
    brake_fraction: float = 0.5
    cold_start_distance_m: float = 2.0

    def resolved(self, params: VehicleParams) -> NmpcConfig:
        """A copy with every ``None`` scale derived from the vehicle (validated)."""
        wb = params.L
        rate = max(abs(params.delta_dot_min), abs(params.delta_dot_max))
        cfg = dataclasses.replace(
            self,
            lateral_scale_m=self.lateral_scale_m or 0.08 * wb,
            speed_scale_mps=self.speed_scale_mps or 0.35 * math.sqrt(wb),
            steer_rate_scale_radps=self.steer_rate_scale_radps or rate,
            steer_rate_change_scale_radps=self.steer_rate_change_scale_radps or 0.25 * rate,
        )
        cfg.validate()
        return cfg

    def validate(self) -> None:
        def need(ok, name, rule):
            if not ok:
                raise ValueError(f"NmpcConfig.{name}={getattr(self, name)!r} must be {rule}")

        need(int(self.horizon) >= 2, "horizon", ">= 2")
        need(self.dt_s > 0, "dt_s", "> 0")
        need(self.model in MODELS, "model", f"one of {MODELS}")
        for name in (
            "course_angle_scale_rad",
            "accel_scale_mps2",
            "accel_change_scale_mps2",
            "terminal_factor",
            "friction_margin",
            "corridor_fraction",
            "v_lin_min_mps",
            "ks_relax_s",
            "brake_fraction",
            "cold_start_distance_m",
        ):
            need(getattr(self, name) > 0, name, "> 0")
        for name in (
            "lateral_scale_m",
            "speed_scale_mps",
            "steer_rate_scale_radps",
            "steer_rate_change_scale_radps",
            "yaw_rate_scale_radps",
            "time_limit_s",
        ):
            value = getattr(self, name)
            need(value is None or value > 0, name, "> 0 or None")
        need(0 < self.speed_margin <= 1, "speed_margin", "in (0, 1]")
        need(0 < self.long_fraction <= 1, "long_fraction", "in (0, 1]")
        need(self.slack_linear >= 0 and self.slack_quadratic > 0, "slack_quadratic", "> 0")
        need(int(self.max_iter) >= 1, "max_iter", ">= 1")
        need(int(self.fallback_shift_steps) >= 0, "fallback_shift_steps", ">= 0")


@dataclass(frozen=True)
class NmpcMemory:
    """What one update hands to the next (the controller's discrete state; never mutated).

    ``x_plan`` (N+1, 7) and ``u_plan`` (N, 2): the last successful plan (None before the first);
    ``dual``/``slack``: OSQP warm start;
    ``u_applied`` (2,): the last applied input; ``steps_since_solve``: updates since that plan;
    ``valid``: whether the plan may seed the next RTI; counters for diagnostics.
    """

    x_plan: np.ndarray | None = None
    u_plan: np.ndarray | None = None
    dual: np.ndarray | None = None
    slack: np.ndarray | None = None
    u_applied: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(NU))
    steps_since_solve: int = 0
    valid: bool = False
    updates: int = 0
    fallback_count: int = 0
    consecutive_fallbacks: int = 0


@dataclass(frozen=True)
class NmpcDiagnostics:
    """Result of one update: ``mode`` is ``"qp"``, ``"shifted_plan"`` or ``"braking"``;
    ``status`` the OSQP status (or the reason of a fallback); times in seconds; ``s_m``,
    ``lateral_error_m``, ``heading_error_rad`` of the measured state against the course;
    ``v_ref_mps`` the reference speed there; ``mu_hat`` the friction used."""

    mode: str = "none"
    status: str = "not run"
    update_time_s: float = 0.0
    solve_time_s: float = 0.0
    iterations: int = 0
    objective: float = float("nan")
    fallback_count: int = 0
    consecutive_fallbacks: int = 0
    updates: int = 0
    s_m: float = float("nan")
    lateral_error_m: float = float("nan")
    heading_error_rad: float = float("nan")
    v_ref_mps: float = float("nan")
    mu_hat: float = float("nan")


# ---------------------------------------------------------------------------- prediction models
def ks_jacobians(x: np.ndarray, u: np.ndarray, params: VehicleParams, relax_s: float):
    """Kinematic single-track model on the 7-entry ST state, batched: ``(f, A, B)``.

    sx' = v cos(psi + beta_k), sy' = v sin(psi + beta_k), delta' = steer, v' = accel,
    psi' = v cos(beta_k) tan(delta) / L, with beta_k = atan(lr tan(delta) / L); the states
    psi_dot and beta relax to psi'_k and beta_k with time constant ``relax_s`` [s]. Inputs pass
    through CommonRoad's constraints (``vehicle.constrain_inputs``).
    """
    n = x.shape[0]
    wb = params.L
    u_eff, d_steer, d_acc_du1, d_acc_dv = constrain_inputs(x, u, params)
    delta, v, psi, r, beta = x[:, DELTA], x[:, V], x[:, PSI], x[:, PSI_DOT], x[:, BETA]
    c = params.lr / wb
    t = np.tan(delta)
    sec2 = 1.0 + t * t
    q = 1.0 + c * c * t * t
    beta_k = np.arctan(c * t)
    dbeta_k = c * sec2 / q
    gk = t / np.sqrt(q)
    dgk = q**-1.5 * sec2
    yaw_k = v * gk / wb
    cs, sn = np.cos(psi + beta_k), np.sin(psi + beta_k)
    inv = 1.0 / relax_s
    f = np.empty((n, NX))
    f[:, SX] = v * cs
    f[:, SY] = v * sn
    f[:, DELTA] = u_eff[:, 0]
    f[:, V] = u_eff[:, 1]
    f[:, PSI] = yaw_k
    f[:, PSI_DOT] = (yaw_k - r) * inv
    f[:, BETA] = (beta_k - beta) * inv
    A = np.zeros((n, NX, NX))
    B = np.zeros((n, NX, NU))
    A[:, SX, V] = cs
    A[:, SY, V] = sn
    A[:, SX, PSI] = -v * sn
    A[:, SY, PSI] = v * cs
    A[:, SX, DELTA] = -v * sn * dbeta_k
    A[:, SY, DELTA] = v * cs * dbeta_k
    A[:, V, V] = d_acc_dv
    A[:, PSI, V] = gk / wb
    A[:, PSI, DELTA] = v * dgk / wb
    A[:, PSI_DOT, V] = gk / wb * inv
    A[:, PSI_DOT, DELTA] = v * dgk / wb * inv
    A[:, PSI_DOT, PSI_DOT] = -inv
    A[:, BETA, DELTA] = dbeta_k * inv
    A[:, BETA, BETA] = -inv
    B[:, DELTA, 0] = d_steer
    B[:, V, 1] = d_acc_du1
    return f, A, B


def expm_batched(m: np.ndarray) -> np.ndarray:
    """Matrix exponentials of a batch of square matrices (B, n, n).

    Scaling and squaring with a degree-12 Taylor polynomial (Horner form): the batch is scaled
    by 2^-s so that every 1-norm is <= 0.5 (truncation error below 2e-14 relative), then squared
    s times. Vectorised over the batch (scipy's expm loops over it in Python).
    """
    norm = float(np.abs(m).sum(axis=-2).max()) if m.size else 0.0
    s = max(0, int(math.ceil(math.log2(norm / 0.5)))) if norm > 0.5 else 0
    a = m / 2.0**s
    eye = np.eye(m.shape[-1])
    e = eye + a / 12.0
    for k in range(11, 0, -1):
        e = eye + (a @ e) / k
    for _ in range(s):
        e = e @ e
    return e


def discretize(f: np.ndarray, A: np.ndarray, B: np.ndarray, dt: float):
    """Exact zero-order-hold discretisation of ``dx' = A dx + B du + f`` over ``dt``, batched.

    Returns ``(Ad, Bd, g)`` with ``dx(dt) = Ad dx(0) + Bd du + g`` (shapes (N,7,7), (N,7,2),
    (N,7)), from one batched matrix exponential of ``[[A, B, f], [0, 0, 0]] dt``.
    """
    n = f.shape[0]
    m = np.zeros((n, NX + NU + 1, NX + NU + 1))
    m[:, :NX, :NX] = A * dt
    m[:, :NX, NX : NX + NU] = B * dt
    m[:, :NX, -1] = f * dt
    e = expm_batched(m)
    return e[:, :NX, :NX], e[:, :NX, NX : NX + NU], e[:, :NX, -1]


# ---------------------------------------------------------------------------- QP layout
class QpLayout:
    """Index bookkeeping of the QP: variables ``dz = [dx_0..dx_N, du_0..du_{N-1}, s_fric_0..
    s_fric_{N-1}, s_lat_1..s_lat_N]`` and constraint rows ``[init (7), dynamics (7N), inputs (2N),
    steering angle (N), friction (8N), corridor (2N), slack >= 0 (2N)]``."""

    N_FRICTION_SIDES = 8

    def __init__(self, horizon: int) -> None:
        n = int(horizon)
        self.N = n
        self.n_x = NX * (n + 1)
        self.n_u = NU * n
        self.off_u = self.n_x
        self.off_sf = self.n_x + self.n_u
        self.off_sl = self.off_sf + n
        self.nz = self.off_sl + n
        self.r_init = 0
        self.r_dyn = NX
        self.r_in = self.r_dyn + NX * n
        self.r_del = self.r_in + NU * n
        self.r_fr = self.r_del + n
        self.r_lat = self.r_fr + self.N_FRICTION_SIDES * n
        self.r_sl = self.r_lat + 2 * n
        self.m = self.r_sl + 2 * n
        angles = np.arange(self.N_FRICTION_SIDES) * (2 * np.pi / self.N_FRICTION_SIDES)
        self.fr_cos = np.cos(angles)
        self.fr_sin = np.sin(angles)

    def ix(self, k, i):
        return NX * np.asarray(k) + np.asarray(i)

    def iu(self, k, j):
        return self.off_u + NU * np.asarray(k) + np.asarray(j)

    def shift_rows(self) -> np.ndarray:
        """For warm starts: the row of the next stage of each row (the last stage keeps its own)."""
        n = self.N
        src = np.arange(self.m)

        def shift(first: int, per_stage: int, stages: int) -> None:
            rows = first + np.arange(stages * per_stage).reshape(stages, per_stage)
            src[rows[:-1]] = rows[1:]

        shift(self.r_dyn, NX, n)
        shift(self.r_in, NU, n)
        shift(self.r_del, 1, n)
        shift(self.r_fr, self.N_FRICTION_SIDES, n)
        shift(self.r_lat, 2, n)
        shift(self.r_sl, 1, n)
        shift(self.r_sl + n, 1, n)
        return src


class _Pattern:
    """Fixed sparsity: blocks of (row, col) entries in a fixed order, and the permutation from
    that order to CSC data order. ``csc(values)`` builds the matrix once; ``data(values)`` gives
    the CSC data vector of new values in the same pattern."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self.shape = shape
        self._rows: list[np.ndarray] = []
        self._cols: list[np.ndarray] = []
        self.blocks: dict[str, slice] = {}
        self.size = 0

    def add(self, name: str, rows, cols) -> None:
        rows, cols = np.broadcast_arrays(np.asarray(rows), np.asarray(cols))
        self._rows.append(rows.ravel())
        self._cols.append(cols.ravel())
        self.blocks[name] = slice(self.size, self.size + rows.size)
        self.size += rows.size

    def finish(self) -> None:
        rows = np.concatenate(self._rows)
        cols = np.concatenate(self._cols)
        key = cols.astype(np.int64) * self.shape[0] + rows
        if np.unique(key).size != key.size:
            raise RuntimeError("QP pattern has duplicate entries")
        order = np.argsort(key, kind="stable")  # CSC order: by column, then row
        self.perm = order
        self.indices = rows[order].astype(np.int32)
        counts = np.bincount(cols, minlength=self.shape[1])
        self.indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)

    def data(self, values: np.ndarray) -> np.ndarray:
        return values[self.perm]

    def csc(self, values: np.ndarray) -> sp.csc_matrix:
        return sp.csc_matrix((self.data(values), self.indices, self.indptr), shape=self.shape)


@dataclass
class Linearization:
    """Everything the QP of one update depends on (arrays over the horizon)."""

    x_bar: np.ndarray  # (N+1, 7) linearisation states (x_bar[0] = measured state)
    u_bar: np.ndarray  # (N, 2)
    Ad: np.ndarray  # (N, 7, 7)
    Bd: np.ndarray  # (N, 7, 2)
    defect: np.ndarray  # (N, 7): prediction of x_{k+1} at the bars minus x_bar[k+1]
    normal: np.ndarray  # (N, 2) path normals at the projections of x_bar[1:]
    e_lat: np.ndarray  # (N,) lateral errors of x_bar[1:]
    e_course: np.ndarray  # (N,) course-angle errors of x_bar[1:]
    v_ref: np.ndarray  # (N,)
    yaw_ref: np.ndarray  # (N,)
    s: np.ndarray  # (N,)
    u_prev: np.ndarray  # (2,)
    u_lo: np.ndarray  # (N, 2)
    u_hi: np.ndarray  # (N, 2)
    friction_radius: float
    corridor: float
    measured: tuple[float, float, float]  # s [m], lateral and course-angle errors of the state


# ---------------------------------------------------------------------------- controller
class NmpcController:
    """Tracking NMPC for one vehicle on one course (see the module docstring).

    ``update(x, theta)`` keeps the memory inside the object (for plain simulations);
    ``step(x, theta, memory)`` is the functional form used by the Drake system, whose context
    holds the memory. The OSQP workspace is a cache: the warm start comes from the memory.
    """

    def __init__(
        self,
        course: Course,
        params: VehicleParams,
        config: NmpcConfig | None = None,
    ) -> None:
        self.course = course
        self.params = params
        self.config = (config or NmpcConfig()).resolved(params)
        cfg = self.config
        self.N = int(cfg.horizon)
        self.layout = QpLayout(self.N)
        self._profiles: dict[float, SpeedProfile] = {}
        self._weights()
        self._build_patterns()
        self._shift_rows = self.layout.shift_rows()
        self._solver = self._setup_solver()
        self.memory = NmpcMemory()
        self.last_diagnostics = NmpcDiagnostics()

    # ----------------------------------------------------------------- setup
    def _weights(self) -> None:
        cfg = self.config
        n = self.N
        phi = np.ones(n)
        phi[-1] = cfg.terminal_factor
        self.w_lat = phi / cfg.lateral_scale_m**2
        self.w_course = phi / cfg.course_angle_scale_rad**2
        self.w_speed = phi / cfg.speed_scale_mps**2
        yaw = cfg.yaw_rate_scale_radps
        self.w_yaw = phi * (0.0 if yaw is None else 1.0 / yaw**2)
        self.w_u = np.array([1.0 / cfg.steer_rate_scale_radps**2, 1.0 / cfg.accel_scale_mps2**2])
        self.w_du = np.array(
            [1.0 / cfg.steer_rate_change_scale_radps**2, 1.0 / cfg.accel_change_scale_mps2**2]
        )

    def _build_patterns(self) -> None:
        lay = self.layout
        n = self.N
        k1 = np.arange(1, n + 1)  # state stages with costs
        k0 = np.arange(n)  # input stages
        # --- P (upper triangle)
        P = _Pattern((lay.nz, lay.nz))
        P.add("lat_xx", lay.ix(k1, SX), lay.ix(k1, SX))
        P.add("lat_xy", lay.ix(k1, SX), lay.ix(k1, SY))
        P.add("lat_yy", lay.ix(k1, SY), lay.ix(k1, SY))
        P.add("psi_psi", lay.ix(k1, PSI), lay.ix(k1, PSI))
        P.add("psi_beta", lay.ix(k1, PSI), lay.ix(k1, BETA))
        P.add("beta_beta", lay.ix(k1, BETA), lay.ix(k1, BETA))
        P.add("v_v", lay.ix(k1, V), lay.ix(k1, V))
        P.add("r_r", lay.ix(k1, PSI_DOT), lay.ix(k1, PSI_DOT))
        P.add("u_diag", lay.iu(k0[:, None], np.arange(NU)), lay.iu(k0[:, None], np.arange(NU)))
        P.add(
            "u_off",
            lay.iu(k0[:-1, None], np.arange(NU)),
            lay.iu(k0[1:, None], np.arange(NU)),
        )
        P.add("slack", np.arange(lay.off_sf, lay.nz), np.arange(lay.off_sf, lay.nz))
        P.finish()
        self._P = P
        pv = np.zeros(P.size)
        pv[P.blocks["psi_psi"]] = 2 * self.w_course
        pv[P.blocks["psi_beta"]] = 2 * self.w_course
        pv[P.blocks["beta_beta"]] = 2 * self.w_course
        pv[P.blocks["v_v"]] = 2 * self.w_speed
        pv[P.blocks["r_r"]] = 2 * self.w_yaw
        ud = np.tile(2 * (self.w_u + self.w_du), (n, 1))
        ud[:-1] += 2 * self.w_du  # inputs 0..N-2 also enter the next stage's change
        pv[P.blocks["u_diag"]] = ud.ravel()
        pv[P.blocks["u_off"]] = np.tile(-2 * self.w_du, (n - 1, 1)).ravel()
        pv[P.blocks["slack"]] = 2 * self.config.slack_quadratic
        self._p_template = pv

        # --- A
        A = _Pattern((lay.m, lay.nz))
        i7 = np.arange(NX)
        A.add("init", lay.r_init + i7, lay.ix(0, i7))
        kk, ii, jj = np.meshgrid(k0, i7, i7, indexing="ij")
        A.add("Ad", lay.r_dyn + NX * kk + ii, lay.ix(kk, jj))
        kk, ii, jj = np.meshgrid(k0, i7, np.arange(NU), indexing="ij")
        A.add("Bd", lay.r_dyn + NX * kk + ii, lay.iu(kk, jj))
        kk, ii = np.meshgrid(k0, i7, indexing="ij")
        A.add("negI", lay.r_dyn + NX * kk + ii, lay.ix(kk + 1, ii))
        A.add("inputs", lay.r_in + np.arange(NU * n), lay.off_u + np.arange(NU * n))
        A.add("delta", lay.r_del + k0, lay.ix(k1, DELTA))
        ns = lay.N_FRICTION_SIDES
        kk, jj = np.meshgrid(k0, np.arange(ns), indexing="ij")
        rows = lay.r_fr + ns * kk + jj
        A.add("fr_acc", rows, lay.iu(kk, 1))
        A.add("fr_v", rows, lay.ix(kk, V))
        A.add("fr_r", rows, lay.ix(kk, PSI_DOT))
        A.add("fr_s", rows, lay.off_sf + kk)
        kk, side = np.meshgrid(k0, np.arange(2), indexing="ij")
        rows = lay.r_lat + 2 * kk + side
        A.add("lat_x", rows, lay.ix(kk + 1, SX))
        A.add("lat_y", rows, lay.ix(kk + 1, SY))
        A.add("lat_s", rows, lay.off_sl + kk)
        A.add("slack", lay.r_sl + np.arange(2 * n), lay.off_sf + np.arange(2 * n))
        A.finish()
        self._A = A
        av = np.zeros(A.size)
        av[A.blocks["init"]] = 1.0
        av[A.blocks["negI"]] = -1.0
        av[A.blocks["inputs"]] = 1.0
        av[A.blocks["delta"]] = 1.0
        av[A.blocks["fr_acc"]] = np.tile(lay.fr_cos, n)
        av[A.blocks["fr_s"]] = -1.0
        av[A.blocks["lat_s"]] = np.tile([-1.0, 1.0], n)
        av[A.blocks["slack"]] = 1.0
        self._a_template = av

    # ----------------------------------------------------------------- speed profile
    def profile(self, mu: float) -> SpeedProfile:
        """The course's speed profile for friction ``mu`` (cached per 0.005 of mu)."""
        key = round(float(mu) / 0.005) * 0.005
        prof = self._profiles.get(key)
        if prof is None:
            if len(self._profiles) >= 64:
                self._profiles.clear()
            cfg = self.config
            prof = speed_profile(
                self.course,
                key,
                v_max=cfg.max_speed_mps,
                speed_margin=cfg.speed_margin,
                long_fraction=cfg.long_fraction,
                a_drive_max=self.params.a_max,
                g=self.params.g,
            )
            self._profiles[key] = prof
        return prof

    # ----------------------------------------------------------------- linearisation
    def _model_jacobians(self, x, u, theta):
        if self.config.model == "ks":
            return ks_jacobians(x, u, self.params, self.config.ks_relax_s)
        f, A, B, _ = st_jacobians(x, u, self.params, theta)
        return f, A, B

    def _cold_guess(self, x: np.ndarray, prof: SpeedProfile):
        """Reference states along the course from the projection of ``x`` at the planned speed."""
        cfg, p = self.config, self.params
        n = self.N
        s0 = float(self.course.project(x[:2]).s)
        s = prof.advance(s0, np.arange(n + 1) * cfg.dt_s)
        ref = self.course.state_on_path(s, prof.speed_at(s), p.L, p.lr)
        ref[0] = x
        ref[:, PSI] = np.unwrap(ref[:, PSI])
        u = np.empty((n, NU))
        u[:, 0] = np.clip(np.diff(ref[:, DELTA]) / cfg.dt_s, p.delta_dot_min, p.delta_dot_max)
        u[:, 1] = np.clip(np.diff(ref[:, V]) / cfg.dt_s, -p.a_max, p.a_max)
        return ref, u

    def _bars(self, x: np.ndarray, memory: NmpcMemory, prof: SpeedProfile):
        """Linearisation trajectory: the shifted previous plan, else the cold guess."""
        n = self.N
        if memory.valid and memory.x_plan is not None:
            xp, up = memory.x_plan, memory.u_plan
            x_bar = np.empty((n + 1, NX))
            x_bar[:n] = xp[1:]
            x_bar[n] = 2 * xp[n] - xp[n - 1]
            if np.hypot(*(x_bar[0, :2] - x[:2])) <= self.config.cold_start_distance_m:
                x_bar[0] = x
                # Keep the plan's heading on the same branch as the measured heading.
                x_bar[:, PSI] += x[PSI] - xp[1, PSI] - wrap_angle(x[PSI] - xp[1, PSI])
                x_bar[0, PSI] = x[PSI]
                u_bar = np.concatenate([up[1:], up[-1:]], axis=0)
                return x_bar, u_bar
        return self._cold_guess(x, prof)

    def linearize(self, x, theta, memory: NmpcMemory, prof: SpeedProfile) -> Linearization:
        """Linearisation trajectory, reference and discretised Jacobians of one update."""
        cfg, p = self.config, self.params
        n = self.N
        x_bar, u_bar = self._bars(x, memory, prof)
        everything = self.course.project(x_bar[:, :2], heading=x_bar[:, PSI] + x_bar[:, BETA])
        proj = dataclasses.replace(everything, **{f: getattr(everything, f)[1:] for f in _PROJ})
        normal = np.column_stack([-np.sin(proj.heading), np.cos(proj.heading)])
        e_course = proj.heading_error
        v_ref = prof.speed_at(proj.s)
        x_lin = x_bar[:n].copy()
        x_lin[:, V] = np.maximum(x_lin[:, V], cfg.v_lin_min_mps)
        f, A, B = self._model_jacobians(x_lin, u_bar, theta)
        Ad, Bd, g = discretize(f, A, B, cfg.dt_s)
        defect = x_lin + g + np.einsum("kij,kj->ki", Ad, x_bar[:n] - x_lin) - x_bar[1:]
        v_hi = np.where(
            x_bar[:n, V] > p.v_switch,
            p.a_max * p.v_switch / np.maximum(x_bar[:n, V], 1e-6),
            p.a_max,
        )
        u_lo = np.column_stack([np.full(n, p.delta_dot_min), np.full(n, -p.a_max)])
        u_hi = np.column_stack([np.full(n, p.delta_dot_max), v_hi])
        mu = float(theta[0])
        return Linearization(
            x_bar=x_bar,
            u_bar=u_bar,
            Ad=Ad,
            Bd=Bd,
            defect=defect,
            normal=normal,
            e_lat=proj.lateral_error,
            e_course=e_course,
            v_ref=v_ref,
            yaw_ref=v_ref * proj.curvature,
            s=proj.s,
            measured=(
                float(everything.s[0]),
                float(everything.lateral_error[0]),
                float(everything.heading_error[0]),
            ),
            u_prev=np.asarray(memory.u_applied, dtype=float),
            u_lo=u_lo,
            u_hi=u_hi,
            friction_radius=cfg.friction_margin * mu * p.g,
            corridor=cfg.corridor_fraction * self.course.half_width,
        )

    # ----------------------------------------------------------------- QP data
    def qp_vectors(self, lin: Linearization):
        """``(Px, q, Ax, l, u)`` of the sparse QP for a linearisation (CSC data in the fixed
        patterns)."""
        lay, n = self.layout, self.N
        xb, ub = lin.x_bar, lin.u_bar
        # P values
        pv = self._p_template.copy()
        nx_, ny_ = lin.normal[:, 0], lin.normal[:, 1]
        pv[self._P.blocks["lat_xx"]] = 2 * self.w_lat * nx_ * nx_
        pv[self._P.blocks["lat_xy"]] = 2 * self.w_lat * nx_ * ny_
        pv[self._P.blocks["lat_yy"]] = 2 * self.w_lat * ny_ * ny_
        # q
        q = np.zeros(lay.nz)
        qx = q[: lay.n_x].reshape(n + 1, NX)
        qx[1:, SX] = 2 * self.w_lat * lin.e_lat * nx_
        qx[1:, SY] = 2 * self.w_lat * lin.e_lat * ny_
        qx[1:, PSI] = 2 * self.w_course * lin.e_course
        qx[1:, BETA] = 2 * self.w_course * lin.e_course
        qx[1:, V] = 2 * self.w_speed * (xb[1:, V] - lin.v_ref)
        qx[1:, PSI_DOT] = 2 * self.w_yaw * (xb[1:, PSI_DOT] - lin.yaw_ref)
        qu = q[lay.off_u : lay.off_sf].reshape(n, NU)
        qu[:] = 2 * self.w_u * ub
        change = np.diff(np.vstack([lin.u_prev, ub]), axis=0) * (2 * self.w_du)
        qu += change
        qu[:-1] -= change[1:]
        q[lay.off_sf :] = self.config.slack_linear
        # A values
        av = self._a_template.copy()
        blocks = self._A.blocks
        av[blocks["Ad"]] = lin.Ad.ravel()
        av[blocks["Bd"]] = lin.Bd.ravel()
        av[blocks["fr_v"]] = np.outer(xb[:n, PSI_DOT], lay.fr_sin).ravel()
        av[blocks["fr_r"]] = np.outer(xb[:n, V], lay.fr_sin).ravel()
        av[blocks["lat_x"]] = np.repeat(nx_, 2)
        av[blocks["lat_y"]] = np.repeat(ny_, 2)
        # bounds
        lo = np.empty(lay.m)
        hi = np.empty(lay.m)
        lo[: lay.r_dyn] = hi[: lay.r_dyn] = 0.0
        lo[lay.r_dyn : lay.r_in] = hi[lay.r_dyn : lay.r_in] = -lin.defect.ravel()
        lo[lay.r_in : lay.r_del] = (lin.u_lo - ub).ravel()
        hi[lay.r_in : lay.r_del] = (lin.u_hi - ub).ravel()
        lo[lay.r_del : lay.r_fr] = self.params.delta_min - xb[1:, DELTA]
        hi[lay.r_del : lay.r_fr] = self.params.delta_max - xb[1:, DELTA]
        a_x = ub[:, 1]
        a_y = xb[:n, V] * xb[:n, PSI_DOT]
        lo[lay.r_fr : lay.r_lat] = -np.inf
        hi[lay.r_fr : lay.r_lat] = (
            lin.friction_radius - np.outer(a_x, lay.fr_cos) - np.outer(a_y, lay.fr_sin)
        ).ravel()
        hi[lay.r_lat : lay.r_sl : 2] = lin.corridor - lin.e_lat
        lo[lay.r_lat : lay.r_sl : 2] = -np.inf
        lo[lay.r_lat + 1 : lay.r_sl : 2] = -lin.corridor - lin.e_lat
        hi[lay.r_lat + 1 : lay.r_sl : 2] = np.inf
        lo[lay.r_sl :] = 0.0
        hi[lay.r_sl :] = np.inf
        return self._P.data(pv), q, self._A.data(av), lo, hi

    def qp_matrices(self, lin: Linearization):
        """``(P (upper CSC), q, A (CSC), l, u)`` of the sparse assembly (for tests/setup)."""
        px, q, ax, lo, hi = self.qp_vectors(lin)
        P = sp.csc_matrix((px, self._P.indices, self._P.indptr), shape=self._P.shape)
        A = sp.csc_matrix((ax, self._A.indices, self._A.indptr), shape=self._A.shape)
        return P, q, A, lo, hi

    def _setup_solver(self) -> osqp.OSQP:
        """OSQP workspace on the fixed patterns (template values), set up once.

        One solve of the template problem completes OSQP's first run here, so that its time
        limit (which counts the setup time on the first solve) applies to control updates only.
        """
        lay = self.layout
        solver = osqp.OSQP()
        solver.setup(
            self._P.csc(self._p_template),
            np.zeros(lay.nz),
            self._A.csc(self._a_template),
            np.full(lay.m, -1.0),
            np.full(lay.m, 1.0),
            **self.osqp_settings(),
        )
        solver.update_settings(max_iter=1, time_limit=_NO_TIME_LIMIT)
        solver.solve(raise_error=False)
        solver.update_settings(max_iter=int(self.config.max_iter), time_limit=self._time_limit())
        return solver

    def _time_limit(self) -> float:
        return _NO_TIME_LIMIT if self.config.time_limit_s is None else self.config.time_limit_s

    def osqp_settings(self) -> dict:
        cfg = self.config
        return dict(
            verbose=False,
            warm_starting=True,
            polishing=False,
            max_iter=int(cfg.max_iter),
            eps_abs=cfg.eps_abs,
            eps_rel=cfg.eps_rel,
            time_limit=self._time_limit(),
            adaptive_rho=True,
            adaptive_rho_interval=25,
            check_termination=5,
        )

    # ----------------------------------------------------------------- update
    def _theta(self, theta) -> tuple[np.ndarray, str]:
        if theta is None:
            return self.params.theta, ""
        th = np.asarray(theta, dtype=float).reshape(-1)
        if th.size != 3 or not np.all(np.isfinite(th)) or th[1] <= 0 or th[2] <= 0:
            return self.params.theta, "theta_hat invalid, nominal used"
        if th[0] <= 0:
            return self.params.theta, "theta_hat mu <= 0, nominal used"
        th = th.copy()
        th[0] = float(np.clip(th[0], *_MU_RANGE))
        return th, ""

    def step(self, x, theta, memory: NmpcMemory):
        """One controller update: ``(u (2,), new memory, NmpcDiagnostics)``; never raises."""
        t_start = time.perf_counter()
        th, note = self._theta(theta)
        x = np.asarray(x, dtype=float).reshape(-1)
        if x.size != NX or not np.all(np.isfinite(x)):
            return self._fallback(x, th, memory, "state not finite", t_start)
        try:
            prof = self.profile(th[0])
            lin = self.linearize(x, th, memory, prof)
            px, q, ax, lo, hi = self.qp_vectors(lin)
            self._solver.update(q=q, l=lo, u=hi, Px=px, Ax=ax)
            z0 = np.zeros(self.layout.nz)
            y0 = np.zeros(self.layout.m)
            if memory.valid and memory.dual is not None:
                y0 = memory.dual[self._shift_rows]
                z0[self.layout.off_sf :] = memory.slack
            self._solver.warm_start(x=z0, y=y0)
            res = self._solver.solve(raise_error=False)
            status = str(res.info.status)
            ok = status in _ACCEPTED and np.all(np.isfinite(res.x))
        except Exception as exc:  # the loop must never raise
            return self._fallback(x, th, memory, f"error: {type(exc).__name__}: {exc}", t_start)
        if not ok:
            return self._fallback(x, th, memory, f"osqp: {status}", t_start, lin=lin)
        lay, n = self.layout, self.N
        z = res.x
        x_plan = lin.x_bar + z[: lay.n_x].reshape(n + 1, NX)
        u_plan = lin.u_bar + z[lay.off_u : lay.off_sf].reshape(n, NU)
        u = np.clip(u_plan[0], lin.u_lo[0], lin.u_hi[0])
        slack = z[lay.off_sf :]
        new = dataclasses.replace(
            memory,
            x_plan=x_plan,
            u_plan=u_plan,
            dual=np.array(res.y),
            slack=np.concatenate([slack[1:n], slack[n - 1 : n], slack[n + 1 :], slack[-1:]]),
            u_applied=u,
            steps_since_solve=0,
            valid=True,
            updates=memory.updates + 1,
            consecutive_fallbacks=0,
        )
        diag = self._diagnostics(
            new, x, th, prof, "qp", status + (f"; {note}" if note else ""), t_start, res, lin
        )
        return u, new, diag

    def _fallback(self, x, th, memory: NmpcMemory, reason: str, t_start: float, lin=None):
        cfg, p = self.config, self.params
        j = memory.steps_since_solve + 1
        if memory.u_plan is not None and j <= min(cfg.fallback_shift_steps, self.N - 1):
            u = np.array(memory.u_plan[j], dtype=float)
            mode = "shifted_plan"
        else:
            v = float(x[V]) if x.size == NX and np.isfinite(x[V]) else np.inf
            brake = cfg.brake_fraction * float(th[0]) * p.g
            u = np.array([0.0, -min(brake, max(v, 0.0) / cfg.dt_s)])
            mode = "braking"
        u = np.clip(np.nan_to_num(u), [p.delta_dot_min, -p.a_max], [p.delta_dot_max, p.a_max])
        new = dataclasses.replace(
            memory,
            u_applied=u,
            steps_since_solve=j,
            valid=False,
            updates=memory.updates + 1,
            fallback_count=memory.fallback_count + 1,
            consecutive_fallbacks=memory.consecutive_fallbacks + 1,
        )
        prof = None
        try:
            prof = self.profile(th[0])
        except Exception:
            prof = None
        return u, new, self._diagnostics(new, x, th, prof, mode, reason, t_start, None, lin)

    def _diagnostics(
        self, mem, x, th, prof, mode, status, t_start, res, lin=None
    ) -> NmpcDiagnostics:
        s = lat = herr = vref = float("nan")
        if lin is not None:
            s, lat, herr = lin.measured
        elif x.size == NX and np.all(np.isfinite(x[:2])):
            pr = self.course.project(x[:2], heading=x[PSI] + x[BETA])
            s, lat, herr = float(pr.s), float(pr.lateral_error), float(pr.heading_error)
        if prof is not None and np.isfinite(s):
            vref = float(prof.speed_at(s))
        return NmpcDiagnostics(
            mode=mode,
            status=status,
            update_time_s=time.perf_counter() - t_start,
            solve_time_s=0.0 if res is None else float(res.info.solve_time),
            iterations=0 if res is None else int(res.info.iter),
            objective=float("nan") if res is None else float(res.info.obj_val),
            fallback_count=mem.fallback_count,
            consecutive_fallbacks=mem.consecutive_fallbacks,
            updates=mem.updates,
            s_m=s,
            lateral_error_m=lat,
            heading_error_rad=herr,
            v_ref_mps=vref,
            mu_hat=float(th[0]),
        )

    def update(self, x, theta=None) -> np.ndarray:
        """One update using and advancing the memory kept in this object; returns u (2,)."""
        u, self.memory, self.last_diagnostics = self.step(x, theta, self.memory)
        return u

    def reset(self) -> None:
        self.memory = NmpcMemory()
        self.last_diagnostics = NmpcDiagnostics()


# ---------------------------------------------------------------------------- dense reference
def dense_qp(ctrl: NmpcController, lin: Linearization):
    """Straightforward dense build of the same QP (full symmetric P), term by term in loops.

    The reference for tests and the naive baseline of ``benchmarks/nmpc_step.py``.
    """
    lay, n = ctrl.layout, ctrl.N
    cfg, p = ctrl.config, ctrl.params
    nz, m = lay.nz, lay.m
    P = np.zeros((nz, nz))
    q = np.zeros(nz)
    A = np.zeros((m, nz))
    lo = np.zeros(m)
    hi = np.zeros(m)

    def add_square(weight, coeffs: dict, offset: float):
        # weight * (sum_i c_i z_i + offset)^2 -> 1/2 z' P z + q' z
        idx = np.array(list(coeffs.keys()))
        c = np.array(list(coeffs.values()))
        P[np.ix_(idx, idx)] += 2 * weight * np.outer(c, c)
        q[idx] += 2 * weight * offset * c

    for k in range(1, n + 1):
        j = k - 1
        xb = lin.x_bar[k]
        nrm = lin.normal[j]
        add_square(ctrl.w_lat[j], {lay.ix(k, SX): nrm[0], lay.ix(k, SY): nrm[1]}, lin.e_lat[j])
        add_square(ctrl.w_course[j], {lay.ix(k, PSI): 1.0, lay.ix(k, BETA): 1.0}, lin.e_course[j])
        add_square(ctrl.w_speed[j], {lay.ix(k, V): 1.0}, xb[V] - lin.v_ref[j])
        add_square(ctrl.w_yaw[j], {lay.ix(k, PSI_DOT): 1.0}, xb[PSI_DOT] - lin.yaw_ref[j])
    for k in range(n):
        for i in range(NU):
            add_square(ctrl.w_u[i], {lay.iu(k, i): 1.0}, lin.u_bar[k, i])
            if k == 0:
                add_square(ctrl.w_du[i], {lay.iu(0, i): 1.0}, lin.u_bar[0, i] - lin.u_prev[i])
            else:
                add_square(
                    ctrl.w_du[i],
                    {lay.iu(k, i): 1.0, lay.iu(k - 1, i): -1.0},
                    lin.u_bar[k, i] - lin.u_bar[k - 1, i],
                )
    for v in range(lay.off_sf, nz):
        P[v, v] += 2 * cfg.slack_quadratic
        q[v] += cfg.slack_linear

    row = 0
    for i in range(NX):
        A[row, lay.ix(0, i)] = 1.0
        row += 1
    for k in range(n):
        for i in range(NX):
            for jj in range(NX):
                A[row, lay.ix(k, jj)] = lin.Ad[k, i, jj]
            for jj in range(NU):
                A[row, lay.iu(k, jj)] = lin.Bd[k, i, jj]
            A[row, lay.ix(k + 1, i)] = -1.0
            lo[row] = hi[row] = -lin.defect[k, i]
            row += 1
    for k in range(n):
        for i in range(NU):
            A[row, lay.iu(k, i)] = 1.0
            lo[row] = lin.u_lo[k, i] - lin.u_bar[k, i]
            hi[row] = lin.u_hi[k, i] - lin.u_bar[k, i]
            row += 1
    for k in range(1, n + 1):
        A[row, lay.ix(k, DELTA)] = 1.0
        lo[row] = p.delta_min - lin.x_bar[k, DELTA]
        hi[row] = p.delta_max - lin.x_bar[k, DELTA]
        row += 1
    for k in range(n):
        vb, rb, ab = lin.x_bar[k, V], lin.x_bar[k, PSI_DOT], lin.u_bar[k, 1]
        for c, s in zip(lay.fr_cos, lay.fr_sin, strict=True):
            A[row, lay.iu(k, 1)] = c
            A[row, lay.ix(k, V)] = s * rb
            A[row, lay.ix(k, PSI_DOT)] = s * vb
            A[row, lay.off_sf + k] = -1.0
            lo[row] = -np.inf
            hi[row] = lin.friction_radius - (c * ab + s * vb * rb)
            row += 1
    for k in range(1, n + 1):
        nrm = lin.normal[k - 1]
        for sign in (-1.0, 1.0):
            A[row, lay.ix(k, SX)] = nrm[0]
            A[row, lay.ix(k, SY)] = nrm[1]
            A[row, lay.off_sl + k - 1] = sign
            if sign < 0:
                lo[row], hi[row] = -np.inf, lin.corridor - lin.e_lat[k - 1]
            else:
                lo[row], hi[row] = -lin.corridor - lin.e_lat[k - 1], np.inf
            row += 1
    for v in range(lay.off_sf, nz):
        A[row, v] = 1.0
        lo[row], hi[row] = 0.0, np.inf
        row += 1
    return P, q, A, lo, hi


# ---------------------------------------------------------------------------- closed loop
@dataclass
class ClosedLoopResult:
    """Log of a closed-loop run: times (T,), states (T, 7), inputs (T, 2), true mu (T,),
    course projection (s, lateral and course-angle errors), progress [m], the failure reason
    (empty if none) and the controller diagnostics of each update."""

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    mu: np.ndarray
    s: np.ndarray
    lateral_error: np.ndarray
    course_error: np.ndarray
    progress: np.ndarray
    failure: str
    diagnostics: list

    def metrics(self, course: Course) -> dict:
        """Laps, lateral RMS/max [m], course-angle RMS [rad], speed, fallbacks (count and
        reasons), update times [ms]."""
        times = np.array([d.update_time_s for d in self.diagnostics])
        dist = float(self.progress[-1] - self.progress[0]) if self.progress.size else 0.0
        return {
            "duration_s": float(self.t[-1]) if self.t.size else 0.0,
            "distance_m": dist,
            "laps": dist / course.length,
            "lateral_rms_m": float(np.sqrt(np.mean(self.lateral_error**2))),
            "lateral_max_m": float(np.max(np.abs(self.lateral_error))),
            "course_angle_rms_rad": float(np.sqrt(np.mean(self.course_error**2))),
            "mean_speed_mps": float(np.mean(self.x[:, V])),
            "max_abs_beta_rad": float(np.max(np.abs(self.x[:, BETA]))),
            "fallbacks": int(self.diagnostics[-1].fallback_count) if self.diagnostics else 0,
            "fallback_reasons": dict(
                Counter(d.status for d in self.diagnostics if d.mode != "qp").most_common()
            ),
            "update_ms_median": float(np.median(times) * 1e3) if times.size else float("nan"),
            "update_ms_p95": float(np.percentile(times, 95) * 1e3) if times.size else float("nan"),
            "failure": self.failure,
        }


def failure_reason(course: Course, lateral_error: float, course_error: float, beta: float) -> str:
    """Why a state counts as failed ("" if it does not): off the course (|lateral error| >
    ``course.half_width``), or spinning (|course-angle error| > 60 deg or |beta| > 30 deg)."""
    if abs(lateral_error) > course.half_width:
        return f"left the course: lateral error {lateral_error:.2f} m"
    if abs(course_error) > math.radians(60) or abs(beta) > math.radians(30):
        return f"spinning: course-angle error {course_error:.2f} rad, beta {beta:.2f} rad"
    return ""


class StTruth:
    """The ST model as a closed-loop truth: RK4 steps with theta = [mu, C_Sf, C_Sr]."""

    def __init__(self, params: VehicleParams) -> None:
        self.params = params
        self.x = np.zeros(NX)

    def reset(self, x0: np.ndarray) -> np.ndarray:
        self.x = np.asarray(x0, dtype=float).copy()
        return self.x.copy()

    def step(self, u: np.ndarray, mu: float, dt: float) -> np.ndarray:
        """Advance by ``dt`` [s] with ``u`` held on friction ``mu``; returns the ST state."""
        theta = np.array([mu, self.params.C_Sf, self.params.C_Sr])
        self.x = rk4_step(self.x, u, self.params, dt, theta=theta)
        return self.x.copy()


def simulate_closed_loop(
    controller: NmpcController,
    x0,
    duration_s: float,
    *,
    mu_at: Callable[[np.ndarray], float] | None = None,
    theta_hat: Callable[[float, np.ndarray], np.ndarray] | None = None,
    truth=None,
    dt_sim_s: float = 0.01,
    stop_on_failure: bool = True,
    stop_after_laps: float | None = None,
) -> ClosedLoopResult:
    """Drive a truth model with the controller at its period (zero-order hold).

    ``truth`` has ``reset(x0) -> x`` and ``step(u, mu, dt) -> x`` returning ST states (default
    :class:`StTruth`: RK4 of the ST model every ``dt_sim_s``). ``mu_at(xy)`` gives the true
    friction under the vehicle (default: the vehicle's mu). ``theta_hat(t, x)`` gives the
    controller's belief (default: [true mu, C_Sf, C_Sr], i.e. the true mu is given).
    """
    ctrl = controller
    p = ctrl.params
    course = ctrl.course
    period = ctrl.config.dt_s
    every = max(1, int(round(period / dt_sim_s)))
    steps = int(round(duration_s / dt_sim_s))
    plant = truth if truth is not None else StTruth(p)
    x = plant.reset(np.asarray(x0, dtype=float))
    mu_fn = mu_at if mu_at is not None else (lambda xy: p.mu)
    ts, xs, us, mus, diags = [], [], [], [], []
    s_prev = None
    s_log, lat_log, ce_log = [], [], []
    failure = ""
    u = np.zeros(NU)
    progress = 0.0
    for i in range(steps + 1):
        t = i * dt_sim_s
        mu_true = float(mu_fn(x[:2]))
        theta_true = np.array([mu_true, p.C_Sf, p.C_Sr])
        pr = course.project(x[:2], heading=x[PSI] + x[BETA])
        if s_prev is not None:
            d = float(pr.s) - s_prev
            progress += d - course.length * round(d / course.length)
        s_prev = float(pr.s)
        ts.append(t)
        xs.append(x.copy())
        mus.append(mu_true)
        s_log.append(float(pr.s))
        lat_log.append(float(pr.lateral_error))
        ce_log.append(float(pr.heading_error))
        reason = failure_reason(course, pr.lateral_error, pr.heading_error, x[BETA])
        if reason and not failure:
            failure = f"t={t:.2f} s: {reason}"
        if i % every == 0:
            th = theta_true if theta_hat is None else theta_hat(t, x)
            u = ctrl.update(x, th)
            diags.append(ctrl.last_diagnostics)
        us.append(u.copy())
        if (failure and stop_on_failure) or i == steps:
            break
        if stop_after_laps is not None and progress >= stop_after_laps * course.length:
            break
        x = plant.step(u, mu_true, dt_sim_s)
    s_arr = np.array(s_log)
    return ClosedLoopResult(
        t=np.array(ts),
        x=np.array(xs),
        u=np.array(us),
        mu=np.array(mus),
        s=s_arr,
        lateral_error=np.array(lat_log),
        course_error=np.array(ce_log),
        progress=course.unwrap_progress(s_arr),
        failure=failure,
        diagnostics=diags,
    )


def start_state(course: Course, params: VehicleParams, speed_mps: float, s_m: float = 0.0):
    """An ST state on the course at arc length ``s_m`` driving at ``speed_mps`` (steady kinematic
    cornering)."""
    return course.state_on_path(np.array([s_m]), speed_mps, params.L, params.lr)[0]
