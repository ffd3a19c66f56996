# Study helper (frozen): the quasi-likelihood ratio of a fit against the tyre without a peak, on saved buffers or time spans of a run.
import sys, numpy as np
from pcvfe_drake.models.effect_model import load_model_file
from pcvfe_drake.estimation.effect_fit import EffectFitter, drive_data_from_arrays, friction_used
from pcvfe_drake.models.estimate import training_costs, FIT_STATES
from pcvfe_drake.vehicle.params import load_vehicle
vp = load_vehicle("ford_escort"); model = load_model_file("pcvfe_drake/data/vehicles/ford_escort_lateral_peak_model.yaml")
f = EffectFitter(vp, model.effects, model_error_rel=model.model_error_rel)
def q(name, t, x, u):
    res = f(t, x, u, None, 1.05)
    if res is None: print(name, "too little"); return
    data = drive_data_from_arrays(t, x, u, "x"); starts, h, burn = f.windows(data)
    th = np.tile(res.model_theta, (2, 1)); th[1, 0] *= 1000
    c = training_costs(f.model, th, data, starts, h, burn)
    n_eff = starts.size / (f.horizon_s / f.stride_s) * len(FIT_STATES)
    n_res = starts.size * (h - burn) * len(FIT_STATES)
    lr = (c[1] - c[0]) * n_eff / c[0]
    used = friction_used(t, x, lateral_only=True)
    print(f"{name:14s} mu={res.theta[0]:.3f} std={res.std[0]:.3f} used={used:.3f} win={starts.size} loss={c[0]/n_res:.2f} dcost={c[1]-c[0]:.0f} QLR={lr:.1f}")
if sys.argv[1].endswith(".npz"):
    z = np.load(sys.argv[1])
    for k in sys.argv[2:]:
        kk = [s.rsplit("_", 1)[0] for s in z.files if s.startswith(k)][0]
        q(kk, z[kk + "_t"], z[kk + "_s"], z[kk + "_u"])
else:
    npz = np.load(f"{sys.argv[1]}/fitter_samples.npz"); t, X, U = npz["t_s"], npz["state"], npz["actuation"]
    for p in sys.argv[2].split(","):
        name, ab = p.split("="); a, b = map(float, ab.split(":")); s = (t >= a) & (t <= b)
        q(f"{name}[{a:g},{b:g}]", t[s], X[s], U[s])
