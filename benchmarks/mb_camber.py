"""What the multi-body truth's camber does to the lateral tyre forces, and how well
``roll_camber`` describes it (force level, no noise, no fit of the rest of the model).

CommonRoad's multi-body tyre (``vehiclemodels.utils.tire_model.formula_lateral``) adds per
wheel ``S_hy = sign(gamma) (p_hy1 + p_hy3 |gamma|)`` to the slip and ``S_vy = sign(gamma) F_z
(p_vy1 + p_vy3 |gamma|)`` to the force, gamma the wheel's camber from roll, heave and pitch.

* ``sign_check``: the package's own law on patchy grass under ``lateral_peak`` (mu 0.30) at a
  slip of 0.0129 rad in a left bend (gamma < 0, the slip negative in the package's
  convention): the force per load with gamma = 0, with gamma = -1e-6 (the sign-of-camber offsets
  alone) and with gamma = -0.03; beside it the peak tyre's law with the slip shifted by +-p_hy1
  and p_vy1 subtracted (which way the shift goes decides whether the offsets explain the
  low force the closed loop measures there, 0.156; ``peak_bias_offline.py``).
* ``drives``: per mapping and mu, 40 s of the workbench's driving program on the multi-body
  model (the driver at 0.85 mu g), sampled at 20 Hz: per axle, the camber's share of the
  lateral force per load (the package's pure lateral law per wheel, summed, with the camber
  against gamma = 0; and the sign-of-camber offsets alone, against ``p_vy1 = p_hy1 = 0``), and
  ``roll_camber``'s form ``law(alpha + s0 c) - law(alpha) + f0 c + f1 a / g``
  (``a = v psi_dot`` of the single-track state, ``c = tanh(a / 0.5 m/s^2)``, law = the axle's
  magic formula, alpha = the mean slip of its wheels) fitted to it by least squares: the
  parameters and the RMS left.

Usage: python benchmarks/mb_camber.py [--seconds S] [--quick]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import time

import numpy as np
from scipy.optimize import least_squares
from vehiclemodels.utils import tire_model

from pcvfe_drake.vehicle.mb_truth import MbTruth, st_state
from pcvfe_drake.vehicle.params import load_vehicle
from pcvfe_drake.workbench import synth
from pcvfe_drake.workbench.tyre_effects import ROLL_SIGN_WIDTH_MPS2

CASES = (("lateral_peak", 0.30), ("lateral_peak", 0.45), ("peak_and_stiffness", 0.45))


def wheel_terms(x, p):
    """Per wheel (LF, RF, LR, RR): slip angle (package convention), camber, load."""
    c6 = math.cos(x[6])
    zf = (p.h_s - p.R_w + x[16] - x[11]) / c6 - p.h_s + p.R_w
    zr = (p.h_s - p.R_w + x[21] - x[11]) / c6 - p.h_s + p.R_w
    z = (
        zf + p.a * x[8] + 0.5 * (x[6] - x[13]) * p.T_f,
        zf + p.a * x[8] - 0.5 * (x[6] - x[13]) * p.T_f,
        zr - p.b * x[8] + 0.5 * (x[6] - x[18]) * p.T_r,
        zr - p.b * x[8] - 0.5 * (x[6] - x[18]) * p.T_r,
    )
    gamma = (
        x[6] + p.D_f * z[0] + p.E_f * z[0] ** 2,
        x[6] - p.D_f * z[1] - p.E_f * z[1] ** 2,
        x[6] + p.D_r * z[2] + p.E_r * z[2] ** 2,
        x[6] - p.D_r * z[3] - p.E_r * z[3] ** 2,
    )
    fz = (
        (x[16] + p.R_w * (math.cos(x[13]) - 1) - 0.5 * p.T_f * math.sin(x[13])) * p.K_zt,
        (x[16] + p.R_w * (math.cos(x[13]) - 1) + 0.5 * p.T_f * math.sin(x[13])) * p.K_zt,
        (x[21] + p.R_w * (math.cos(x[18]) - 1) - 0.5 * p.T_r * math.sin(x[18])) * p.K_zt,
        (x[21] + p.R_w * (math.cos(x[18]) - 1) + 0.5 * p.T_r * math.sin(x[18])) * p.K_zt,
    )
    vy_f = x[10] + p.a * x[5] - x[14] * (p.R_w - x[16])
    vy_r = x[10] - p.b * x[5] - x[19] * (p.R_w - x[21])
    alpha = (
        math.atan(vy_f / (x[3] + 0.5 * p.T_f * x[5])) - x[2],
        math.atan(vy_f / (x[3] - 0.5 * p.T_f * x[5])) - x[2],
        math.atan(vy_r / (x[3] + 0.5 * p.T_r * x[5])),
        math.atan(vy_r / (x[3] - 0.5 * p.T_r * x[5])),
    )
    return alpha, gamma, fz


def sign_check(truth) -> dict:
    t = truth.parameters_for_mu(0.30).tire
    fz, alpha = 3000.0, -0.0129

    def per_load(gamma):
        return tire_model.formula_lateral(alpha, gamma, fz, t)[0] / fz

    c, d = t.p_cy1, t.p_dy1
    k = -t.p_ky1

    def law(a):
        return d * math.sin(c * math.atan(k * a / (c * d)))

    return {
        "slip_rad": -alpha,
        "package_gamma_0": round(per_load(0.0), 4),
        "package_offsets_only": round(per_load(-1e-6), 4),
        "package_gamma_minus_0.03": round(per_load(-0.03), 4),
        "law_shift_toward_bend_minus_p_vy1": round(law(-alpha + t.p_hy1) - t.p_vy1, 4),
        "law_shift_away_minus_p_vy1": round(law(-alpha - t.p_hy1) - t.p_vy1, 4),
    }


def drive(truth, vp, mapping: str, mu: float, seconds: float) -> dict:
    p = truth.parameters_for_mu(mu)
    tyre = p.tire
    no_offsets = copy.deepcopy(tyre)
    no_offsets.p_vy1 = no_offsets.p_hy1 = 0.0
    dt = 0.05
    ex = synth.design_excitation(vp, seconds, dt, 0)
    grip = synth.MB_GRIP_FRACTION * mu * vp.g / (float(np.max(synth.LATERAL_PATTERN_MPS2)) + 0.5)
    x = truth.initial_state(np.array([0.0, 0.0, 0.0, 10.0, 0.0, 0.0, 0.0]))
    rows = []
    for k in range(ex.v_ref.size):
        st = st_state(x)
        alpha, gamma, fz = wheel_terms(x, p)
        forces = []
        for law_tyre, cambered in ((tyre, True), (no_offsets, True), (tyre, False)):
            f = [
                tire_model.formula_lateral(a, g if cambered else 0.0, z, law_tyre)[0]
                for a, g, z in zip(alpha, gamma, fz, strict=True)
            ]
            forces += [f[0] + f[1], f[2] + f[3]]
        rows.append(
            [st[3] * st[5], *forces, fz[0] + fz[1], fz[2] + fz[3]]
            + [-0.5 * (alpha[0] + alpha[1]), -0.5 * (alpha[2] + alpha[3])]
        )
        steer, acc = synth.driver_commands(vp, ex, k, st[None, :], grip)
        x = truth.integrate(x, [float(steer[0]), float(acc[0])], mu, dt)
    r = np.array(rows)[int(5.0 / dt) :]  # the first 5 s settle the initial state
    a = r[:, 0]
    c, d, k_y = tyre.p_cy1, tyre.p_dy1, -tyre.p_ky1

    def law(al):
        return d * np.sin(c * np.arctan(k_y * al / (c * d)))

    out = {"mapping": mapping, "mu": mu}
    for i, axle in enumerate(("front", "rear")):
        full, no_off, no_cam = r[:, 1 + i], r[:, 3 + i], r[:, 5 + i]
        fz, alpha = r[:, 7 + i], r[:, 9 + i]
        entry = {"force_per_load_rms": round(float(np.sqrt(np.mean((full / fz) ** 2))), 4)}
        for label, target in (
            ("camber", (full - no_cam) / fz),
            ("offsets", (full - no_off) / fz),
        ):

            def resid(q, target=target, alpha=alpha):
                turn = np.tanh(a / ROLL_SIGN_WIDTH_MPS2)
                pred = law(alpha + q[2] * turn) - law(alpha) + q[0] * turn + q[1] * a / vp.g
                return pred - target

            fit = least_squares(resid, [0.0, 0.0, 0.0])
            entry[label] = {
                "rms": round(float(np.sqrt(np.mean(target**2))), 4),
                "roll_camber_f0_f1_s0": [round(float(v), 4) for v in fit.x],
                "rms_left": round(float(np.sqrt(np.mean(fit.fun**2))), 4),
            }
        out[axle] = entry
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=40.0, help="length of each drive [s]")
    parser.add_argument("--quick", action="store_true", help="15 s drives")
    args = parser.parse_args()
    if args.quick:
        args.seconds = 15.0
    t0 = time.perf_counter()
    vp = load_vehicle("ford_escort")
    check = sign_check(MbTruth("ford_escort", "lateral_peak"))
    print(json.dumps({"sign_check": check}), flush=True)
    drives = []
    for mapping, mu in CASES:
        row = drive(MbTruth("ford_escort", mapping), vp, mapping, mu, args.seconds)
        print(json.dumps(row), flush=True)
        drives.append(row)
    summary = {
        "benchmark": "mb_camber",
        "sign_check": check,
        "drives": drives,
        "wall_s": round(time.perf_counter() - t0, 1),
    }
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
