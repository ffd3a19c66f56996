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
   against the friction-limited speed profile ``v_ref(s_k)`` (``speed_profile`` with the
   friction the controller believes).
3. *Dynamics*: exact Jacobians ``A = df/dx``, ``B = df/du`` of the prediction model (the ST model
   with theta_hat, ``st_jacobians``, or a kinematic single-track model for the KMPC baseline),
   evaluated in one batched call over the horizon at speeds clamped to >= ``v_lin_min_mps``, and
   discretised exactly for a zero-order-held input with the matrix exponential of the augmented
   matrix ``[[A, B, f], [0, 0, 0]] dt`` (one batched ``expm``). The ST model's yaw/slip modes
   scale like 1/v (Ford Escort: about -215 1/s at 1 m/s), so an explicit RK4 step of 50 ms is
   unstable below about 4 m/s; the exponential is exact for the linear model at every speed
   (its cost against RK4 sub-steps and against SciPy's ``expm``: ``docs/nmpc.md``).
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

Modules: this one holds the controller (memory, diagnostics, linearisation, QP values, update
and fallback); ``nmpc_config`` its settings, ``prediction_model`` the KS model and the exact
discretisation, ``qp_layout`` the QP's index bookkeeping and fixed sparsity. For tests and
benchmarks only: ``reference_qp`` (a dense build of the same QP) and ``closed_loop`` (a
Drake-free closed loop). All pydrake-free; ``pcvfe_drake.systems.nmpc.Nmpc`` wraps the
controller as a LeafSystem.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np
import osqp
import scipy.sparse as sp

from pcvfe_drake.control.course import Course
from pcvfe_drake.control.nmpc_config import MODELS, NmpcConfig
from pcvfe_drake.control.plan import NmpcPlan
from pcvfe_drake.control.prediction_model import discretize, ks_jacobians
from pcvfe_drake.control.qp_layout import QpLayout, SparsityPattern
from pcvfe_drake.control.speed_profile import SpeedProfile, speed_profile
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
    st_jacobians,
    wrap_angle,
)

__all__ = [
    "MODELS",
    "Linearization",
    "NmpcConfig",
    "NmpcController",
    "NmpcDiagnostics",
    "NmpcMemory",
]

_ACCEPTED = ("solved", "solved inaccurate")
OSQP_INTERRUPTED = "interrupted"
"""OSQP's status when Ctrl-C arrived during a solve (it catches SIGINT and returns)."""
_MU_RANGE = (0.05, 2.0)
_NO_TIME_LIMIT = 1e10  # OSQP's own default: no wall-clock limit
_PROJ = ("s", "lateral_error", "heading_error", "x", "y", "heading", "curvature")


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

    def __deepcopy__(self, memo) -> NmpcMemory:
        # Immutable (frozen; an update builds a new memory and never writes into the arrays of
        # the one it was given): Drake's copies of the abstract state at every update share it.
        return self


@dataclass(frozen=True)
class NmpcDiagnostics:
    """Result of one update: ``mode`` is ``"qp"``, ``"shifted_plan"`` or ``"braking"``;
    ``status`` the OSQP status (or the reason of a fallback); times in seconds; ``s_m``,
    ``lateral_error_m``, ``heading_error_rad`` of the measured state against the course;
    ``v_ref_mps`` the reference speed there; ``mu_hat`` the friction used; ``plan`` what the
    update planned (:class:`pcvfe_drake.control.plan.NmpcPlan`: predicted states and inputs,
    reference window, fallback reason; the arrays are the plan's own, not copies)."""

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
    plan: NmpcPlan = field(default_factory=NmpcPlan)

    def __deepcopy__(self, memo) -> NmpcDiagnostics:
        # Immutable (frozen, the plan's arrays never written): Drake's per-step copies of the
        # abstract state can share it.
        return self


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
    ref_xy: np.ndarray  # (N, 2) course points [m] the predicted positions x_bar[1:] project on


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
        P = SparsityPattern((lay.nz, lay.nz))
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
        A = SparsityPattern((lay.m, lay.nz))
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
                steer_rate_max=cfg.steer_rate_fraction * self.params.delta_dot_max,
                wheelbase_m=self.params.L,
            )
            self._profiles[key] = prof
        return prof

    def reference_speed(self, prof: SpeedProfile, s_m, v_mps: float, mu: float) -> np.ndarray:
        """Reference speeds [m/s] of the horizon's stages k = 1..N at arc lengths ``s_m``.

        The profile's speed there; with ``ref_rise_limit`` at most the measured speed ``v_mps``
        plus the profile's acceleration (``long_fraction * mu g``, at most ``a_max``) times
        the stage's time: the profile assumes the car is on it, and below it (a start, after
        a slow-down) the car should reach it where the profile can still brake for the next
        bend, not catch up at the friction polygon's limit.
        """
        cfg, p = self.config, self.params
        v_ref = prof.speed_at(s_m)
        if cfg.ref_rise_limit:
            a_rise = min(cfg.long_fraction * mu * p.g, p.a_max)
            t_k = np.arange(1, len(v_ref) + 1) * cfg.dt_s
            v_ref = np.minimum(v_ref, max(v_mps, 0.0) + a_rise * t_k)
        return v_ref

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
        v_ref = self.reference_speed(prof, proj.s, float(x[V]), float(theta[0]))
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
            ref_xy=np.column_stack([proj.x, proj.y]),
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
        """One controller update: ``(u (2,), new memory, NmpcDiagnostics)``. Never raises, but
        for ``KeyboardInterrupt`` when Ctrl-C interrupted the OSQP solve."""
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
            if status == OSQP_INTERRUPTED:
                # OSQP catches Ctrl-C during a solve and returns instead of raising: the
                # interrupt is the user's, not a failed solve (no fallback step).
                raise KeyboardInterrupt("OSQP solve interrupted (Ctrl-C)")
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
        u[1] = self.clip_to_friction(u[1], x, float(th[0]))
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

    def clip_to_friction(self, accel_mps2: float, x: np.ndarray, mu: float) -> float:
        """The applied acceleration [m/s^2] within the friction circle (``friction_clip``): at
        most ``sqrt(R^2 - a_y^2)`` in magnitude, with ``R = friction_margin * mu g`` and the
        measured lateral acceleration ``a_y = v psi_dot`` (0 where a_y alone reaches R); only
        a positive one with ``"drive"``; unchanged with ``""``."""
        cfg = self.config
        if not cfg.friction_clip or (cfg.friction_clip == "drive" and accel_mps2 <= 0):
            return accel_mps2
        radius = cfg.friction_margin * mu * self.params.g
        lateral = float(x[V] * x[PSI_DOT])
        room = math.sqrt(max(radius * radius - lateral * lateral, 0.0))
        return float(np.clip(accel_mps2, -room, room))

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
            plan=self._plan(mem, mode, status, th, lin),
        )

    @staticmethod
    def _plan(mem: NmpcMemory, mode: str, status: str, th, lin) -> NmpcPlan:
        """What this update planned: the fresh plan (mode "qp"), the rest of the stale plan it
        shifted ("shifted_plan"), or nothing ("braking")."""
        if mode == "qp":
            return NmpcPlan(mem.x_plan, mem.u_plan, lin.ref_xy, lin.v_ref, mode, "", float(th[0]))
        if mode == "shifted_plan" and mem.x_plan is not None:
            j = mem.steps_since_solve
            return NmpcPlan(
                mem.x_plan[j:], mem.u_plan[j:], mode=mode, reason=status, mu_hat=float(th[0])
            )
        return NmpcPlan(mode=mode, reason=status, mu_hat=float(th[0]))

    def update(self, x, theta=None) -> np.ndarray:
        """One update using and advancing the memory kept in this object; returns u (2,)."""
        u, self.memory, self.last_diagnostics = self.step(x, theta, self.memory)
        return u

    def reset(self) -> None:
        self.memory = NmpcMemory()
        self.last_diagnostics = NmpcDiagnostics()
