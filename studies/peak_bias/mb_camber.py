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
* ``wheel_signs`` (per drive): when each wheel's camber sign switches. Per wheel (LF, RF, LR,
  RR; left = the package's ``+T/2`` wheel) the share of time its sign is predicted right by
  ``-sign(v psi_dot)`` (``roll_camber``'s per-axle direction) and by ``wheel_camber``'s
  form ``-sign(a_roll +- k_x a_x)`` (``a_roll`` the model's lateral acceleration
  ``v_y' + v_x psi_dot`` lagged by ``tau``, ``a_x`` the command), ``k_x`` and an offset
  fitted per wheel by least squares on the camber, for the lags in ``ROLL_TAUS``; the
  roll angle's correlation with each lag; the static cambers (the initial state); and per
  axle the RMS of the load-weighted mean of its wheels' signs (the sign-of-camber offsets'
  force over ``p_vy1`` Fz) left by ``roll_camber``'s ``tanh(v psi_dot / 0.5)`` and by
  ``wheel_camber``'s mean sign at ``WHEEL_CAMBER_FORM`` for the widths in ``SIGN_WIDTHS``.

Usage: python studies/peak_bias/mb_camber.py [--seconds S] [--quick]
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
from scipy.signal import lfilter
from vehiclemodels.utils import tire_model

from pcvfe_drake.models.tyre_effects import ROLL_SIGN_WIDTH_MPS2
from pcvfe_drake.vehicle.mb_truth import MbTruth, st_state
from pcvfe_drake.vehicle.params import load_vehicle
from pcvfe_drake.workbench import synth

CASES = (("lateral_peak", 0.30), ("lateral_peak", 0.45), ("peak_and_stiffness", 0.45))
ROLL_TAUS = (0.0, 0.03, 0.05, 0.08, 0.1, 0.15)
"""Roll lags tried in ``wheel_signs`` [s] (0: the lateral acceleration itself)."""
SIGN_WIDTHS = (0.1, 0.3, 0.5)
"""Widths of the smooth sign tried in ``wheel_signs`` [m/s^2]."""
WHEEL_CAMBER_FORM = {"k_xf": 0.39, "k_xr": -0.095, "tau": 0.08}
"""``wheel_camber``'s geometry as held in ``validation/workbench_multibody.py``."""


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
    signs = []
    for k in range(ex.v_ref.size):
        st = st_state(x)
        alpha, gamma, fz = wheel_terms(x, p)
        steer, acc = synth.driver_commands(vp, ex, k, st[None, :], grip)
        u = [float(steer[0]), float(acc[0])]
        a_lat = float(truth.derivatives(x, u, mu)[10] + x[3] * x[5])
        signs.append([*gamma, *fz, a_lat, u[1], st[3] * st[5], x[6]])
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
        x = truth.integrate(x, u, mu, dt)
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
    out["wheel_signs"] = wheel_signs(np.array(signs), dt, int(5.0 / dt))
    return out


def _lag(a: np.ndarray, tau: float, dt: float) -> np.ndarray:
    """``a`` through a first-order lag ``tau``, from its first value, each sample's value
    taken over the step that ends at it (the sampled signal neither delayed nor led by a step;
    a rollout integrates the lag continuously)."""
    if tau <= 0.0:
        return a
    e = math.exp(-dt / tau)
    return lfilter([1.0 - e], [1.0, -e], a - a[0]) + a[0]


def wheel_signs(rec: np.ndarray, dt: float, skip: int) -> dict:
    """The ``wheel_signs`` entry (module docstring) of a drive's per-step records ``rec``
    (gamma x4, F_z x4, lateral acceleration, acceleration command, v psi_dot, roll)."""
    gamma, fz = rec[:, 0:4], rec[:, 4:8]
    a_lat, a_x, v_r, roll = rec[:, 8], rec[:, 9], rec[:, 10], rec[:, 11]
    s = slice(skip, None)
    truth_sign = np.sign(gamma[s])
    out = {
        "static_camber_rad": [round(float(g), 4) for g in gamma[0]],
        "sign_right_roll_camber": [
            round(float(np.mean(truth_sign[:, w] == -np.sign(v_r[s]))), 3) for w in range(4)
        ],
    }
    per_tau = {}
    for tau in ROLL_TAUS:
        a = _lag(a_lat, tau, dt)
        right, k_x = [], []
        for w in range(4):
            m = np.column_stack([np.ones(a.size), a, a_x])[s]
            c, *_ = np.linalg.lstsq(m, gamma[s, w], rcond=None)
            right.append(round(float(np.mean(np.sign(m @ c) == truth_sign[:, w])), 3))
            k_x.append(round(float(c[2] / c[1]), 3))
        per_tau[str(tau)] = {
            "sign_right": right,
            "k_x": k_x,
            "roll_corr": round(float(np.corrcoef(a[s], roll[s])[0, 1]), 4),
        }
    out["wheel_camber_form"] = per_tau
    a = _lag(a_lat, WHEEL_CAMBER_FORM["tau"], dt)
    for i, (axle, key) in enumerate((("front", "k_xf"), ("rear", "k_xr"))):
        left, right = 2 * i, 2 * i + 1
        net = (np.sign(gamma[:, left]) * fz[:, left] + np.sign(gamma[:, right]) * fz[:, right]) / (
            fz[:, left] + fz[:, right]
        )
        k_x = WHEEL_CAMBER_FORM[key]
        entry = {
            "rms": round(float(np.sqrt(np.mean(net[s] ** 2))), 3),
            "rms_left_roll_camber": round(
                float(np.sqrt(np.mean((net + np.tanh(v_r / ROLL_SIGN_WIDTH_MPS2))[s] ** 2))), 3
            ),
        }
        for width in SIGN_WIDTHS:
            mean = 0.5 * (np.tanh((a + k_x * a_x) / width) + np.tanh((a - k_x * a_x) / width))
            entry[f"rms_left_wheel_camber_w{width}"] = round(
                float(np.sqrt(np.mean((net + mean)[s] ** 2))), 3
            )
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
