"""Why a sample waits for the estimate that uses it: each wait of a lap, by its cause.

Drives one lap (``pcvfe simulate``, in this process) with the fitter's publication and its
sample intake watched, and classes every sample a published fit counts (the samples
``ContextEstimator._published`` puts in ``sample_to_estimate_s``) by how it came to that
context:

* ``first fit``: counted by the context's first fit (it waited for the context's windows);
* ``taken with its id``: the sample carried the context's id when it was taken (after the
  first fit: the refits' cadence, a window's horizon after a gap in the context's data);
* ``noise, relabelled in``: the online clustering called its frame noise when it was taken,
  and a re-clustering gave it the context later;
* ``other id, relabelled in``: taken with another context's id (a re-clustering moved it, or
  renamed its context).

Prints, per cause, the samples, how many waited more than 1 s, and the p50/p99 of their waits,
then the p99 over all samples and without each cause; the last line is one JSON object.

Usage: python studies/estimate_latency/latency_causes.py [--scenario paper_eval] [--seed 0]
           [--duration S]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from collections import defaultdict

import numpy as np

CAUSES = ("first fit", "taken with its id", "noise, relabelled in", "other id, relabelled in")


def watch():
    """Patch the estimator's sample intake and publication; returns the dict of waits by
    cause it fills."""
    from pcvfe_drake.estimation import context_estimator as ce
    from pcvfe_drake.estimation.estimate_latency import newly_used

    taken: dict[int, int] = {}  # sample time [10 ms ticks] -> the id it was taken with
    waits: dict[str, list] = defaultdict(list)
    add_sample, published = ce.ContextEstimator.add_sample, ce.ContextEstimator._published

    def add(self, t, state, inputs, context_id):
        cid = float(np.asarray(context_id).reshape(-1)[0])
        taken[round(float(t) * 100)] = int(round(cid)) if math.isfinite(cid) and cid >= 0 else -1
        return add_sample(self, t, state, inputs, context_id)

    def publish(self, slot, t, data_end_s, t_now, used=None):
        previous = slot.estimate_data_end_s
        first = not math.isfinite(previous)
        new = newly_used(t, previous, data_end_s, used)
        ident = slot.estimate.context_id
        for ts in new:
            if first:
                cause = "first fit"
            else:
                label = taken.get(round(float(ts) * 100), -1)
                cause = (
                    "taken with its id"
                    if label == ident
                    else ("noise, relabelled in" if label < 0 else "other id, relabelled in")
                )
            waits[cause].append(t_now - ts)
        return published(self, slot, t, data_end_s, t_now, used)

    ce.ContextEstimator.add_sample = add
    ce.ContextEstimator._published = publish
    return waits


def quantiles(values) -> tuple[float, float]:
    if not len(values):
        return math.nan, math.nan
    return tuple(float(np.quantile(values, q)) for q in (0.5, 0.99))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="paper_eval")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=None, help="seconds (default: the lap)")
    args = ap.parse_args(argv)
    waits = watch()
    from pcvfe_drake.cli import main as pcvfe

    with tempfile.TemporaryDirectory() as out:
        length = [] if args.duration is None else ["--duration", str(args.duration)]
        run = ["simulate", args.scenario, "--seed", str(args.seed), *length]
        pcvfe([*run, "--no-meshcat", "--no-progress", "--out", out])
    every = np.concatenate([np.asarray(waits[c]) for c in CAUSES if waits[c]])
    rows = {}
    print(f"\n{'cause':<26} {'samples':>8} {'> 1 s':>7} {'p50 [s]':>8} {'p99 [s]':>8}")
    for cause in CAUSES:
        w = np.asarray(waits[cause])
        p50, p99 = quantiles(w)
        late = int((w > 1.0).sum())
        rows[cause] = {"samples": int(w.size), "over_1s": late, "p50_s": p50, "p99_s": p99}
        print(f"{cause:<26} {w.size:>8} {late:>7} {p50:>8.2f} {p99:>8.2f}")
    without = {
        cause: quantiles(
            np.concatenate([np.asarray(waits[c]) for c in CAUSES if c != cause and waits[c]])
        )[1]
        for cause in CAUSES
    }
    p99_all = quantiles(every)[1]
    print(f"\np99 over every sample: {p99_all:.2f} s ({every.size} samples)")
    for cause, value in without.items():
        print(f"  without '{cause}': {value:.2f} s")
    result = {
        "scenario": args.scenario,
        "seed": args.seed,
        "p99_all_s": p99_all,
        "samples": int(every.size),
        "by_cause": rows,
        "p99_without_s": without,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    sys.exit(main())
