# Study helper (frozen): records every effect refit of a run and saves the buffers of fits below 0.35.
"""Run pcvfe simulate with every effect refit recorded (and context buffers saved)."""
import atexit, json, sys, numpy as np
import pcvfe_drake.estimation.context_estimator as ce
out = sys.argv.pop(1)
rec, bufs = [], {}
orig = ce.ContextEstimator._refit_effects
def wrapped(self, slot, t, states, inputs, t_now):
    orig(self, slot, t, states, inputs, t_now)
    e = slot.estimate
    rec.append(dict(t_now=float(t_now), ctx=int(e.context_id), mu=float(e.theta[0]), std=float(e.theta_std[0]),
                    lb=float(e.mu_lower_bound), near=bool(e.near_limit), ident=bool(e.identifiable), below=bool(e.below_used),
                    n=int(len(t)), t0=float(t[0]) if len(t) else None, t1=float(t[-1]) if len(t) else None, msg=e.message[:200]))
    if e.fitted and e.theta[0] < 0.35:
        bufs[f"{int(e.context_id)}_{t_now:.2f}"] = (np.asarray(t), np.asarray(states), np.asarray(inputs))
ce.ContextEstimator._refit_effects = wrapped
def dump():
    json.dump(rec, open(out + ".json", "w"))
    np.savez_compressed(out + ".npz", **{k + "_" + n: v for k, tri in bufs.items() for n, v in zip("tsu", tri)})
atexit.register(dump)
from pcvfe_drake.cli import main
sys.exit(main(sys.argv[1:]))
