"""Does a refit in the fitter's worker thread leave the loop's thread free (the GIL)?

On the LCM station (``refit_worker``) each refit runs in a worker thread beside the loop's
thread. Both are Python threads of one process: the loop runs only while the worker does not
hold the GIL. The compiled rollout releases it (numba ``nogil``); the refit's Python around it
(windows, noise scales, Gauss-Newton steps, covariance) holds it. This replays a run's fitter
samples (``fitter_samples.npz`` of ``pcvfe simulate``) into the scenario's fitter and, for each
1 Hz refit, measures:

* ``refit_s``: the refit's wall time alone;
* ``nogil_s``: the part of it inside the compiled rollout (the GIL released);
* with a loop thread ticking beside the refit (each tick ``--tick-ms`` of pure Python, then a
  1 ms sleep, as a loop that waits for its next message): the ticks' longest gap and the
  share of the loop's tick rate kept while the refit runs, against the same loop alone for
  the refit's time (whose longest gap is the machine's own scheduling), and beside two
  controls of the refit's length: a compiled spin without the GIL (what CPU contention alone
  costs the loop) and a pure-Python spin (a worker that always holds the GIL).

A nogil share near 1 and a kept share near 1 mean the refit overlaps the loop; where they are
low the worker's Python holds the loop back. Timings are wall times: on a loaded machine read
the shares, not the seconds.

Usage: python studies/estimator_profile/refit_gil.py RUN_DIR [--scenario paper_eval]
           [--tick-ms 2] [--refits 10]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import copy
import json
import threading
import time
from pathlib import Path

import numba
import numpy as np

import pcvfe_drake.models.compiled_rollout as compiled
from pcvfe_drake.diagrams.scenario_io import load_scenario
from pcvfe_drake.estimation.context_estimator import ContextEstimator
from pcvfe_drake.vehicle.params import load_vehicle


@numba.njit(nogil=True, cache=False)
def _spin(n: int) -> float:
    x = 0.0
    for i in range(n):
        x += np.sin(x + i)
    return x


def spin_nogil(seconds: float) -> None:
    """Busy CPU for ``seconds`` without the GIL (the control for CPU contention alone)."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        _spin(20000)


def busy(ms: float) -> None:
    end = time.perf_counter() + ms / 1000.0
    while time.perf_counter() < end:
        pass


def loop_ticks(stop: threading.Event, tick_ms: float) -> list[float]:
    """A loop thread: ``tick_ms`` of Python, a 1 ms sleep, again; the ticks' end times."""
    ends = []
    while not stop.is_set():
        busy(tick_ms)
        ends.append(time.perf_counter())
        time.sleep(0.001)
    return ends


def with_loop(work, tick_ms: float) -> tuple[float, list[float]]:
    """Run ``work`` in a worker thread while this thread ticks; its wall time and the ticks."""
    stop = threading.Event()
    result = {}

    def worker():
        t0 = time.perf_counter()
        work()
        result["s"] = time.perf_counter() - t0
        stop.set()

    thread = threading.Thread(target=worker)
    thread.start()
    ends = loop_ticks(stop, tick_ms)
    thread.join()
    return result["s"], ends


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--scenario", default="paper_eval")
    parser.add_argument("--tick-ms", type=float, default=2.0)
    parser.add_argument("--refits", type=int, default=10, help="the last N 1 Hz refits")
    args = parser.parse_args()
    scenario = load_scenario(args.scenario)
    params = load_vehicle(scenario.vehicle)
    data = np.load(args.run_dir / "fitter_samples.npz")
    t, S, U = data["t_s"], data["state"], data["actuation"]
    est = ContextEstimator(params, scenario.fit_config())
    inside = [0.0]
    rollout = compiled.rollout

    def timed_rollout(*a, **k):
        c0 = time.perf_counter()
        rollout(*a, **k)
        inside[0] += time.perf_counter() - c0

    compiled.rollout = timed_rollout
    rows = []
    last = t[0]
    due = list(np.arange(t[0] + 1.0, t[-1], 1.0))[-args.refits :]
    k_due = 0
    for k in range(t.size):
        est.add_sample(float(t[k]), S[k], U[k], 0)
        if k_due < len(due) and t[k] >= due[k_due] - 1e-9:
            k_due += 1
            if t[k] - last < 1.0 - 1e-9:
                continue
            last = float(t[k])
            alone = copy.deepcopy(est)
            inside[0] = 0.0
            t0 = time.perf_counter()
            alone.refit(float(t[k]))
            refit_s = time.perf_counter() - t0
            nogil_s = inside[0]
            base_stop = threading.Event()
            timer = threading.Timer(refit_s, base_stop.set)
            timer.start()
            base = loop_ticks(base_stop, args.tick_ms)
            wall, ends = with_loop(lambda tt=float(t[k]): est.refit(tt), args.tick_ms)
            gaps = np.diff(ends) if len(ends) > 1 else np.array([np.nan])
            spin_s, spin_ends = with_loop(lambda d=wall: spin_nogil(d), args.tick_ms)
            py_s, py_ends = with_loop(lambda d=wall: busy(1000.0 * d), args.tick_ms)
            base_rate = len(base) / max(refit_s, 1e-9)
            rows.append(
                {
                    "t_s": float(t[k]),
                    "refit_s": refit_s,
                    "nogil_share": nogil_s / max(refit_s, 1e-12),
                    "refit_beside_loop_s": wall,
                    "loop_ticks_kept_share": len(ends) / max(wall, 1e-9) / max(base_rate, 1e-9),
                    "kept_beside_nogil_spin": len(spin_ends)
                    / max(spin_s, 1e-9)
                    / max(base_rate, 1e-9),
                    "kept_beside_python_spin": len(py_ends)
                    / max(py_s, 1e-9)
                    / max(base_rate, 1e-9),
                    "loop_longest_gap_ms": 1000.0 * float(np.max(gaps)),
                    "loop_alone_longest_gap_ms": 1000.0 * float(np.max(np.diff(base)))
                    if len(base) > 1
                    else float("nan"),
                }
            )
            print(rows[-1], flush=True)
    summary = {
        "refits": len(rows),
        "refit_s_median": float(np.median([r["refit_s"] for r in rows])),
        "nogil_share_median": float(np.median([r["nogil_share"] for r in rows])),
        "loop_ticks_kept_share_median": float(
            np.median([r["loop_ticks_kept_share"] for r in rows])
        ),
        "kept_beside_nogil_spin_median": float(
            np.median([r["kept_beside_nogil_spin"] for r in rows])
        ),
        "kept_beside_python_spin_median": float(
            np.median([r["kept_beside_python_spin"] for r in rows])
        ),
        "loop_longest_gap_ms_max": float(max(r["loop_longest_gap_ms"] for r in rows)),
        "loop_alone_longest_gap_ms_max": float(max(r["loop_alone_longest_gap_ms"] for r in rows)),
    }
    print(json.dumps({"study": "refit_gil", "tick_ms": args.tick_ms, **summary}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
