"""A Drake-free closed loop of the NMPC: a truth model driven at the controller's period.

Serves tests and ``validation/nmpc_laps.py`` / ``nmpc_step.py`` (the Drake diagram is
``pcvfe_drake.diagrams.simulation``): :func:`simulate_closed_loop` drives a truth (default
:class:`StTruth`, RK4 of the ST model) with an :class:`~pcvfe_drake.control.nmpc.NmpcController`
under a zero-order hold and logs a :class:`ClosedLoopResult`.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pcvfe_drake.control import failure
from pcvfe_drake.control.course import Course
from pcvfe_drake.control.nmpc import NmpcController
from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import BETA, NU, NX, PSI, V, rk4_step


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
    """Why a state counts as failed ("" if it does not): the project's one definition
    (``pcvfe_drake.control.failure``) with the course's half width."""
    return failure.failure_reason(course.half_width, lateral_error, course_error, beta)


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


class MbTruthPlant:
    """CommonRoad's multi-body model as a closed-loop truth (RK4 substeps of 1 ms); returns the
    ST states it implies (``vehicle.mb_truth.st_state``)."""

    def __init__(
        self, vehicle: str = "ford_escort", friction_scaling: str = "peak_and_stiffness"
    ) -> None:
        from pcvfe_drake.vehicle.mb_truth import MbTruth, st_state

        self.mb = MbTruth(vehicle, friction_scaling=friction_scaling)
        self._st_state = st_state
        self.x = None

    def reset(self, x0: np.ndarray) -> np.ndarray:
        self.x = self.mb.initial_state(x0)
        return self._st_state(self.x)

    def step(self, u: np.ndarray, mu: float, dt: float) -> np.ndarray:
        """Advance by ``dt`` [s] with ``u`` held on friction ``mu``; returns the ST state."""
        self.x = self.mb.integrate(self.x, u, mu, dt, method="rk4", rk4_step_s=1e-3)
        return self._st_state(self.x)


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
    from pcvfe_drake.vehicle.mb_truth import MbSingularity  # the MB package: only when used

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
        try:
            x = plant.step(u, mu_true, dt_sim_s)
        except MbSingularity as exc:  # the multi-body truth ends: a failure (control.failure)
            failure = failure or f"t={t + dt_sim_s:.2f} s: truth model singular: {exc.detail}"
            break
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
