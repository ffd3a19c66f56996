"""Where the PC-VFE loop's CPU time goes, against the oracle loop (cProfile).

Drives the scenario's lap (``--duration`` s) once with ``--estimator pcvfe`` and once with
``--estimator oracle``, each in its own process under cProfile, and prints per loop the
cumulative seconds of the estimator's parts (refits and their rollouts, the fitter's sample
event, Drake's copies of the estimator, the clustering, the features) and of the whole
``AdvanceTo``. cProfile's own cost falls on Python function calls, so the Python-heavy parts
read larger than they are; compare parts within one run, and take the loops' CPU times from
``benchmarks/estimator_budget.py``.

Usage: python studies/estimator_profile/profile_loop.py [--scenario paper_eval] [--duration 45]
"""

from __future__ import annotations

import argparse
import pstats
import subprocess
import sys
import tempfile
from pathlib import Path

PARTS = {
    "whole loop (AdvanceTo)": ("<built-in method pydrake.systems.analysis.AdvanceTo>", None),
    "refits (effect_fit.refit)": ("effect_fit.py", "refit"),
    "  of which first fits (EffectFitter.__call__)": ("effect_fit.py", "__call__"),
    "  of which rollouts (WorkbenchModel.simulate)": ("models/model.py", "simulate"),
    "fitter sample event (ContextFitter._on_sample)": ("context_fitter.py", "_on_sample"),
    "  of which refits published there (_finish)": ("context_fitter.py", "_finish", "_on_sample"),
    "  of which the handing's theta (_set_theta)": (
        "context_fitter.py",
        "_set_theta",
        "_on_sample",
    ),
    "copies of the estimator (ContextEstimator.__deepcopy__)": (
        "context_estimator.py",
        "__deepcopy__",
    ),
    "clustering per frame (ContextClustering._on_frame)": ("context_clustering.py", "_on_frame"),
    "clustering re-clusterings (_on_recluster)": ("context_clustering.py", "_on_recluster"),
    "features (ClipFeatures._calc_features; in both loops)": ("clip_features.py", "_calc_features"),
    "camera (TextureCamera._on_frame)": ("texture_camera.py", "_on_frame"),
    "all deep copies (copy.deepcopy)": ("copy.py", "deepcopy"),
}


def cumulative(stats: pstats.Stats, where: str, name: str | None, caller: str = "") -> float:
    """Cumulative seconds of the function ``name`` in a file ending with ``where`` (a built-in:
    ``where`` its name, ``name`` None); with ``caller``, only its calls from that function."""
    total = 0.0
    for (path, _line, func), (_cc, _nc, _tt, ct, callers) in stats.stats.items():
        if not ((name is None and func == where) or (func == name and path.endswith(where))):
            continue
        if not caller:
            total += ct
            continue
        total += sum(c[3] for (_p, _l, f), c in callers.items() if f == caller)
    return total


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_eval")
    parser.add_argument("--duration", type=float, default=45.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="estimator_profile_"))
    results = {}
    for estimator in ("pcvfe", "oracle"):
        prof = work / f"{estimator}.prof"
        cmd = [sys.executable, "-m", "cProfile", "-o", str(prof), "-m", "pcvfe_drake.cli"]
        cmd += ["simulate", args.scenario, "--duration", str(args.duration)]
        cmd += ["--seed", str(args.seed), "--estimator", estimator]
        cmd += ["--no-meshcat", "--no-progress", "--out", str(work / estimator)]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        stats = pstats.Stats(str(prof))
        results[estimator] = {k: cumulative(stats, *v) for k, v in PARTS.items()}
    print(f"cumulative seconds under cProfile ({args.scenario}, {args.duration:g} s, {work})")
    print(f"{'part':58s} {'PC-VFE':>8s} {'oracle':>8s}")
    for k in PARTS:
        print(f"{k:58s} {results['pcvfe'][k]:8.2f} {results['oracle'][k]:8.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
