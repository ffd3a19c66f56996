"""Hardware-in-the-loop rehearsal against the all-in-one simulation, and end-to-end latency.

Runs, in one go:

1. the all-in-one simulation of the scenario (``pcvfe simulate``, no Meshcat): the baseline;
2. ``pcvfe vehicle-bridge`` (the simulated car behind LCM, with a localhost tcpq hub) in one
   process and ``pcvfe simulate --hardware`` (the pipeline on the LCM station) in another, both
   paced at ``--rate`` times wall-clock time (1.0: real time).

It reports, for both: contexts discovered, the per-context friction estimates scored against the
truth (for the rehearsal the truth comes from the bridge's ``truth.csv``, matched to the
station's rows by position along time), lap time; and for the rehearsal the latency from each
state message to the actuation computed after it (median, p99), the station's watchdog counts
(late, out of order, timeouts) and the share of 100 Hz states it accepted. The load average is
printed: timings on a shared machine depend on it.

Keeping up: the share of the station's 100 Hz checks that got a fresh state (a message not seen
at an earlier check: what the fitter samples), the rows of the drive log without a state (the
NMPC's fallback at each), the watchdog's timeouts and rejections, messages superseded (arrived,
accepted, never the current one) and the station's largest lag behind the wall clock.

``--before-tree DIR`` also runs the rehearsal with the Python code of another source tree (a
package folder laid out as installed: ``DIR/pcvfe_drake`` with ``systems``, ``diagrams``,
``textures`` inside; see ``docs/hardware.md``), alternating with this tree ``--repeats`` times,
so a change to the station is measured before and after under the same load; ``--hold``
rehearses with each given ``hardware.playout_hold_s``.

``--priority N`` runs both loops at the real-time priority N (``vehicle-bridge --priority``,
``hardware.control_priority``); the JSON reports it, and the fits the station's estimator made
(``refits_after_first``: whether refits ran beside the loop).

Usage: python benchmarks/hardware_rehearsal.py [--duration S | --laps N] [--rate R] [--quick]
       [--no-baseline] [--before-tree DIR] [--hold S ...] [--repeats N] [--priority N]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def pcvfe(*args: str) -> list[str]:
    return [sys.executable, "-m", "pcvfe_drake.cli", *args]


def length_args(args) -> list[str]:
    return ["--laps", str(args.laps)] if args.laps else ["--duration", str(args.duration)]


def contexts_vs_truth(log: pd.DataFrame, truth: pd.DataFrame, terrain_mu: dict) -> list[dict]:
    """Per context id: rows, majority true terrain (nearest truth sample in space, searched
    within 2 s of the time-aligned truth) and its mu, and the last mu_hat."""
    xy_t = truth[["sx", "sy"]].to_numpy()
    tt = truth["t"].to_numpy()
    # The station's clock starts when it first hears the car: align by the best time offset.
    offsets = np.arange(0.0, 30.0, 0.05)
    sample = log.iloc[:: max(1, len(log) // 200)]
    errs = []
    for off in offsets:
        idx = np.clip(np.searchsorted(tt, sample["t"].to_numpy() + off), 0, len(tt) - 1)
        errs.append(np.nanmean(np.hypot(*(sample[["sx", "sy"]].to_numpy() - xy_t[idx]).T)))
    off = float(offsets[int(np.nanargmin(errs))])
    idx = np.clip(np.searchsorted(tt, log["t"].to_numpy() + off), 0, len(tt) - 1)
    terrain = truth["terrain"].fillna("").to_numpy()[idx]
    out = []
    for cid in sorted(int(c) for c in log["context"].unique() if c >= 0):
        rows = np.flatnonzero(log["context"].to_numpy() == cid)
        names, counts = np.unique(terrain[rows], return_counts=True)
        major = str(names[np.argmax(counts)])
        mu_hat = float(log["mu_hat"].to_numpy()[rows[-1]])
        mu = terrain_mu.get(major)
        out.append(
            {
                "id": cid,
                "terrain": major,
                "time_s": len(rows) * float(np.median(np.diff(log["t"]))),
                "mu_true": mu,
                "mu_hat": mu_hat,
                "abs_error": abs(mu_hat - mu) if mu is not None else None,
            }
        )
    return out, off


def rehearsal(
    args,
    scenario,
    terrain_mu,
    work: Path,
    env: dict | None,
    hold_s: float | None = None,
    estimator: str | None = None,
) -> dict:
    """One rehearsal (bridge + hardware station, two processes) in ``work``; ``env``: the
    environment of both processes (None: this one); ``hold_s``: the station's
    ``hardware.playout_hold_s`` (None: the scenario's); ``estimator``: the station's friction
    source (None: the scenario's)."""
    work.mkdir(parents=True, exist_ok=True)
    url = f"tcpq://127.0.0.1:{free_port()}"
    priority = getattr(args, "priority", 0)
    bridge_duration = (args.duration if not args.laps else scenario.max_duration_s) + 60.0
    load0 = os.getloadavg()[0]
    bridge = subprocess.Popen(
        pcvfe(
            "vehicle-bridge",
            args.scenario,
            "--lcm-url",
            url,
            "--duration",
            str(bridge_duration),
            "--idle-stop",
            "3",
            "--quiet",
            "--realtime-rate",
            str(args.rate),
            "--out",
            str(work / "bridge"),
            "--priority",
            str(priority),
        ),
        stdout=subprocess.PIPE,
        text=True,
        env=env,
        cwd=work,  # not the checkout: its folders would shadow the --before-tree code
    )
    override = work / "rate.yaml"
    hold = "" if hold_s is None else f"  playout_hold_s: {hold_s}\n"
    source = "" if estimator is None else f"estimator: {estimator}\n"
    override.write_text(
        f"{source}hardware:\n  realtime_rate: {args.rate}\n  control_priority: {priority}\n{hold}"
    )
    try:
        subprocess.run(
            pcvfe(
                "simulate",
                args.scenario,
                "--with",
                str(override),
                *length_args(args),
                "--hardware",
                "--lcm-url",
                url,
                "--no-meshcat",
                "--no-progress",
                "--out",
                str(work / "hw"),
            ),
            check=True,
            stdout=subprocess.DEVNULL,
            env=env,
            cwd=work,
        )
        out, _ = bridge.communicate(timeout=120)
    finally:
        if bridge.poll() is None:
            bridge.kill()
    bridge_report = json.loads(out.strip().splitlines()[-1])
    hw_summary = json.loads((work / "hw" / "summary.json").read_text())
    hw_log = pd.read_csv(work / "hw" / "drive_log.csv")
    truth = pd.read_csv(work / "bridge" / "truth.csv")
    # The bridge's clock ran while it held the car for the station's first command; the
    # station's starts at that command.
    truth["t"] -= bridge_report.get("started_s", 0.0)
    hw_contexts, offset = contexts_vs_truth(hw_log, truth, terrain_mu)
    streams = hw_summary["station_status"]["streams"]
    state = streams["state"]
    checks = hw_summary["sim_time_s"] / scenario.hardware.watchdog_period_s
    expected_states = hw_summary["sim_time_s"] / scenario.hardware.state_period_s
    # A check has a fresh state when it takes a message not seen before: every accepted message
    # with the newest-only subscriber, every one handed out with the queue (``released``).
    fresh = state.get("released", state["accepted"])
    rows_lost = hw_summary.get("rows_skipped_state_not_finite") or 0
    # Whether the estimator refitted beside the loop: a context's fits after its first.
    fits = [e.get("fits") or 0 for e in hw_summary.get("mu_estimates") or []]
    return {
        "priority": priority,
        "load_average_start": load0,
        "load_average_end": os.getloadavg()[0],
        "sim_time_s": hw_summary["sim_time_s"],
        "wall_s": hw_summary["wall_time_s"],
        "realtime_factor": hw_summary["realtime_factor"],
        "realtime_factor_cpu": hw_summary.get("realtime_factor_cpu"),
        "contexts": hw_summary["contexts_discovered"],
        "laps": hw_summary.get("laps_completed"),
        "lap_time_s": hw_summary.get("lap_time_s"),
        "estimates": hw_contexts,
        "truth_time_offset_s": offset,
        "latency_ms": bridge_report["latency"],
        "station_status": hw_summary["station_status"],
        "states_accepted_share": state["accepted"] / max(expected_states, 1.0),
        "checks_with_fresh_state_share": fresh / max(checks, 1.0),
        "state_timeouts": state["timeouts"],
        "camera_timeouts": streams["camera"]["timeouts"],
        "states_rejected": state["rejected"],
        "states_superseded": state.get("superseded"),
        "max_lag_s": state.get("max_lag_s"),
        "mean_lag_s": state.get("mean_lag_s"),
        "mean_hold_s": state.get("mean_hold_s"),
        "rows_lost": rows_lost,
        "rows_lost_share": rows_lost / max(rows_lost + len(hw_log), 1),
        "nmpc_fallbacks": hw_summary.get("nmpc_fallbacks"),
        "contexts_fitted": sum(f > 0 for f in fits),
        "fits": sum(fits),
        "refits_after_first": sum(max(f - 1, 0) for f in fits),
        "bridge_actuation": bridge_report["actuation"],
        "bridge_started_s": bridge_report.get("started_s"),
        # Simulated s per wall s while the car drove (the hold before the first command ran
        # on the wall clock): below 1, the car's states came later than the station expected.
        "bridge_pace": bridge_pace(bridge_report),
        "bridge_stopped_because": bridge_report.get("stopped_because"),
    }


def bridge_pace(report: dict) -> float | None:
    """The bridge's simulated seconds per wall second after the station's first command."""
    start = report.get("started_s") or 0.0
    wall = report["wall_time_s"] - start
    return (report["sim_time_s"] - start) / wall if wall > 0 else None


def brief(name: str, r: dict) -> str:
    lat = r["latency_ms"]
    return (
        f"{name}: load {r['load_average_start']:.1f}, mean lag {r['mean_lag_s']} s, fresh state at "
        f"{100 * r['checks_with_fresh_state_share']:.1f} % of checks, accepted "
        f"{100 * r['states_accepted_share']:.1f} % of states, rows without state "
        f"{100 * r['rows_lost_share']:.1f} %, timeouts state {r['state_timeouts']} camera "
        f"{r['camera_timeouts']}, rejected {r['states_rejected']}, latency median "
        f"{lat['median_ms']} ms p99 {lat['p99_ms']} ms"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_sim")
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--laps", type=float, default=None)
    parser.add_argument("--rate", type=float, default=1.0, help="pace (1.0: real time)")
    parser.add_argument("--quick", action="store_true", help="15 s of driving")
    parser.add_argument("--no-baseline", action="store_true", help="skip the all-in-one simulation")
    parser.add_argument(
        "--before-tree", default=None, help="also rehearse with the code of this package folder"
    )
    parser.add_argument("--repeats", type=int, default=1, help="rehearsals per variant")
    parser.add_argument(
        "--priority",
        type=int,
        default=0,
        help="SCHED_FIFO priority of the bridge's and the station's loops (1-99; 0: off; "
        "hardware.control_priority, vehicle-bridge --priority)",
    )
    parser.add_argument(
        "--hold",
        type=float,
        nargs="+",
        default=None,
        help="rehearse with each of these hardware.playout_hold_s [s] (default: the scenario's)",
    )
    args = parser.parse_args()
    if args.quick:
        args.duration, args.laps = 15.0, None
    from pcvfe_drake.diagrams.scenario_io import load_scenario
    from pcvfe_drake.diagrams.world_io import scenario_world

    scenario = load_scenario(args.scenario)
    terrain_mu = {t.name: t.mu for t in scenario_world(scenario).terrain_map.terrains}
    work = Path(tempfile.mkdtemp(prefix="hw_rehearsal_"))
    load0 = os.getloadavg()[0]
    print(f"load average {load0:.1f}; work folder {work}", flush=True)

    sim_summary, sim_wall = None, None
    if not args.no_baseline:
        print("all-in-one simulation ...", flush=True)
        t0 = time.perf_counter()
        subprocess.run(
            pcvfe(
                "simulate",
                args.scenario,
                *length_args(args),
                "--no-meshcat",
                "--no-progress",
                "--out",
                str(work / "sim"),
            ),
            check=True,
            stdout=subprocess.DEVNULL,
        )
        sim_wall = time.perf_counter() - t0
        sim_summary = json.loads((work / "sim" / "summary.json").read_text())

    variants: list[tuple[str, dict | None, float | None]] = []
    if args.before_tree:
        tree = str(Path(args.before_tree).resolve())
        variants.append(("before", dict(os.environ, PYTHONPATH=tree), None))
    if args.hold:
        variants += [(f"after_hold_{h:g}s", None, h) for h in args.hold]
    else:
        variants.append(("after", None, None))
    runs: dict[str, list[dict]] = {name: [] for name, _, _ in variants}
    for k in range(args.repeats):
        for name, env, hold in variants:
            print(f"rehearsal ({name}) {k + 1} at {args.rate}x real time ...", flush=True)
            r = rehearsal(args, scenario, terrain_mu, work / f"{name}{k}", env, hold)
            runs[name].append(r)
            print("  " + brief(name, r), flush=True)
    hw = runs[variants[-1][0]][0]
    sim_contexts = [
        {
            "id": e["id"],
            "terrain": e["majority_terrain"],
            "mu_true": e["true_mu"],
            "mu_hat": e["mu_hat"],
            "abs_error": e["abs_error"],
        }  # fmt: skip
        for e in (sim_summary or {}).get("mu_estimates", [])
    ]
    result = {
        "benchmark": "hardware_rehearsal",
        "scenario": args.scenario,
        "rate": args.rate,
        "priority": args.priority,
        "load_average_start": load0,
        "load_average_end": os.getloadavg()[0],
        "all_in_one": None
        if sim_summary is None
        else {
            "sim_time_s": sim_summary["sim_time_s"],
            "wall_s": sim_wall,
            "contexts": sim_summary["contexts_discovered"],
            "laps": sim_summary.get("laps_completed"),
            "lap_time_s": sim_summary.get("lap_time_s"),
            "estimates": sim_contexts,
        },
        "rehearsal": hw,
        "runs": runs,
    }
    for name in ("all_in_one", "rehearsal"):
        r = result[name]
        if r is None:
            continue
        print(f"{name}: {r['contexts']} contexts, laps {r['laps']}, lap time {r['lap_time_s']}")
        for e in r["estimates"]:
            print(f"   context {e['id']} {e['terrain']:<13} mu_true {e['mu_true']} "
                  f"mu_hat {e['mu_hat']:.3f}")  # fmt: skip
    lat = result["rehearsal"]["latency_ms"]
    print(f"latency state -> actuation: median {lat['median_ms']} ms, p99 {lat['p99_ms']} ms")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
