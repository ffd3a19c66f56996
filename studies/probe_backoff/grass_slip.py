"""The probe's slip test on a stored run's visits of one terrain: per 1 s window, the 90th
percentile of each axle's kinematic slip angle (from the measured and from the true
single-track states) against the test's limit at a handed friction.

    python studies/probe_backoff/grass_slip.py RUN [--terrain patchy_grass] [--mu 0.3]

``RUN`` is a run folder (its ``drive_log.parquet``, 20 Hz, with the true states); the limit is
``SLIP_FRACTION`` of the peak slip of the car's prior small-slip stiffness at ``--mu`` (what
the probe judges a level before its fit by, ``lateral_peak``).

Beside the measured slips it predicts the front axle's kinematic slip from the lateral
acceleration (steady cornering: the axle's force per load is ``a_y / g``) by the tyre the
slip test assumes (a magic-formula tyre at ``--mu`` with the prior stiffness, ``pred_prior``)
and by the car's calibrated model (``pred_model``: its front stiffness factor
``axle_stiffness.k_f``, and ``roll_camber``'s step force ``f0`` and slip shift ``s0``, which
the tyre law works against: ``q = (|a_y| / g - f0 s) / mu``, kinematic slip ``alpha(q) -
s0 s``, ``s = tanh(|a_y| / 0.5 m/s^2)``). Prints a JSON object last.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import pandas as pd

from pcvfe_drake.estimation import probe as P
from pcvfe_drake.models.effect_model import load_model_file, vehicle_model_path
from pcvfe_drake.models.tyre_effects import ROLL_SIGN_WIDTH_MPS2
from pcvfe_drake.vehicle.params import load_vehicle

ST = ["sx", "sy", "delta", "v", "psi", "psi_dot", "beta"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--terrain", default="patchy_grass")
    ap.add_argument("--mu", type=float, default=0.3)
    ap.add_argument("--vehicle", default="ford_escort")
    ap.add_argument("--mapping", default="lateral_peak")
    args = ap.parse_args()
    vp = load_vehicle(args.vehicle)
    df = pd.read_parquet(f"{args.run}/drive_log.parquet")
    limit = P.SLIP_FRACTION * P.peak_slip_rad(args.mu, vp.mu * np.array([vp.C_Sf, vp.C_Sr]))
    g = df[df.terrain == args.terrain]
    t = g.t.to_numpy()
    measured = P.axle_slip_angles(g[ST].to_numpy(), vp.lf, vp.lr)
    true = P.axle_slip_angles(g[["true_" + c for c in ST]].to_numpy(), vp.lf, vp.lr)
    ay_g = np.abs(g.v.to_numpy() * g.psi_dot.to_numpy()) / vp.g
    held = held_constants(args.vehicle, args.mapping)
    stiffness = vp.mu * vp.C_Sf  # the prior's front small-slip stiffness per load [1/rad]
    pred_prior = front_slip(ay_g, args.mu, stiffness, 0.0, 0.0, vp.g)
    k_f = stiffness * held.get("axle_stiffness.k_f", 1.0)
    f0, s0 = held.get("roll_camber.f0", 0.0), held.get("roll_camber.s0", 0.0)
    pred_model = front_slip(ay_g, args.mu, k_f, f0, s0, vp.g)
    # the front axle's force in a transient bend: the lateral acceleration v (r + beta') (the
    # side slip's rate included) and the yaw acceleration, F_yf = (m a_y lr + I_z r') / L, per
    # its static load m g lr / L: a_y / g + I_z r' / (m g lr) (true states, central differences)
    tv, tr, tb = (g[f"true_{c}"].to_numpy() for c in ("v", "psi_dot", "beta"))
    a_y = tv * (tr + np.gradient(tb, t))
    front_g = np.abs(a_y / vp.g + vp.I_z * np.gradient(tr, t) / (vp.m * vp.g * vp.lr))
    pred_yaw = front_slip(front_g, args.mu, k_f, f0, s0, vp.g)
    rows = []
    for t0 in np.arange(t[0], t[-1], 1.0):
        m = (t >= t0) & (t < t0 + 1.0)
        if m.sum() < 5:
            continue
        row = {"t": round(float(t0), 1), "ay_g_max": round(float(ay_g[m].max()), 3)}
        for name, (front, rear) in (("measured", measured), ("true", true)):
            row[f"front_{name}"] = round(float(np.quantile(np.abs(front[m]), 0.9)), 4)
            row[f"rear_{name}"] = round(float(np.quantile(np.abs(rear[m]), 0.9)), 4)
        for name, pred in (
            ("pred_prior", pred_prior),
            ("pred_model", pred_model),
            ("pred_yaw", pred_yaw),
        ):
            row[name] = round(float(np.nanquantile(pred[m], 0.9)), 4)
        rows.append(row)
    table = pd.DataFrame(rows)
    print(table.to_string(index=False))
    demand = P.DEFAULT_PROBE_USE_FRACTION * args.mu  # the planner's demand at the level [g]
    bends = table[table.ay_g_max >= 0.6 * demand]
    out = {
        "limit_rad": [round(float(v), 4) for v in np.broadcast_to(limit, (2,))],
        "windows_in_bends": int(len(bends)),
        "front_true_p90_median_in_bends": round(float(bends.front_true.median()), 4),
        "front_measured_p90_median_in_bends": round(float(bends.front_measured.median()), 4),
        "ay_g_max_median_in_bends": round(float(bends.ay_g_max.median()), 3),
        "front_pred_prior_p90_median_in_bends": round(float(bends.pred_prior.median()), 4),
        "front_pred_model_p90_median_in_bends": round(float(bends.pred_model.median()), 4),
        "front_pred_yaw_p90_median_in_bends": round(float(bends.pred_yaw.median()), 4),
        "held": held,
    }
    print(json.dumps(out))


def held_constants(vehicle: str, mapping: str) -> dict:
    """``{effect.param: value}`` of the car's shipped model (its held constants)."""
    model = load_model_file(vehicle_model_path(vehicle, "mb", mapping))
    return {f"{e.name}.{k}": float(v) for e in model.effects for k, v in e.fixed.items()}


def front_slip(ay_g, mu, stiffness, f0, s0, g):
    """The front axle's kinematic slip [rad] a magic-formula tyre (peak ``mu``, small-slip
    stiffness ``stiffness`` per load, shape ``probe.MF_SHAPE``) needs for the force per load
    ``|a_y| / g`` with ``roll_camber``'s step force ``f0`` and slip shift ``s0``; NaN past the
    peak."""
    s = np.tanh(ay_g * g / ROLL_SIGN_WIDTH_MPS2)
    q = (ay_g - f0 * s) / mu
    c = P.MF_SHAPE
    with np.errstate(invalid="ignore"):
        law = np.tan(np.arcsin(np.where(q < 1.0, q, np.nan)) / c) * c * mu / stiffness
    return law - s0 * s


if __name__ == "__main__":
    main()
