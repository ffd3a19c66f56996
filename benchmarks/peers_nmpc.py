"""Peer of the NMPC: the same tracking problem in plain CasADi, solved to convergence by IPOPT.

The project's controller (``NmpcController``) makes one real-time iteration per update: one
linearisation and one OSQP QP. The peer (``IpoptNmpc`` below) poses the *nonlinear* program of
the same problem and lets IPOPT converge it at every update:

* same course (``slalom``), vehicle (Ford Escort), horizon (40 x 0.05 s), weights
  (``NmpcController._weights``: lateral, course-angle, speed, yaw-rate, input and input-change
  terms, terminal factor), speed profile, reference construction (each predicted position of the
  shifted previous plan projected on the course: normal, point, heading, v_ref), constraints
  (steering-rate, acceleration and steering-angle bounds, the 8-sided friction polygon of radius
  ``friction_margin * mu_hat * g`` on (accel, v * psi_dot), the soft corridor) and slack
  penalties (linear + quadratic);
* the prediction model is the nonlinear ST model with theta_hat (CommonRoad's dynamic equations
  as in ``vehicle.single_track``), integrated by RK4 with 4 substeps per 50 ms interval (12.5 ms:
  the ST yaw/slip modes, about -215/v 1/s, stay inside RK4's stability region down to 1 m/s),
  in direct multiple shooting; the friction polygon uses the exact a_y = v psi_dot and the
  acceleration limit above v_switch the exact ``accel * max(v, v_switch) <= a_max v_switch``;
* CasADi as its documentation recommends for MPC: ``nlpsol`` built once with the varying data
  as parameters, ``expand=True`` (SX evaluation), IPOPT with MUMPS and its default convergence
  tolerance (``tol`` 1e-8) and iteration limit (3000), primal and dual warm start from the
  shifted previous solution (``warm_start_init_point``, ``mu_init`` 1e-3 as IPOPT's
  warm-start notes suggest, so a warm start is not thrown away by the barrier's first steps).
  An update whose IPOPT status is not a success falls back exactly as the project's controller
  does (shifted plan, then braking).

Both controllers drive the same closed loop (``simulate_closed_loop``: ST truth, RK4 10 ms, the
true mu given) on the four-terrain map, one lap (``--quick``: 8 s). Reported for each: update
time median / p95 / max, updates over the 50 ms period of 20 Hz (a missed deadline on a car),
lateral RMS / max, mean speed, fallbacks; and the ratio of median update times in this run.
Wall-clock times on a shared machine; CPU times (``time.process_time``) beside them.

``--friction-limited``: ``paper_eval``'s friction-limited driving instead, where the plan runs
at the friction polygon on every curve and IPOPT's convergence could matter: the same course
and terrains, the reference speed capped at 12 m/s (so the curves' speeds are set by mu on every
terrain, brick included), CommonRoad's multi-body model as the truth with ``paper_eval``'s
friction mapping (``lateral_peak``: only the lateral tyre peak is the terrain's mu; RK4 with
1 ms substeps), the true mu given to both controllers (``paper_eval``'s oracle).

Usage: python benchmarks/peers_nmpc.py [--quick] [--friction-limited].
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.metadata
import json
import os
import platform
import time

import numpy as np

from pcvfe_drake.control.closed_loop import MbTruthPlant, simulate_closed_loop
from pcvfe_drake.control.course import initial_state, load_course
from pcvfe_drake.control.nmpc import NmpcConfig, NmpcController, NmpcDiagnostics, NmpcMemory
from pcvfe_drake.control.plan import NmpcPlan
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.vehicle.single_track import BETA, DELTA, NU, NX, PSI, PSI_DOT, V

DEADLINE_S = 0.05  # 20 Hz
_OK = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


def st_rhs(ca, x, u, theta, p):
    """CommonRoad's dynamic single-track equations (``vehicle.single_track``), symbolic."""
    delta, v, psi, r, beta = x[DELTA], x[V], x[PSI], x[PSI_DOT], x[BETA]
    steer, acc = u[0], u[1]
    mu, c_sf, c_sr = theta[0], theta[1], theta[2]
    lf, lr, h, g = p.lf, p.lr, p.h, p.g
    wb = lf + lr
    vd = ca.fmax(v, 0.1)
    ff = c_sf * (g * lr - acc * h)
    fr = c_sr * (g * lf + acc * h)
    k_yaw = mu * p.m / (p.I_z * wb)
    yaw_sum = lf**2 * ff + lr**2 * fr
    moment = lr * fr - lf * ff
    r_v = r / vd
    dd_psi = k_yaw * (lf * ff * delta + moment * beta - yaw_sum * r_v)
    d_beta = mu / (vd * wb) * (ff * delta - (fr + ff) * beta + moment * r_v) - r
    return ca.vertcat(v * ca.cos(psi + beta), v * ca.sin(psi + beta), steer, acc, r, dd_psi, d_beta)


class IpoptNmpc(NmpcController):
    """The NMPC's problem as an NLP solved to convergence by IPOPT (see the module doc)."""

    def __init__(self, course, params, config=None, substeps: int = 4):
        super().__init__(course, params, config)
        import casadi as ca

        self._ca = ca
        self._build_nlp(int(substeps))
        self._warm = None

    def _build_nlp(self, substeps: int) -> None:
        ca, cfg, p, n = self._ca, self.config, self.params, self.N
        xs = ca.SX.sym("x", NX)
        us = ca.SX.sym("u", NU)
        th = ca.SX.sym("theta", 3)
        h = cfg.dt_s / substeps
        xk = xs
        for _ in range(substeps):
            k1 = st_rhs(ca, xk, us, th, p)
            k2 = st_rhs(ca, xk + h / 2 * k1, us, th, p)
            k3 = st_rhs(ca, xk + h / 2 * k2, us, th, p)
            k4 = st_rhs(ca, xk + h * k3, us, th, p)
            xk = xk + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        step = ca.Function("step", [xs, us, th], [xk])

        X = ca.SX.sym("X", NX, n + 1)
        U = ca.SX.sym("U", NU, n)
        SF = ca.SX.sym("sf", n)
        SL = ca.SX.sym("sl", n)
        # parameters: x0 (7), u_prev (2), theta (3), friction radius, corridor, and per stage
        # k = 1..N: normal (2), course point (2), course-angle offset, v_ref, yaw_ref
        P = ca.SX.sym("p", NX + NU + 3 + 2 + 7 * n)
        x0, u_prev, theta = P[:NX], P[NX : NX + NU], P[NX + NU : NX + NU + 3]
        radius, corridor = P[NX + NU + 3], P[NX + NU + 4]
        stage = ca.reshape(P[NX + NU + 5 :], 7, n)
        cost = 0
        g, lbg, ubg = [X[:, 0] - x0], [0.0] * NX, [0.0] * NX
        big = ca.inf
        for k in range(n):
            xk, uk = X[:, k], U[:, k]
            g.append(step(xk, uk, theta) - X[:, k + 1])
            lbg += [0.0] * NX
            ubg += [0.0] * NX
            # inputs: acceleration limit above v_switch (CommonRoad), exact in v
            g.append(uk[1] * ca.fmax(xk[V], p.v_switch))
            lbg.append(-big)
            ubg.append(p.a_max * p.v_switch)
            # friction polygon on (a_x, a_y) = (accel, v psi_dot), soft
            a_y = xk[V] * xk[PSI_DOT]
            for cj, sj in zip(self.layout.fr_cos, self.layout.fr_sin, strict=True):
                g.append(cj * uk[1] + sj * a_y - SF[k] - radius)
                lbg.append(-big)
                ubg.append(0.0)
            # stage k+1 costs and the soft corridor
            x1 = X[:, k + 1]
            nrm, pt = stage[0:2, k], stage[2:4, k]
            e_lat = nrm[0] * (x1[0] - pt[0]) + nrm[1] * (x1[1] - pt[1])
            e_course = x1[PSI] + x1[BETA] + stage[4, k]
            cost += self.w_lat[k] * e_lat**2 + self.w_course[k] * e_course**2
            cost += self.w_speed[k] * (x1[V] - stage[5, k]) ** 2
            cost += self.w_yaw[k] * (x1[PSI_DOT] - stage[6, k]) ** 2
            g.append(e_lat - SL[k] - corridor)
            lbg.append(-big)
            ubg.append(0.0)
            g.append(e_lat + SL[k] + corridor)
            lbg.append(0.0)
            ubg.append(big)
            prev = u_prev if k == 0 else U[:, k - 1]
            cost += ca.dot(self.w_u, uk**2) + ca.dot(self.w_du, (uk - prev) ** 2)
        cost += cfg.slack_linear * (ca.sum1(SF) + ca.sum1(SL))
        cost += cfg.slack_quadratic * (ca.sumsqr(SF) + ca.sumsqr(SL))
        z = ca.vertcat(ca.vec(X), ca.vec(U), SF, SL)
        opts = {
            "expand": True,
            "print_time": False,
            "ipopt.print_level": 0,
            "ipopt.sb": "yes",
            "ipopt.linear_solver": "mumps",
        }
        self._nlp = ca.nlpsol(
            "nmpc", "ipopt", {"x": z, "f": cost, "g": ca.vertcat(*g), "p": P}, opts
        )
        self._nlp_warm = ca.nlpsol(
            "nmpc_warm",
            "ipopt",
            {"x": z, "f": cost, "g": ca.vertcat(*g), "p": P},
            {
                **opts,
                "ipopt.warm_start_init_point": "yes",
                "ipopt.mu_init": 1e-3,
                "ipopt.warm_start_bound_push": 1e-6,
                "ipopt.warm_start_mult_bound_push": 1e-6,
            },
        )
        lbx = np.full(z.shape[0], -np.inf)
        ubx = np.full(z.shape[0], np.inf)
        ix = np.arange(NX * (n + 1)).reshape(n + 1, NX)
        lbx[ix[1:, DELTA]] = p.delta_min
        ubx[ix[1:, DELTA]] = p.delta_max
        iu = NX * (n + 1) + np.arange(NU * n).reshape(n, NU)
        lbx[iu[:, 0]], ubx[iu[:, 0]] = p.delta_dot_min, p.delta_dot_max
        lbx[iu[:, 1]], ubx[iu[:, 1]] = -p.a_max, p.a_max
        lbx[NX * (n + 1) + NU * n :] = 0.0
        self._lbx, self._ubx = lbx, ubx
        self._lbg, self._ubg = np.array(lbg), np.array(ubg)
        self.ipopt_iterations: list[int] = []

    def step(self, x, theta, memory: NmpcMemory):
        t_start = time.perf_counter()
        th, _ = self._theta(theta)
        x = np.asarray(x, dtype=float).reshape(-1)
        cfg, n = self.config, self.N
        if x.size != NX or not np.all(np.isfinite(x)):
            return self._fallback(x, th, memory, "state not finite", t_start)
        prof = self.profile(th[0])
        x_bar, u_bar = self._bars(x, memory, prof)
        pr = self.course.project(x_bar[:, :2], heading=x_bar[:, PSI] + x_bar[:, BETA])
        heading = pr.heading[1:]
        normal = np.column_stack([-np.sin(heading), np.cos(heading)])
        # course-angle error = (psi + beta) + offset, offset from the projection of the bars
        offset = pr.heading_error[1:] - (x_bar[1:, PSI] + x_bar[1:, BETA])
        v_ref = self.reference_speed(prof, pr.s[1:], float(x[V]), float(th[0]))
        stage = np.column_stack(
            [normal, pr.x[1:], pr.y[1:], offset, v_ref, v_ref * pr.curvature[1:]]
        )
        par = np.concatenate(
            [
                x,
                np.asarray(memory.u_applied, dtype=float),
                th,
                [cfg.friction_margin * th[0] * self.params.g],
                [cfg.corridor_fraction * self.course.half_width],
                stage.ravel(),
            ]
        )
        warm = memory.valid and self._warm is not None
        z0 = np.concatenate([x_bar.ravel(), u_bar.ravel(), np.zeros(2 * n)])
        args = dict(x0=z0, p=par, lbx=self._lbx, ubx=self._ubx, lbg=self._lbg, ubg=self._ubg)
        solver = self._nlp
        if warm:
            lam_x, lam_g = self._warm
            args.update(lam_x0=lam_x, lam_g0=lam_g)
            solver = self._nlp_warm
        try:
            sol = solver(**args)
            stats = solver.stats()
            status = str(stats["return_status"])
            z = np.asarray(sol["x"]).ravel()
            ok = status in _OK and np.all(np.isfinite(z))
        except Exception as exc:  # the loop must never raise
            self._warm = None
            return self._fallback(x, th, memory, f"error: {type(exc).__name__}: {exc}", t_start)
        self.ipopt_iterations.append(int(stats.get("iter_count", -1)))
        if not ok:
            self._warm = None
            return self._fallback(x, th, memory, f"ipopt: {status}", t_start)
        x_plan = z[: NX * (n + 1)].reshape(n + 1, NX)
        u_plan = z[NX * (n + 1) : NX * (n + 1) + NU * n].reshape(n, NU)
        self._warm = (
            self._shift(np.asarray(sol["lam_x"]).ravel()),
            np.asarray(sol["lam_g"]).ravel(),
        )
        u = np.clip(
            u_plan[0],
            [self.params.delta_dot_min, -self.params.a_max],
            [self.params.delta_dot_max, self.params.a_max],
        )
        new = dataclasses.replace(
            memory,
            x_plan=x_plan,
            u_plan=u_plan,
            u_applied=u,
            steps_since_solve=0,
            valid=True,
            updates=memory.updates + 1,
            consecutive_fallbacks=0,
        )
        diag = NmpcDiagnostics(
            mode="qp",  # a solved update (the closed loop counts every other mode as fallback)
            status=status,
            update_time_s=time.perf_counter() - t_start,
            iterations=int(stats.get("iter_count", -1)),
            fallback_count=new.fallback_count,
            updates=new.updates,
            mu_hat=float(th[0]),
            plan=NmpcPlan(x_plan, u_plan, mode="qp", mu_hat=float(th[0])),
        )
        return u, new, diag

    def _shift(self, lam_x: np.ndarray) -> np.ndarray:
        """Bound multipliers of the previous solution shifted by one stage (warm start)."""
        n = self.N
        out = lam_x.copy()
        xs = out[: NX * (n + 1)].reshape(n + 1, NX)
        xs[:-1] = xs[1:].copy()
        us = out[NX * (n + 1) : NX * (n + 1) + NU * n].reshape(n, NU)
        us[:-1] = us[1:].copy()
        return out


FRICTION_LIMITED_MAX_SPEED_MPS = 12.0
"""``paper_eval``'s speed cap: above every curve's friction-limited speed on the slalom."""


def _run(label, ctrl, course, mu_at, duration_s, laps, truth=None):
    prof = ctrl.profile(float(mu_at(np.array(course.sample(0.0)[:2]))))
    x0 = initial_state(course, ctrl.params, float(prof.speed_at(0.0)))
    cpu_times: list[float] = []
    inner = ctrl.step

    def timed_step(x, theta, memory):
        c0 = time.process_time()
        out = inner(x, theta, memory)
        cpu_times.append(time.process_time() - c0)
        return out

    ctrl.step = timed_step
    w, c = time.perf_counter(), time.process_time()
    res = simulate_closed_loop(
        ctrl, x0, duration_s=duration_s, mu_at=mu_at, stop_after_laps=laps, truth=truth
    )
    wall, cpu = time.perf_counter() - w, time.process_time() - c
    m = res.metrics(course)
    times = np.array([d.update_time_s for d in res.diagnostics])
    out = {
        "label": label,
        "updates": int(times.size),
        "update_ms_median": float(np.median(times) * 1e3),
        "update_ms_p95": float(np.percentile(times, 95) * 1e3),
        "update_ms_max": float(times.max() * 1e3),
        "update_cpu_ms_median": float(np.median(cpu_times) * 1e3),
        "update_cpu_ms_p95": float(np.percentile(cpu_times, 95) * 1e3),
        "updates_over_50ms_cpu": int(np.sum(np.array(cpu_times) > DEADLINE_S)),
        "updates_over_50ms": int(np.sum(times > DEADLINE_S)),
        "fraction_over_50ms": float(np.mean(times > DEADLINE_S)),
        "lateral_rms_m": m["lateral_rms_m"],
        "lateral_max_m": m["lateral_max_m"],
        "mean_speed_mps": m["mean_speed_mps"],
        "laps": m["laps"],
        "duration_s": m["duration_s"],
        "fallbacks": m["fallbacks"],
        "fallback_reasons": m["fallback_reasons"],
        "failure": m["failure"],
        "loop_wall_s": wall,
        "loop_cpu_s": cpu,
    }
    its = getattr(ctrl, "ipopt_iterations", None)
    if its:
        out["ipopt_iterations_median"] = float(np.median(its))
        out["ipopt_iterations_max"] = int(np.max(its))
    print(
        f"{label:22s} updates {out['updates']}  median {out['update_ms_median']:.1f} ms  "
        f"p95 {out['update_ms_p95']:.1f} ms  >50 ms {out['updates_over_50ms']}  "
        f"(CPU median {out['update_cpu_ms_median']:.1f} ms, "
        f">50 ms {out['updates_over_50ms_cpu']})  "
        f"lateral RMS {out['lateral_rms_m'] * 100:.3f} cm  "
        f"max {out['lateral_max_m'] * 100:.2f} cm  "
        f"v {out['mean_speed_mps']:.3f} m/s  fallbacks {out['fallbacks']}  laps {out['laps']:.2f}",
        flush=True,
    )
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="8 s of the course instead of a lap")
    ap.add_argument(
        "--friction-limited",
        action="store_true",
        help="paper_eval's friction-limited driving (12 m/s cap, multi-body truth)",
    )
    args = ap.parse_args(argv)
    result = {
        "benchmark": "peers_nmpc",
        "quick": args.quick,
        "friction_limited": args.friction_limited,
        "cpu_count": os.cpu_count(),
        "load_avg_1min": os.getloadavg()[0],
        "python": platform.python_version(),
    }
    try:
        import casadi  # noqa: F401

        result["casadi"] = importlib.metadata.version("casadi")
    except Exception as exc:
        result["peers_missing"] = {
            "casadi": f"casadi not installed ({type(exc).__name__}: {exc}); "
            "`pip install .[peers]` installs it"
        }
        print(f"PEER MISSING: {result['peers_missing']['casadi']}", flush=True)
    from pcvfe_drake.diagrams.world_io import world_terrain_map

    terrain = world_terrain_map("paper")

    def mu_at(xy):
        return float(terrain.mu_at(np.asarray(xy, dtype=float)))

    course = load_course("slalom")
    ford = ford_escort()
    cfg = NmpcConfig()
    if args.friction_limited:
        cfg = dataclasses.replace(cfg, max_speed_mps=FRICTION_LIMITED_MAX_SPEED_MPS)
    laps = None if args.quick else 1.0
    duration = (
        8.0 if args.quick else 1.6 * NmpcController(course, ford, cfg).profile(0.3).lap_time + 5.0
    )

    def truth():
        return MbTruthPlant(friction_scaling="lateral_peak") if args.friction_limited else None

    ours = _run(
        "RTI + OSQP (ours)",
        NmpcController(course, ford, cfg),
        course,
        mu_at,
        duration,
        laps,
        truth(),
    )
    result["ours"] = ours
    if "peers_missing" not in result:
        t0 = time.perf_counter()
        peer = IpoptNmpc(course, ford, cfg)
        result["ipopt_build_s"] = time.perf_counter() - t0
        result["ipopt"] = _run("CasADi + IPOPT", peer, course, mu_at, duration, laps, truth())
        result["ratio_ipopt_over_ours_median"] = (
            result["ipopt"]["update_ms_median"] / ours["update_ms_median"]
        )
        result["ratio_ipopt_over_ours_p95"] = (
            result["ipopt"]["update_ms_p95"] / ours["update_ms_p95"]
        )
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
