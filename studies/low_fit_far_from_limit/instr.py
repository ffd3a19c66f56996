"""Study helper (frozen): `pcvfe` with every effect refit of the run recorded.

    python instr.py OUT simulate paper_eval --with W.yaml --seed 0 --no-meshcat --no-progress

writes OUT.json (per refit: time, context, mu, std, used friction, near, identifiable, the
buffer's span) and OUT.npz (the buffers of the fits below 0.35, for qlr.py)."""

import atexit
import json
import sys

import numpy as np

import pcvfe_drake.estimation.context_estimator as ce
from pcvfe_drake.cli import main

OUT = sys.argv.pop(1)
RECORDS: list[dict] = []
BUFFERS: dict[str, tuple] = {}
_refit = ce.ContextEstimator._refit_effects


def recorded(self, slot, t, states, inputs, t_now):
    _refit(self, slot, t, states, inputs, t_now)
    e = slot.estimate
    RECORDS.append(
        {
            "t_now": float(t_now),
            "ctx": int(e.context_id),
            "mu": float(e.theta[0]),
            "std": float(e.theta_std[0]),
            "lb": float(e.mu_lower_bound),
            "near": bool(e.near_limit),
            "ident": bool(e.identifiable),
            "below": bool(e.below_used),
            "n": len(t),
            "t0": float(t[0]) if len(t) else None,
            "t1": float(t[-1]) if len(t) else None,
            "msg": e.message[:200],
        }
    )
    if e.fitted and e.theta[0] < 0.35:
        BUFFERS[f"{int(e.context_id)}_{t_now:.2f}"] = (np.asarray(t), states, inputs)


def dump():
    with open(OUT + ".json", "w") as f:
        json.dump(RECORDS, f)
    arrays = {f"{k}_{n}": v for k, tri in BUFFERS.items() for n, v in zip("tsu", tri, strict=True)}
    np.savez_compressed(OUT + ".npz", **arrays)


ce.ContextEstimator._refit_effects = recorded
atexit.register(dump)
sys.exit(main(sys.argv[1:]))
