"""Why the friction peaks of grass and sand come out low in the loop (``paper_eval_effects``):
offline fits of saved closed-loop runs, varying what the effect model holds fixed and adds.

Input: a ``pcvfe evaluate`` output folder whose ``runs/<scenario>__<source>__sNNN/`` hold
``drive_log.parquet`` (20 Hz rows with the measured state, the true state ``true_*``, the
commands and the terrain under the car), e.g. ``pcvfe evaluate pcvfe_effects --out DIR``.

Per seed and terrain (the rows where the car was on it), with ``EffectFitter`` (the online
fitter's own fit, here on all of the terrain's 1 s windows, 10 iterations, cold start):

* ``as_run``: the scenario's model (``peak_tyre`` k_s 0 + ``axle_stiffness`` k_f 1.01, k_r 1.24)
  on the measured states, and on the true states (``true_state``: noise or not);
* ``stiffness_free``: k_f, k_r fitted too (are the fixed values the cause?);
* ``stiffness_stiff``: k_f 1.15, k_r 1.5 (what brick and concrete give when fitted);
* ``more_effects``: + ``speed_scale`` (k 0.97) + ``rolling_resistance`` (c_rr 0.003), the
  workbench's rich-excitation findings, and the same two fitted;
* ``shape_1``: the magic-formula shape C = 1.0 instead of ``peak_tyre``'s 1.35 (a flatter law);
* ``roll_camber_tyre``: + ``roll_camber`` held at the multi-body tyre's sign-of-camber constants
  (f0 -0.037, f1 0, s0 0.0027 rad); ``roll_camber_fitted``: the same three fitted;
* ``track_slip_car``: ``roll_camber_tyre`` + ``track_slip`` at the car's track widths (1.39 m,
  1.42 m); ``track_slip_fitted``: the two widths fitted;

the used friction (95th percentile over the terrain) as ``friction_used`` measures it (total
and lateral only; measured and true states); and the front axle's lateral force per load
against its slip angle from the true states (quasi-static: ``F_yf + F_yr = m a_y``, ``lf F_yf -
lr F_yr = I_z r_dot``; central differences at 20 Hz), in quartile bins of the slip, beside what
``peak_tyre`` at the terrain's true mu would give.

Without ``--runs`` the runs are made first: ``pcvfe evaluate pcvfe_effects --seeds N`` into a
temporary folder (``--quick``: one seed of the experiment's quick 30 s, sand only).

``--models project`` (with ``--scenario paper_eval_effects_project`` and that scenario's runs):
the rows of ``PROJECT_MODELS`` instead, for the project's mapping (``peak_and_stiffness``).

Usage: python studies/peak_bias/peak_bias_offline.py [--runs DIR] [--quick] [--source pcvfe_effects]
       [--scenario paper_eval_effects] [--seeds 0,1,2] [--terrains patchy_grass,sand,brick]
       [--models public|project]
Each fit takes about a second. Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.estimation.effect_fit import EffectFitter, friction_used
from pcvfe_drake.models.tyre_effects import MF_SHAPE, PeakTyre
from pcvfe_drake.vehicle.params import ford_escort

STATES = ["sx", "sy", "delta", "v", "psi", "psi_dot", "beta"]
TRUE_MU = {"patchy_grass": 0.30, "sand": 0.45, "concrete": 0.60, "brick": 0.80}
PEAK = {"name": "peak_tyre", "fixed": {"k_s": 0.0}}
AXLE = {"name": "axle_stiffness", "fixed": {"k_f": 1.01, "k_r": 1.24}}
ROLL_CAMBER_TYRE = {"f0": -0.037, "f1": 0.0, "s0": 0.0027}
"""``roll_camber`` at the multi-body tyre's own sign-of-camber offsets (``p_vy1``, ``p_hy1``)."""
TRACK = {"name": "track_slip", "fixed": {"t": 1.39, "k_lt": -0.85}}
"""``track_slip`` at the multi-body Ford Escort's track widths (``T_f``, ``T_r``) and the load
transfer its front wheels show (``studies/peak_bias/front_axle_gap.py``: the inner wheel loaded)."""
TRACK_EFFECTIVE = {"name": "track_slip", "fixed": {"t": 1.1, "k_lt": -0.85}}
MODELS = {
    "as_run": [PEAK, AXLE],
    "stiffness_free": [PEAK, {"name": "axle_stiffness"}],
    "stiffness_stiff": [PEAK, {"name": "axle_stiffness", "fixed": {"k_f": 1.15, "k_r": 1.5}}],
    "more_effects": [
        PEAK,
        AXLE,
        {"name": "speed_scale", "fixed": {"k": 0.97}},
        {"name": "rolling_resistance", "fixed": {"c_rr": 0.003}},
    ],
    "more_effects_fitted": [PEAK, AXLE, {"name": "speed_scale"}, {"name": "rolling_resistance"}],
    "roll_camber_tyre": [PEAK, AXLE, {"name": "roll_camber", "fixed": ROLL_CAMBER_TYRE}],
    "roll_camber_fitted": [PEAK, AXLE, {"name": "roll_camber"}],
    "track_slip_car": [PEAK, AXLE, {"name": "roll_camber", "fixed": ROLL_CAMBER_TYRE}, TRACK],
    "track_slip_effective": [
        PEAK,
        AXLE,
        {"name": "roll_camber", "fixed": ROLL_CAMBER_TYRE},
        TRACK_EFFECTIVE,
    ],
    "track_slip_fitted": [
        PEAK,
        AXLE,
        {"name": "roll_camber", "fixed": ROLL_CAMBER_TYRE},
        {"name": "track_slip", "fixed": {"k_lt": -0.85}},
    ],
}

PROJECT_FOUND = [
    {"name": "peak_tyre", "fixed": {"k_s": 1.19}},
    {"name": "axle_stiffness", "fixed": {"k_f": 0.96, "k_r": 1.08}},
]
"""The model the workbench's loop found on the rich-excitation multi-body log of the project's
mapping before ``roll_camber`` and ``track_slip`` were held (``paper_eval_effects_project``
until then)."""
ROLL_CAMBER = {"name": "roll_camber", "fixed": ROLL_CAMBER_TYRE}
OWN_TYRE = {"name": "peak_tyre", "fixed": {"k_s": 1.0}}
"""``peak_and_stiffness``: the multi-body tyre's small-slip stiffness is ``C_S mu`` per load at
every load and mu (its peak ``mu`` at 0.149 rad for every mu: the magic formula with C 1.35,
E -0.007), i.e. ``peak_tyre`` with k_s 1 and axle factors 1."""
PROJECT_MODELS = {
    "found_before": PROJECT_FOUND,
    "found_before_track": [*PROJECT_FOUND, TRACK],
    "found_before_track_camber": [*PROJECT_FOUND, TRACK, ROLL_CAMBER],
    "tyre_law": [OWN_TYRE, ROLL_CAMBER, TRACK],
    "tyre_law_no_camber": [OWN_TYRE, TRACK],
    "car_model": [OWN_TYRE, AXLE, ROLL_CAMBER, TRACK],
    "car_model_axle_fitted": [OWN_TYRE, {"name": "axle_stiffness"}, ROLL_CAMBER, TRACK],
}
"""``--models project`` (the project's mapping, ``paper_eval_effects_project`` runs): the model
found before, with the chassis effects held; the multi-body tyre's own law (k_s 1, no axle
factors) with them; ``car_model``: ``paper_eval_effects``' chassis (axle 1.01 / 1.24,
``roll_camber``, ``track_slip``) with k_s 1 as the mapping says (the scenario's model now)."""
MODEL_SETS = {"public": MODELS, "project": PROJECT_MODELS}


def fit(vp, effects, t, x, u, shape=MF_SHAPE) -> dict:
    old = PeakTyre.shape
    PeakTyre.shape = shape  # a flatter or sharper law: the class attribute a subclass would set
    try:
        res = EffectFitter(vp, effects, max_windows=1000, max_iterations=10)(t, x, u, None, vp.mu)
    finally:
        PeakTyre.shape = old
    values = dict(zip(res.param_names, map(float, res.model_theta), strict=True))
    return {
        "mu": float(res.theta[0]),
        "std": float(res.std[0]),
        "cost": float(res.loss),
        "params": values,
    }


def front_axle_curve(vp, t, x, mu_true: float) -> list[dict]:
    m = 1
    span = t[2 * m :] - t[: -2 * m]
    beta_dot = (x[2 * m :, 6] - x[: -2 * m, 6]) / span
    r_dot = (x[2 * m :, 5] - x[: -2 * m, 5]) / span
    v_dot = (x[2 * m :, 3] - x[: -2 * m, 3]) / span
    mid = x[m:-m]
    v, r, beta, delta = mid[:, 3], mid[:, 5], mid[:, 6], mid[:, 2]
    wheelbase = vp.lf + vp.lr
    fy = vp.m * v * (r + beta_dot)
    fyf = (vp.I_z * r_dot + vp.lr * fy) / wheelbase
    fzf = vp.m * (vp.g * vp.lr - v_dot * vp.h) / wheelbase
    alpha = delta - np.arctan((v * np.sin(beta) + vp.lf * r) / (v * np.cos(beta)))
    use = v > 2.0
    a, f = np.abs(alpha[use]), (np.sign(alpha) * fyf / fzf)[use]
    k = vp.C_Sf * vp.mu
    edges = np.quantile(a, [0.0, 0.5, 0.75, 0.9, 1.0])
    out = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (a >= lo) & (a <= hi)
        am = float(a[sel].mean())
        law = mu_true * math.sin(MF_SHAPE * math.atan(k * am / (MF_SHAPE * mu_true)))
        out.append(
            {
                "slip_rad": am,
                "force_per_load": float(f[sel].mean()),
                "secant_per_rad": float(f[sel].mean() / am),
                "peak_tyre_at_true_mu": law,
            }
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--runs", default=None, help="a pcvfe evaluate output folder (default: make the runs)"
    )
    ap.add_argument("--quick", action="store_true", help="without --runs: seed 0, 30 s, sand")
    ap.add_argument("--scenario", default="paper_eval")
    ap.add_argument("--source", default="pcvfe_effects")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--terrains", default="patchy_grass,sand,brick")
    ap.add_argument(
        "--models",
        default="public",
        choices=sorted(MODEL_SETS),
        help="the rows: the public mapping's study (default) or the project's (PROJECT_MODELS)",
    )
    args = ap.parse_args()
    if args.quick:
        args.seeds, args.terrains = "0", "sand"
    with tempfile.TemporaryDirectory(prefix="peak_bias_") as tmp:
        if args.runs is None:
            args.runs = make_runs(args, Path(tmp) / "evaluate")
        study(args)


def make_runs(args, out: Path) -> Path:
    """``pcvfe evaluate pcvfe_effects`` (``--models project``: ``pcvfe_effects_project``) for
    seeds 0 .. the largest asked (quick: its 30 s)."""
    from pcvfe_drake.cli import main as pcvfe

    n = max(int(s) for s in args.seeds.split(",")) + 1
    experiment = "pcvfe_effects_project" if args.models == "project" else "pcvfe_effects"
    cmd = ["evaluate", experiment, "--out", str(out), "--workers", "2", "--seeds", str(n)]
    cmd += ["--quick"] if args.quick else []
    print("making the runs: pcvfe " + " ".join(cmd), flush=True)
    if pcvfe(cmd) != 0:
        raise SystemExit("peak_bias_offline: pcvfe evaluate failed")
    return out


def study(args) -> None:
    vp = ford_escort()
    results = []
    for seed in [int(s) for s in args.seeds.split(",")]:
        folder = Path(args.runs) / "runs" / f"{args.scenario}__{args.source}__s{seed:03d}"
        log = pd.read_parquet(folder / "drive_log.parquet")
        for terrain in args.terrains.split(","):
            rows = log[log.terrain == terrain]
            if len(rows) < 100:
                continue
            t = rows.t.to_numpy()
            u = rows[["steer_rate", "accel"]].to_numpy()
            xm = rows[STATES].to_numpy()
            xt = rows[["true_" + c for c in STATES]].to_numpy()
            entry = {"seed": seed, "terrain": terrain, "true_mu": TRUE_MU.get(terrain)}
            models = MODEL_SETS[args.models]
            entry["fits"] = {name: fit(vp, eff, t, xm, u) for name, eff in models.items()}
            if args.models == "public":
                entry["fits"]["as_run_true_states"] = fit(vp, MODELS["as_run"], t, xt, u)
                entry["fits"]["shape_1"] = fit(vp, MODELS["as_run"], t, xm, u, shape=1.0)
            entry["used"] = {
                "measured_total": friction_used(t, xm),
                "measured_lateral": friction_used(t, xm, lateral_only=True),
                "true_total": friction_used(t, xt),
                "true_lateral": friction_used(t, xt, lateral_only=True),
            }
            entry["front_axle"] = front_axle_curve(vp, t, xt, TRUE_MU.get(terrain, vp.mu))
            fits = "  ".join(
                f"{k} {v['mu']:.3f}+-{v['std']:.3f} (cost {v['cost']:.4g})"
                for k, v in entry["fits"].items()
            )
            used = entry["used"]
            print(
                f"seed {seed} {terrain:13s} (mu {entry['true_mu']}): {fits}\n"
                f"   used: total {used['measured_total']:.3f} (true {used['true_total']:.3f}), "
                f"lateral {used['measured_lateral']:.3f} (true {used['true_lateral']:.3f})\n"
                "   front axle F/Fz at slip: "
                + ", ".join(
                    f"{b['slip_rad']:.4f} rad {b['force_per_load']:.3f} "
                    f"(law {b['peak_tyre_at_true_mu']:.3f})"
                    for b in entry["front_axle"]
                ),
                flush=True,
            )
            results.append(entry)
    print(
        json.dumps({"benchmark": "peak_bias_offline", "runs": str(args.runs), "results": results})
    )


if __name__ == "__main__":
    main()
