"""Study helper (frozen): the quasi-likelihood ratio of a cold batch fit against the same tyre
without a peak, on buffers saved by instr.py or on time spans of a run folder.

    python qlr.py OUT.npz 6_95 1_23            # buffers (context_time prefixes)
    python qlr.py RUN "gravel=67:88,mulch=1:15"  # time spans of RUN/fitter_samples.npz
"""

import sys

import numpy as np

from pcvfe_drake.estimation.effect_fit import EffectFitter, drive_data_from_arrays, friction_used
from pcvfe_drake.estimation.fit_quality import peak_evidence
from pcvfe_drake.models.effect_model import load_model_file
from pcvfe_drake.vehicle.params import load_vehicle

MODEL = "pcvfe_drake/data/vehicles/ford_escort_lateral_peak_model.yaml"
VP = load_vehicle("ford_escort")
SPEC = load_model_file(MODEL)
FITTER = EffectFitter(VP, SPEC.effects, model_error_rel=SPEC.model_error_rel)


def report(name, t, x, u):
    res = FITTER(t, x, u, None, VP.mu)
    if res is None:
        print(name, "too little data")
        return
    data = drive_data_from_arrays(t, x, u, name)
    starts, horizon, burn_in = FITTER.windows(data)
    overlap = FITTER.horizon_s / FITTER.stride_s
    ratio = peak_evidence(FITTER.model, res.model_theta, data, starts, horizon, burn_in, overlap)
    used = friction_used(t, x, lateral_only=True)
    print(
        f"{name:16s} mu={res.theta[0]:.3f} std={res.std[0]:.3f} used={used:.3f} "
        f"windows={starts.size} ratio={ratio:.1f}"
    )


if sys.argv[1].endswith(".npz"):
    saved = np.load(sys.argv[1])
    for prefix in sys.argv[2:]:
        key = next(k.rsplit("_", 1)[0] for k in saved.files if k.startswith(prefix))
        report(key, saved[key + "_t"], saved[key + "_s"], saved[key + "_u"])
else:
    npz = np.load(f"{sys.argv[1]}/fitter_samples.npz")
    t, x, u = npz["t_s"], npz["state"], npz["actuation"]
    for part in sys.argv[2].split(","):
        name, span = part.split("=")
        a, b = (float(v) for v in span.split(":"))
        s = (t >= a) & (t <= b)
        report(f"{name}[{a:g},{b:g}]", t[s], x[s], u[s])
