"""What the multi-body truth's suspension does to the axle loads and the lateral forces.

CommonRoad's multi-body model (``pcvfe_drake.vehicle.mb_truth``, Ford Escort) measured
directly, states and forces, no noise:

* ``step``: a braking step (0 -> -4 m/s^2 command at 12 m/s, after 3 s of settling): the
  front-axle load transfer (the tyre loads from the unsprung masses' deflection) over the
  single-track model's instantaneous ``m a_x h / L`` with the car's actual ``a_x``: when it
  first reaches 1, its peak (overshoot), the ringing period, the value it settles on, and the
  damped second-order mode ``tau^2 q'' + 2 zeta tau q' + q = a_x`` (``suspension_lag``)
  fitted to it by least squares;
* ``drive``: 60 s of the workbench's driving program on mu 0.6 (``peak_and_stiffness``, the
  driver scaled to 0.85 mu g): the RMS error of the front-axle load transfer predicted
  instantly and through that mode (from the car's actual a_x), and the static load split
  (the model's ``m g l_r / L`` against the multi-body model's, whose unsprung masses are
  equal front and rear);
* ``camber``: over the same drive, the lateral force the tyre model adds for camber
  (CommonRoad's ``S_vy = sign(gamma) F_z (p_vy1 + p_vy3 |gamma|)`` per wheel, gamma from
  roll, heave and pitch through the suspension), summed per axle: its RMS against the axle's
  lateral force, its correlation with the lateral acceleration, and what is left after a
  regression on sign(a_y), a_y and a_x sign(a_y) (the part no function of the accelerations
  describes: roll and pitch dynamics, the sign flips).

Usage: python studies/mb_suspension/mb_suspension.py
       [--seconds S] [--mu MU] [--quick]  (--quick: 20 s)
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np
from scipy.optimize import least_squares

from pcvfe_drake.models.chassis_effects import mode_transition
from pcvfe_drake.progress import progress_bar
from pcvfe_drake.vehicle.mb_truth import MbTruth, st_state
from pcvfe_drake.vehicle.params import load_vehicle
from pcvfe_drake.workbench import synth

H_S = 0.005
"""Sample step of the measurements [s]."""
SETTLE_S = 3.0
"""Cruise before the braking step [s] (the multi-body initial state settles on its springs)."""


def front_load(x, p) -> float:
    """Front-axle tyre load [N] of a multi-body state (the package's F_z_LF + F_z_RF)."""
    return 2.0 * (x[16] + p.R_w * (math.cos(x[13]) - 1.0)) * p.K_zt


def body_accel(truth, x, u, p) -> float:
    """The car's longitudinal acceleration from its forces [m/s^2] (sumX / m)."""
    f = truth.rhs(list(x), u, p)
    return float(f[3] - x[5] * x[10])


def mode_response(a: np.ndarray, tau: float, zeta: float, dt: float) -> np.ndarray:
    """``q`` of the damped mode driven by ``a`` held over each step, from rest at ``a[0]``."""
    p11, p12, p21, p22 = (float(v) for v in mode_transition(tau, zeta, dt))
    q = np.empty_like(a)
    s0, s1 = a[0], 0.0
    for i, ai in enumerate(a):
        q[i] = s0
        e = s0 - ai
        s0, s1 = ai + p11 * e + p12 * s1, p21 * e + p22 * s1
    return q


def step(truth, vp) -> dict:
    p = truth.parameters_for_mu(truth.mu_nominal)
    x = truth.initial_state(np.array([0.0, 0.0, 0.0, 12.0, 0.0, 0.0, 0.0]))
    wheelbase = vp.lf + vp.lr
    t, ff, ax = [], [], []
    for k in range(int((SETTLE_S + 3.0) / H_S)):
        u = [0.0, 0.0 if k * H_S < SETTLE_S else -4.0]
        t.append(k * H_S)
        ff.append(front_load(x, p))
        ax.append(body_accel(truth, x, u, p))
        x = truth.integrate(x, u, truth.mu_nominal, H_S)
    t, ff, ax = np.array(t), np.array(ff), np.array(ax)
    before = t < SETTLE_S
    static = float(ff[before][-1])
    on = t >= SETTLE_S
    ts = t[on] - SETTLE_S
    # over the instant transfer of the step's mean acceleration (the tyre forces, and with
    # them a_x, build up within ~0.05 s as the wheels slip)
    a_mean = float(np.mean(ax[on][ts > 0.05]))
    ratio = (ff[on] - static) / (-vp.m * a_mean * vp.h / wheelbase)
    first = float(ts[np.argmax(ratio >= 1.0)])
    inner = np.arange(1, ratio.size - 1)
    peaks = inner[(ratio[inner] >= ratio[inner - 1]) & (ratio[inner] > ratio[inner + 1])]
    period = float(ts[peaks[1]] - ts[peaks[0]]) if len(peaks) > 1 else float("nan")
    settled = float(np.mean(ratio[ts > 2.0]))
    a_in = np.concatenate([ax[before][-1:], ax[on]])
    target = ff[on] - static

    def resid(z):
        q = mode_response(a_in, z[0], z[1], H_S)[1:]
        return -vp.m * q * vp.h / wheelbase - target

    # from rest: the mode is driven from the pre-step acceleration
    fit = least_squares(resid, [0.12, 0.3], bounds=([0.02, 0.02], [0.5, 2.0]))
    return {
        "front_static_N": round(static, 1),
        "step_accel_mps2": round(a_mean, 3),
        "first_reaches_instant_s": round(first, 3),
        "peak_over_instant": round(float(ratio[peaks[0]]) if peaks.size else float("nan"), 3),
        "peak_at_s": round(float(ts[peaks[0]]) if peaks.size else float("nan"), 3),
        "ringing_period_s": round(period, 3),
        "settles_at_over_instant": round(settled, 3),
        "fitted_tau_s": round(float(fit.x[0]), 4),
        "fitted_zeta": round(float(fit.x[1]), 3),
        "fitted_frequency_hz": round(1.0 / (2.0 * math.pi * float(fit.x[0])), 3),
        "fit_rms_N": round(float(np.sqrt(np.mean(fit.fun**2))), 1),
    }


def camber_force(x, p) -> tuple[float, float]:
    """Per axle, the tyre model's camber force ``sum sign(gamma) F_z (p_vy1 + p_vy3 |g|)``."""
    c6 = math.cos(x[6])
    zf = (p.h_s - p.R_w + x[16] - x[11]) / c6 - p.h_s + p.R_w
    zr = (p.h_s - p.R_w + x[21] - x[11]) / c6 - p.h_s + p.R_w
    z_lf = zf + p.a * x[8] + 0.5 * (x[6] - x[13]) * p.T_f
    z_rf = zf + p.a * x[8] - 0.5 * (x[6] - x[13]) * p.T_f
    z_lr = zr - p.b * x[8] + 0.5 * (x[6] - x[18]) * p.T_r
    z_rr = zr - p.b * x[8] - 0.5 * (x[6] - x[18]) * p.T_r
    gam = (
        x[6] + p.D_f * z_lf + p.E_f * z_lf**2,
        x[6] - p.D_f * z_rf - p.E_f * z_rf**2,
        x[6] + p.D_r * z_lr + p.E_r * z_lr**2,
        x[6] - p.D_r * z_rr - p.E_r * z_rr**2,
    )
    fz = (
        (x[16] + p.R_w * (math.cos(x[13]) - 1) - 0.5 * p.T_f * math.sin(x[13])) * p.K_zt,
        (x[16] + p.R_w * (math.cos(x[13]) - 1) + 0.5 * p.T_f * math.sin(x[13])) * p.K_zt,
        (x[21] + p.R_w * (math.cos(x[18]) - 1) - 0.5 * p.T_r * math.sin(x[18])) * p.K_zt,
        (x[21] + p.R_w * (math.cos(x[18]) - 1) + 0.5 * p.T_r * math.sin(x[18])) * p.K_zt,
    )
    t = p.tire
    s = [np.sign(g) * f * (t.p_vy1 + t.p_vy3 * abs(g)) for g, f in zip(gam, fz, strict=True)]
    opposite = float(np.sign(gam[0]) != np.sign(gam[1]))
    return s[0] + s[1], s[2] + s[3], opposite


def drive(truth, vp, seconds: float, mu: float, mode: tuple[float, float]) -> dict:
    p = truth.parameters_for_mu(mu)
    dt, sub = 0.05, 10
    ex = synth.design_excitation(vp, seconds, dt, 0)
    grip = synth.MB_GRIP_FRACTION * mu * vp.g / (float(np.max(synth.LATERAL_PATTERN_MPS2)) + 0.5)
    x = truth.initial_state(np.array([0.0, 0.0, 0.0, 10.0, 0.0, 0.0, 0.0]))
    rows = []
    for k in progress_bar(range(ex.v_ref.size), desc="multi-body drive", leave=False):
        st = st_state(x)
        steer, acc = synth.driver_commands(vp, ex, k, st[None, :], grip)
        u = [float(steer[0]), float(acc[0])]
        for _ in range(sub):
            f = truth.rhs(list(x), u, p)
            cf, cr, opp = camber_force(x, p)
            rows.append([front_load(x, p), f[3] - x[5] * x[10], x[3] * x[5], cf, cr, opp])
            x = truth.integrate(x, u, mu, dt / sub)
    r = np.array(rows)[int(5.0 / (dt / sub)) :]  # the first 5 s settle the initial state
    ff, ax, ay, cf, cr, opp = r[:, 0], r[:, 1], r[:, 2], r[:, 3], r[:, 4], r[:, 5]
    wheelbase = vp.lf + vp.lr
    h = dt / sub
    out = {"seconds": seconds, "mu": mu}
    transfer = ff - np.mean(ff + vp.m * ax * vp.h / wheelbase)
    instant = -vp.m * ax * vp.h / wheelbase
    lagged = -vp.m * mode_response(ax, mode[0], mode[1], h) * vp.h / wheelbase
    out["front_transfer_rms_N"] = round(float(np.std(transfer)), 1)
    out["instant_error_rms_N"] = round(float(np.sqrt(np.mean((transfer - instant) ** 2))), 1)
    out["mode_error_rms_N"] = round(float(np.sqrt(np.mean((transfer - lagged) ** 2))), 1)
    out["mode"] = {"tau_s": mode[0], "zeta": mode[1]}
    static_mb = float(np.mean(ff + vp.m * ax * vp.h / wheelbase))
    out["front_static_N"] = {
        "multi_body": round(static_mb, 1),
        "single_track": round(vp.m * vp.g * vp.lr / wheelbase, 1),
    }
    front_lat = vp.m * ay * vp.lr / wheelbase
    rear_lat = vp.m * ay * vp.lf / wheelbase
    basis = np.column_stack([np.sign(ay), ay, ax * np.sign(ay), np.ones_like(ay)])
    for name, force, lat in (("front", cf, front_lat), ("rear", cr, rear_lat)):
        coef, *_ = np.linalg.lstsq(basis, force, rcond=None)
        left = force - basis @ coef
        out[f"camber_{name}"] = {
            "rms_N": round(float(np.sqrt(np.mean(force**2))), 1),
            "axle_lateral_force_rms_N": round(float(np.sqrt(np.mean(lat**2))), 1),
            "corr_with_ay": round(float(np.corrcoef(force, ay)[0, 1]), 3),
            "unexplained_by_accelerations_rms_N": round(float(np.sqrt(np.mean(left**2))), 1),
        }
    out["front_cambers_of_opposite_sign"] = round(float(np.mean(opp)), 3)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="length of the drive [s]")
    parser.add_argument("--mu", type=float, default=0.6, help="friction of the drive")
    parser.add_argument("--quick", action="store_true", help="a 20 s drive")
    args = parser.parse_args()
    if args.quick:
        args.seconds = 20.0
    t0 = time.perf_counter()
    vp = load_vehicle("ford_escort")
    truth = MbTruth("ford_escort", "peak_and_stiffness")
    s = step(truth, vp)
    print(json.dumps({"step": s}), flush=True)
    d = drive(truth, vp, args.seconds, args.mu, (s["fitted_tau_s"], s["fitted_zeta"]))
    print(json.dumps({"drive": d}), flush=True)
    print(
        json.dumps(
            {
                "benchmark": "mb_suspension",
                "step": s,
                "drive": d,
                "wall_s": round(time.perf_counter() - t0, 1),
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
