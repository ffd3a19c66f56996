"""Where the multi-body front axle's side force goes: a telescoping decomposition, at force
level, of the gap between the context fitter's tyre law and the front-axle force per load
that the single-track force balance infers from the motion (what the fit sees).

Per sample of a multi-body (MB) drive, the front axle's lateral force per static axle load
``Fz0 = m g lr / L`` (signs folded with the single-track slip's, so that the cornering force
is positive) is taken through these steps, each a number per sample; the differences of
consecutive steps sum to the whole gap exactly:

1. ``fitter_law``: ``peak_tyre`` (C 1.35, stiffness ``k_f C_Sf mu_nom (mu / mu_nom)^k_s``,
   peak mu; ``k_f`` and ``k_s`` as ``--scenario``'s fitter holds them: 1.01 and 0 in
   ``paper_eval_effects``, 0.96 and 1.19 in ``paper_eval_effects_project``) at the
   single-track slip ``alpha_f = delta - beta - lf r / v`` of the MB state, on the fitter's
   axle load ``m (g lr - a_x h) / L`` (what the scenario predicts without ``roll_camber`` and
   ``track_slip``);
2. ``package_law``: the MB tyre's own pure lateral law (``tire_model.formula_lateral``, no
   camber, no offsets) at the same slip and load (1 - 2: the fitter's law against the
   package's: shape, curvature, stiffness);
3. ``centre_slip``: the same law at the exact slip of the axle's centre, ``delta - atan((v_y
   + a r) / v_x)`` (2 - 3: the single-track model's small-angle slip, ``delta - beta - lf r
   / v``, reads 0.001 rad less in the slalom's slow bends);
4. ``wheel_slip``: the same law at each front wheel's own slip (the track width with one
   steering angle; the unsprung roll rate's term), half the load each (3 - 4:
   ``track_slip``'s spread);
5. ``wheel_load``: ... at the wheels' own loads (4 - 5: the axle load differs from the
   fitter's; the law is load-linear, so the lateral transfer matters only with slips that
   differ: ``track_slip``'s ``k_lt``);
6. ``camber``: ... with the wheels' cambers (5 - 6: ``p_vy1, p_hy1`` switched by the camber's
   sign and ``p_vy3, p_hy3, p_dy3``; what ``roll_camber`` models);
7. ``combined``: the combined-slip force (``formula_lateral_comb``: ``G_yk`` and ``S_Vyk``
   with the wheels' longitudinal slips; 6 - 7);
8. ``body``: the wheel forces in the body frame, ``F_y cos(delta) + F_x sin(delta)`` (7 - 8);
9. ``inferred_exact``: what the single-track balance ``F_f = (lr m a_y + I_z r_dot) / L``,
   ``a_y = v (r + beta_dot)``, infers from the exact rates of the MB state (8 - 9: yaw moments
   of the left/right force differences, the unsprung masses' and the sprung mass's lateral
   motions against the single-track body);
10. ``inferred``: the same with the rates by central differences over +-0.1 s of 20 Hz
    samples (``probe.axle_force_per_load``; 9 - 10).

Also per source: ``front_k_lt``, the front wheels' load transfer as ``track_slip``'s
``k_lt`` (the outer wheel's extra share of the axle load per g of ``v r``), and
``effective_track_f_m``, the width with which ``track_slip``'s two-wheel law matches the
measured wheel forces at force level (with equal loads; with the loads and the measured
``k_lt``; with the loads and ``k_lt`` 0).

The means are reported in bins of the single-track slip (and at the grass reference slip
0.0129 rad, where the closed loop measured 0.156 against the law's 0.220) and as a mu shift:
the peak mu a force-level fit of ``fitter_law`` to each step's force finds (the fitter's
error, step by step: the last step's fit is what a fit of the data would give).

Sources: ``drive`` (the workbench's rich-excitation program on the MB model, the driver at
0.85 mu g) and ``replay`` (saved closed-loop runs: each terrain visit's logged commands
replayed on the MB model in 8 s pieces from the logged true state, the first 1.5 s of each
piece dropped while the suspension settles; ``--runs``; the MB model with ``--scenario``'s
``friction_mapping``; ``yaw_rate_rms_vs_log_radps``: how far the replayed yaw rate strays from
the logged one; ``--no-drive``: the replays only).

Usage: python studies/peak_bias/front_axle_gap.py [--seconds S] [--runs DIR --seeds 0,1]
       [--scenario paper_eval_effects] [--law K_F,K_S] [--terrains patchy_grass,sand]
       [--no-drive] [--quick]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mb_camber import wheel_terms
from scipy.optimize import brentq, minimize_scalar
from vehiclemodels.utils import tire_model

from pcvfe_drake.models.chassis_effects import wheel_slip_offsets
from pcvfe_drake.models.tyre_effects import MF_SHAPE
from pcvfe_drake.progress import progress_bar
from pcvfe_drake.vehicle.mb_truth import MbTruth, st_state
from pcvfe_drake.vehicle.params import load_vehicle
from pcvfe_drake.workbench import synth

STEPS = (
    "fitter_law",
    "package_law",
    "centre_slip",
    "wheel_slip",
    "wheel_load",
    "camber",
    "combined",
    "body",
    "inferred_exact",
    "inferred",
)
SHARES = {
    "law_shape": ("fitter_law", "package_law"),
    "slip_linearisation": ("package_law", "centre_slip"),
    "track_spread": ("centre_slip", "wheel_slip"),
    "wheel_loads": ("wheel_slip", "wheel_load"),
    "camber": ("wheel_load", "camber"),
    "combined_slip": ("camber", "combined"),
    "body_projection": ("combined", "body"),
    "inference_dynamics": ("body", "inferred_exact"),
    "inference_differences": ("inferred_exact", "inferred"),
}


@dataclass(frozen=True)
class FitterLaw:
    """The context fitter's front-axle law: ``peak_tyre`` with exponent ``k_s`` and
    ``axle_stiffness``'s front factor ``k_f`` (small-slip stiffness ``k_f C_Sf mu_nom (mu /
    mu_nom)^k_s`` per load)."""

    k_f: float = 1.01
    k_s: float = 0.0

    def stiffness(self, mu, vp):
        return self.k_f * vp.C_Sf * vp.mu * (np.asarray(mu, dtype=float) / vp.mu) ** self.k_s

    def __call__(self, alpha, mu, vp):
        """Force per load at slip ``alpha`` [rad] for the peak ``mu``."""
        k = self.stiffness(mu, vp)
        return mu * np.sin(MF_SHAPE * np.arctan(k * alpha / (MF_SHAPE * mu)))


def scenario_law(name: str) -> tuple[FitterLaw, str]:
    """The law a scenario's fitter holds (``peak_tyre``'s k_s and ``axle_stiffness``'s k_f,
    as fixed in its ``fitter.effects``) and its ``friction_mapping`` (the replay's truth)."""
    import yaml

    from pcvfe_drake.diagrams.scenario_io import load_scenario
    from pcvfe_drake.runs.scenario_files import resolve_scenario_path

    spec = yaml.safe_load(resolve_scenario_path(name).read_text())
    effects = load_scenario(resolve_scenario_path(name)).fit_config().model.effects
    fixed = {e.name: e.fixed for e in effects}
    law = FitterLaw(
        k_f=float(fixed.get("axle_stiffness", {}).get("k_f", 1.0)),
        k_s=float(fixed.get("peak_tyre", {}).get("k_s", 1.0)),
    )
    return law, spec.get("friction_mapping", "peak_and_stiffness")


REFERENCE_SLIP_RAD = 0.0129
"""The grass slip at which the closed loop measured 0.156 per load (docs/fitting.md)."""
CASES = (("lateral_peak", 0.30), ("lateral_peak", 0.45), ("peak_and_stiffness", 0.45))
TRUE_MU = {"patchy_grass": 0.30, "sand": 0.45, "concrete": 0.60, "brick": 0.80}
SMOOTH_S = 0.1
MIN_SPEED_MPS = 2.0


def kappa_per_wheel(x, p):
    """The package's longitudinal slips (LF, RF, LR, RR)."""
    if abs(x[3]) < 0.1:
        return (0.0, 0.0, 0.0, 0.0)
    c, s = math.cos(x[2]), math.sin(x[2])
    u = (
        (x[3] + 0.5 * p.T_f * x[5]) * c + (x[10] + p.a * x[5]) * s,
        (x[3] - 0.5 * p.T_f * x[5]) * c + (x[10] + p.a * x[5]) * s,
        x[3] + 0.5 * p.T_r * x[5],
        x[3] - 0.5 * p.T_r * x[5],
    )
    return tuple(1.0 - p.R_w * x[23 + i] / max(u[i], 1e-6) for i in range(4))


def sample_steps(x, xdot, p, vp, mu, law: FitterLaw) -> dict:
    """Steps 1-8 (module docstring) for one MB state and its derivative; forces per Fz0,
    not yet sign-folded; plus the slip and the wheels' longitudinal slips."""
    t = p.tire
    L = vp.lf + vp.lr
    fz0 = vp.m * vp.g * vp.lr / L
    st = st_state(x)
    v, r, beta, delta = st[3], st[5], st[6], st[2]
    alpha_st = delta - beta - vp.lf * r / max(v, 0.5)
    ax = xdot[3] - x[5] * x[10]  # the longitudinal acceleration of the body
    fz_fit = vp.m * (vp.g * vp.lr - ax * vp.h) / L
    alpha_w, gamma_w, fz_w = wheel_terms(x, p)
    kap = kappa_per_wheel(x, p)

    def pure(a, g, z):
        return tire_model.formula_lateral(a, g, z, t)[0]

    out = {"alpha": alpha_st, "kappa_front": 0.5 * (kap[0] + kap[1])}
    out |= {"st_v": v, "st_r": r, "st_beta": beta, "load_ratio": fz_fit / fz0}
    out["left_share"] = fz_w[0] / (fz_w[0] + fz_w[1])
    out["fitter_law"] = float(law(alpha_st, mu, vp)) * fz_fit / fz0
    out["package_law"] = pure(-alpha_st, 0.0, fz_fit) / fz0
    centre = math.atan((x[10] + p.a * x[5]) / x[3]) - x[2]  # the package's sign
    out["centre_slip"] = pure(centre, 0.0, fz_fit) / fz0
    out["wheel_slip"] = sum(pure(alpha_w[i], 0.0, 0.5 * fz_fit) for i in (0, 1)) / fz0
    out["wheel_load"] = sum(pure(alpha_w[i], 0.0, fz_w[i]) for i in (0, 1)) / fz0
    f0y, muy = [], []
    for i in (0, 1):
        fy, m_y = tire_model.formula_lateral(alpha_w[i], gamma_w[i], fz_w[i], t)
        f0y.append(fy)
        muy.append(m_y)
    out["camber"] = sum(f0y) / fz0
    fy = [
        tire_model.formula_lateral_comb(kap[i], alpha_w[i], gamma_w[i], muy[i], fz_w[i], f0y[i], t)
        for i in (0, 1)
    ]
    fx = [
        tire_model.formula_longitudinal_comb(
            kap[i], alpha_w[i], tire_model.formula_longitudinal(kap[i], gamma_w[i], fz_w[i], t), t
        )
        for i in (0, 1)
    ]
    out["combined"] = sum(fy) / fz0
    out["body"] = (sum(fy) * math.cos(x[2]) + sum(fx) * math.sin(x[2])) / fz0
    # the single-track balance with the exact rates of the MB state
    vx, vy = x[3], x[10]
    beta_dot = (vx * xdot[10] - vy * xdot[3]) / (vx * vx + vy * vy)
    ay = v * (r + beta_dot)
    out["inferred_exact"] = (vp.lr * vp.m * ay + vp.I_z * xdot[5]) / L / fz0
    return out


def fold_and_infer(rows: list[dict], st: np.ndarray, t: np.ndarray, vp) -> dict:
    """Arrays per step, the 20 Hz central-difference inference added, signs folded with the
    slip's, samples below 2 m/s dropped."""
    cols = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    n = len(rows)
    dt = float(np.median(np.diff(t)))
    m = max(1, int(round(SMOOTH_S / dt)))
    inferred = np.full(n, np.nan)
    span = t[2 * m :] - t[: -2 * m]
    ok = np.abs(span - 2 * m * dt) <= 0.2 * m * dt
    beta_dot = (st[2 * m :, 6] - st[: -2 * m, 6]) / span
    r_dot = (st[2 * m :, 5] - st[: -2 * m, 5]) / span
    mid = st[m:-m]
    ay = mid[:, 3] * (mid[:, 5] + beta_dot)
    L = vp.lf + vp.lr
    fz0 = vp.m * vp.g * vp.lr / L
    f = (vp.lr * vp.m * ay + vp.I_z * r_dot) / L / fz0
    inferred[m:-m] = np.where(ok, f, np.nan)
    cols["inferred"] = inferred
    sign = np.sign(cols["alpha"])
    keep = np.isfinite(inferred) & (st[:, 3] >= MIN_SPEED_MPS) & (sign != 0)
    out = {k: v[keep] for k, v in cols.items()}
    out["sign"] = sign[keep]
    for k in STEPS:
        out[k] = out[k] * sign[keep]
    out["alpha"] = np.abs(out["alpha"])
    out["kappa_front"] = out["kappa_front"]
    return out


def fitted_mu(alpha: np.ndarray, force: np.ndarray, vp, mu_true: float, law: FitterLaw) -> float:
    """The peak mu with which ``fitter_law`` matches ``force`` in least squares over the
    samples whose slip is past a quarter of the law's peak slip at the true mu (where the
    peak shows); the fit's normal equation solved by bracketing."""
    k = law.stiffness(mu_true, vp)
    peak_slip = math.tan(math.pi / (2 * MF_SHAPE)) * MF_SHAPE * mu_true / k
    use = alpha >= 0.25 * peak_slip
    if use.sum() < 20:
        return math.nan
    a, f = alpha[use], force[use]

    def grad(mu):
        h = 1e-6
        e0 = law(a, mu, vp) - f
        d = (law(a, mu + h, vp) - law(a, mu - h, vp)) / (2 * h)
        return float(np.sum(e0 * d))

    lo, hi = 0.05, 2.0
    if grad(lo) * grad(hi) > 0:
        return math.nan
    return float(brentq(grad, lo, hi, xtol=1e-5))


def load_transfer_per_g(data: dict, vp) -> float:
    """``track_slip``'s ``k_lt`` of the truth's front wheel loads: the least-squares slope of
    the outer wheel's extra load share, ``1 - 2 share_left`` for a left bend, on ``v r / g``."""
    a = data["st_v"] * data["st_r"] / vp.g
    y = 1.0 - 2.0 * data["left_share"]
    return float(np.sum(a * y) / max(np.sum(a * a), 1e-12))


def effective_track(
    data: dict, vp, mu: float, target: np.ndarray, k_lt: float, law: FitterLaw
) -> float:
    """The front track width [m] with which ``track_slip``'s two-wheel law (``fitter_law`` at
    the wheels' slips, the outer one with ``(1 + k_lt v r / g) / 2`` of the load) matches
    ``target`` (sign-folded force per Fz0, the law-shape share removed) in least squares."""
    x = np.zeros((data["alpha"].size, 7))
    x[:, 3], x[:, 5], x[:, 6] = data["st_v"], data["st_r"], data["st_beta"]
    alpha = data["alpha"] * data["sign"]
    share = 0.5 * (1.0 - np.clip(k_lt * x[:, 3] * x[:, 5] / vp.g, -0.9, 0.9))

    def cost(track):
        left, right = wheel_slip_offsets(x, vp.lf, np.full(alpha.size, track))
        two = share * law(alpha + left, mu, vp) + (1.0 - share) * law(alpha + right, mu, vp)
        return float(np.sum((two * data["sign"] * data["load_ratio"] - target) ** 2))

    return float(minimize_scalar(cost, bounds=(0.0, 2.5), method="bounded").x)


def summarise(data: dict, vp, mu_true: float, law: FitterLaw) -> dict:
    a = data["alpha"]
    out = {"samples": int(a.size)}
    shape = data["fitter_law"] - data["package_law"]
    k_lt = load_transfer_per_g(data, vp)
    out["front_k_lt"] = round(k_lt, 3)
    out["effective_track_f_m"] = {
        "equal_loads": round(
            effective_track(data, vp, mu_true, data["wheel_slip"] + shape, 0.0, law), 3
        ),
        "wheel_loads_k_lt": round(
            effective_track(data, vp, mu_true, data["wheel_load"] + shape, k_lt, law), 3
        ),
        "wheel_loads_equal_shares": round(
            effective_track(data, vp, mu_true, data["wheel_load"] + shape, 0.0, law), 3
        ),
    }
    edges = np.quantile(a, [0.0, 0.5, 0.75, 0.9, 1.0]) if a.size else []
    bins = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=False):
        sel = (a >= lo) & (a <= hi)
        bins.append(
            {"slip_rad": round(float(a[sel].mean()), 4)}
            | {k: round(float(data[k][sel].mean()), 4) for k in STEPS}
        )
    out["bins"] = bins
    near = np.abs(a - REFERENCE_SLIP_RAD) <= 0.002
    if near.sum() >= 10:
        ref = {k: float(data[k][near].mean()) for k in STEPS}
        out["at_reference_slip"] = {"samples": int(near.sum())} | {
            k: round(v, 4) for k, v in ref.items()
        }
        out["at_reference_shares"] = {
            name: round(ref[s0] - ref[s1], 4) for name, (s0, s1) in SHARES.items()
        }
    mus = {k: fitted_mu(a, data[k], vp, mu_true, law) for k in STEPS}
    out["fitted_mu"] = {k: round(v, 4) for k, v in mus.items()}
    out["mu_shares"] = {name: round(mus[s0] - mus[s1], 4) for name, (s0, s1) in SHARES.items()}
    out["kappa_front_p5_p50_p95"] = [
        round(float(q), 4) for q in np.quantile(data["kappa_front"], [0.05, 0.5, 0.95])
    ]
    return out


def drive(truth, vp, mu: float, seconds: float, law: FitterLaw, dt: float = 0.05) -> dict:
    """The workbench's rich-excitation drive on the MB model (as ``mb_camber.drive``)."""
    p = truth.parameters_for_mu(mu)
    ex = synth.design_excitation(vp, seconds, dt, 0)
    grip = synth.MB_GRIP_FRACTION * mu * vp.g / (float(np.max(synth.LATERAL_PATTERN_MPS2)) + 0.5)
    x = truth.initial_state(np.array([0.0, 0.0, 0.0, 10.0, 0.0, 0.0, 0.0]))
    rows, sts, ts = [], [], []
    drive = progress_bar(
        range(ex.v_ref.size), desc=f"drive mu {mu}", leave=False, stream=sys.stderr
    )
    for k in drive:
        st = st_state(x)
        steer, acc = synth.driver_commands(vp, ex, k, st[None, :], grip)
        u = [float(steer[0]), float(acc[0])]
        if k * dt >= 5.0:  # the first 5 s settle the initial state
            rows.append(sample_steps(x, truth.rhs(list(x), u, p), p, vp, mu, law))
            sts.append(st)
            ts.append(k * dt)
        x = truth.integrate(x, u, mu, dt)
    return fold_and_infer(rows, np.array(sts), np.array(ts), vp)


def replay(
    truth, vp, log, terrain: str, law: FitterLaw, piece_s: float = 8.0, settle_s: float = 1.5
) -> dict:
    """A terrain's logged commands replayed on the MB model in pieces from the logged true
    states (module docstring); the pieces' samples concatenated with their own times."""
    import pandas as pd  # noqa: F401  (the log is a DataFrame)

    mu = TRUE_MU[terrain]
    p = truth.parameters_for_mu(mu)
    rows_all = log[log.terrain == terrain]
    t_all = rows_all.t.to_numpy()
    true_cols = ["true_" + c for c in ("sx", "sy", "delta", "v", "psi", "psi_dot", "beta")]
    xs_all = rows_all[true_cols].to_numpy()
    u_all = rows_all[["steer_rate", "accel"]].to_numpy()
    dt = float(np.median(np.diff(t_all)))
    parts, yaw_err = [], []
    start = 0
    while start < t_all.size - int(piece_s / dt) // 2:
        stop = min(start + int(round(piece_s / dt)), t_all.size - 1)
        if np.any(np.diff(t_all[start : stop + 1]) > 1.5 * dt):  # a gap: next visit
            gap = start + int(np.argmax(np.diff(t_all[start : stop + 1]) > 1.5 * dt)) + 1
            start = gap
            continue
        x = truth.initial_state(xs_all[start])
        rows, sts, ts = [], [], []
        for k in range(start, stop):
            u = [float(u_all[k, 0]), float(u_all[k, 1])]
            if t_all[k] - t_all[start] >= settle_s:
                rows.append(sample_steps(x, truth.rhs(list(x), u, p), p, vp, mu, law))
                sts.append(st_state(x))
                ts.append(t_all[k])
                yaw_err.append(sts[-1][5] - xs_all[k, 5])
            x = truth.integrate(x, u, mu, dt)
        if len(rows) > 10:
            parts.append(fold_and_infer(rows, np.array(sts), np.array(ts), vp))
        start = stop
    if not parts:
        return {}
    out = {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}
    out["yaw_rate_rms_vs_log"] = float(np.sqrt(np.mean(np.square(yaw_err))))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="length of each drive [s]")
    ap.add_argument("--runs", default=None, help="a pcvfe evaluate folder to replay")
    ap.add_argument("--scenario", default="paper_eval")
    ap.add_argument("--source", default="pcvfe_effects")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--terrains", default="patchy_grass,sand")
    ap.add_argument("--quick", action="store_true", help="one 20 s drive at mu 0.30, no replay")
    ap.add_argument("--no-drive", action="store_true", help="the replays of --runs only")
    ap.add_argument(
        "--law",
        default=None,
        metavar="K_F,K_S",
        help="the fitter's law instead of the scenario's (e.g. 0.96,1.19)",
    )
    args = ap.parse_args()
    t0 = time.perf_counter()
    vp = load_vehicle("ford_escort")
    cases = () if args.no_drive else CASES[:1] if args.quick else CASES
    seconds = 20.0 if args.quick else args.seconds
    law, replay_mapping = scenario_law(args.scenario)
    if args.law:
        try:
            k_f, k_s = (float(v) for v in args.law.split(","))
        except ValueError:
            ap.error(f"--law takes K_F,K_S (two numbers), got {args.law!r}")
        law = FitterLaw(k_f, k_s)
    results = []
    for mapping, mu in cases:
        data = drive(MbTruth("ford_escort", mapping), vp, mu, seconds, law)
        row = {"source": "drive", "mapping": mapping, "mu": mu} | summarise(data, vp, mu, law)
        print(json.dumps(row), flush=True)
        results.append(row)
    if args.runs and not args.quick:
        import pandas as pd

        truth = MbTruth("ford_escort", replay_mapping)
        for seed in [int(s) for s in args.seeds.split(",")]:
            folder = Path(args.runs) / "runs" / f"{args.scenario}__{args.source}__s{seed:03d}"
            log = pd.read_parquet(folder / "drive_log.parquet")
            for terrain in args.terrains.split(","):
                data = replay(truth, vp, log, terrain, law)
                if not data:
                    continue
                mu = TRUE_MU[terrain]
                row = {"source": "replay", "seed": seed, "terrain": terrain, "mu": mu}
                row["yaw_rate_rms_vs_log_radps"] = round(data.pop("yaw_rate_rms_vs_log"), 4)
                row |= summarise(data, vp, mu, law)
                print(json.dumps(row), flush=True)
                results.append(row)
    print(
        json.dumps(
            {
                "benchmark": "front_axle_gap",
                "scenario": args.scenario,
                "fitter_law": {"k_f": law.k_f, "k_s": law.k_s},
                "replay_mapping": replay_mapping,
                "results": results,
                "wall_s": round(time.perf_counter() - t0, 1),
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
