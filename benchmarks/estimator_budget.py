"""The estimator's on-board budget: the PC-VFE loop against the oracle loop on the same lap.

In one run it drives the scenario's lap (or ``--duration`` seconds) twice, each in its own
``pcvfe simulate`` process (no Meshcat): once with the scenario's PC-VFE estimator (camera,
features, clustering, context fitter, NMPC) and once with the oracle friction (the same plant,
camera and NMPC, no estimator). Each loop's CPU time is the process CPU time spent in the
simulator's ``AdvanceTo`` (``summary.json``'s ``cpu_time_s``: set-up, figures and files left
out; CPU time, not wall time, because the machine is shared). The two processes run at the
same time (``--sequential``: one after the other), so that whatever slows the machine's CPU
while they run (other work, a virtual machine's host) slows both alike and their ratio holds.
It drives ``--repeats`` such pairs (default 3) and reports the pair whose ratio is the median,
with every pair's CPU times. It prints:

* the CPU time of each loop, its ratio, and each loop's speed by CPU (driving s per CPU s);
* the estimator's CPU seconds per driving second: (PC-VFE loop - oracle loop) / driving time
  of the PC-VFE lap;
* the time from a sample to the published estimate whose fit first used it (per context, p50
  and p99, from the fitter's ``sample_to_estimate_s``; the worst context's p99), and the same
  over the samples a refit published after the context's first fit (``sample_to_refit_s``:
  the refits' cadence, without the wait for a first fit's data; reported beside the target,
  which is judged on every sample);
* the final mu_hat per context (for comparison with a run before a change);
* with ``--lcm``: the LCM rehearsal (``benchmarks/hardware_rehearsal.py``: the simulated car
  behind ``pcvfe vehicle-bridge`` on a 127.0.0.1 tcpq hub, ``pcvfe simulate --hardware``)
  with a competing CPU load (``--load-procs`` busy processes) running, and its p99
  state-to-actuation latency, state timeouts and NMPC fallbacks, then the same rehearsal with
  one fixed friction (no estimator) under the same load (a timeout the loop without the
  estimator has too is not the estimator's); ``--priority N`` runs the bridge's and the
  station's loops at the real-time priority N (``hardware.control_priority``). The rehearsal
  drives ``--lcm-scenario`` (default ``paper_eval``): the bridge stands in for the car's own
  hardware and must keep real time (its pace is reported: ``bridge_pace``, simulated s per
  wall s).

Usage: python benchmarks/estimator_budget.py [--scenario paper_eval] [--duration S]
           [--seed 0] [--lcm] [--lcm-duration S] [--lcm-scenario paper_eval] [--load-procs 1]
           [--priority N] [--quick] [--lcm-only] [--repeats 3] [--sequential]
Last stdout line: one JSON object with the ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

TARGETS = {
    "loop_cpu_ratio_max": 1.3,
    "estimator_cpu_s_per_driving_s_max": 0.1,
    "realtime_by_cpu_min": 4.0,
    "sample_to_estimate_p99_s_max": 1.0,
    "lcm_actuation_latency_p99_ms_max": 50.0,
}
"""The issue's targets (the ratios are judged against them in the JSON)."""


def pcvfe(*args: str) -> list[str]:
    return [sys.executable, "-m", "pcvfe_drake.cli", *args]


def start_drive(args, estimator: str, out: Path) -> subprocess.Popen:
    """One loop in its own process, started (:func:`finish_drive` waits for it)."""
    length = ["--duration", str(args.duration)] if args.duration else []
    cmd = pcvfe(
        "simulate",
        args.scenario,
        *length,
        "--seed",
        str(args.seed),
        "--estimator",
        estimator,
        "--no-meshcat",
        "--no-progress",
        "--out",
        str(out),
    )
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL)


def finish_drive(process: subprocess.Popen, out: Path) -> dict:
    """Wait for a loop's process; its summary."""
    if process.wait() != 0:
        raise SystemExit(f"estimator_budget: {' '.join(process.args)} exited {process.returncode}")
    return json.loads((out / "summary.json").read_text())


def loop_report(summary: dict) -> dict:
    driving = float(summary["sim_time_s"])
    cpu = float(summary["cpu_time_s"])
    return {
        "driving_s": driving,
        "cpu_s": cpu,
        "realtime_by_cpu": driving / max(cpu, 1e-9),
        "lap_time_s": summary.get("lap_time_s"),
        "mean_speed_mps": summary.get("mean_speed_mps"),
        "catastrophic_failures": summary.get("catastrophic_failures"),
        "load_average": os.getloadavg()[0],
        "wall_time_s": summary.get("wall_time_s"),
    }


def delays(summary: dict) -> dict:
    """Per context the sample-to-estimate waits, and the worst p99 / sample-weighted p50."""
    per = []
    for e in summary.get("mu_estimates") or []:
        d = e.get("sample_to_estimate_s")
        if d:
            per.append({"id": e["id"], **d, "after_first_fit": e.get("sample_to_refit_s")})
    if not per:
        return {"contexts": [], "p50_s": None, "p99_s": None, "p99_after_first_fit_s": None}
    total = sum(d["samples"] for d in per)
    later = [d["after_first_fit"]["p99"] for d in per if d["after_first_fit"]]
    return {
        "contexts": per,
        "p50_s": sum(d["p50"] * d["samples"] for d in per) / max(total, 1),
        "p99_s": max(d["p99"] for d in per),
        "p99_after_first_fit_s": max(later) if later else None,
    }


def lcm_rehearsal(args, work: Path) -> dict:
    """The LCM rehearsal with ``--load-procs`` busy processes competing for the CPU."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import hardware_rehearsal  # noqa: PLC0415 (a sibling script)

    from pcvfe_drake.diagrams.scenario_io import load_scenario
    from pcvfe_drake.diagrams.world_io import scenario_world

    scenario = load_scenario(args.lcm_scenario)
    terrain_mu = {t.name: t.mu for t in scenario_world(scenario).terrain_map.terrains}
    rehearsal_args = argparse.Namespace(
        scenario=args.lcm_scenario,
        duration=args.lcm_duration,
        laps=None,
        rate=1.0,
        priority=args.priority,
    )
    load = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.load_procs)
    ]
    runs = {}
    try:
        # The scenario's estimator, then one fixed friction (the loop without an estimator; the
        # oracle needs the simulated truth, which a station on LCM has not) under the same
        # load: a state timeout or a fallback the loop without the estimator has too is not
        # the estimator's.
        for name, estimator in (("estimator", None), ("fixed", "fixed")):
            runs[name] = hardware_rehearsal.rehearsal(
                rehearsal_args, scenario, terrain_mu, work / name, None, estimator=estimator
            )
    finally:
        for p in load:
            p.kill()
            p.wait()
    r, fixed = runs["estimator"], runs["fixed"]
    return {
        "scenario": args.lcm_scenario,
        "estimator": scenario.estimator,
        "duration_s": args.lcm_duration,
        "load_procs": args.load_procs,
        "priority": args.priority,
        "fixed": {
            "latency_ms": fixed["latency_ms"],
            "state_timeouts": fixed["state_timeouts"],
            "nmpc_fallbacks": fixed["nmpc_fallbacks"],
            "states_rejected": fixed["states_rejected"],
            "max_lag_s": fixed.get("max_lag_s"),
            "bridge_pace": fixed.get("bridge_pace"),
        },
        "latency_ms": r["latency_ms"],
        "state_timeouts": r["state_timeouts"],
        "nmpc_fallbacks": r["nmpc_fallbacks"],
        "states_rejected": r["states_rejected"],
        "contexts_fitted": r["contexts_fitted"],
        "refits_after_first": r["refits_after_first"],
        "checks_with_fresh_state_share": r["checks_with_fresh_state_share"],
        "load_average_start": r["load_average_start"],
        "load_average_end": r["load_average_end"],
        "bridge_started_s": r.get("bridge_started_s"),
        "bridge_pace": r.get("bridge_pace"),
        "station_realtime_factor": r.get("realtime_factor"),
        "max_lag_s": r.get("max_lag_s"),
        "bridge_stopped_because": r.get("bridge_stopped_because"),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_eval")
    parser.add_argument("--duration", type=float, default=None, help="default: the scenario's")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="20 s of driving (run_all --quick)")
    parser.add_argument(
        "--repeats",
        type=int,
        default=3,
        help="pairs of loops to drive; the pair with the median ratio (the lower middle one "
        "for an even count) is reported (default 3)",
    )
    parser.add_argument(
        "--sequential",
        action="store_true",
        help="drive the two loops one after the other (default: at the same time)",
    )
    parser.add_argument("--lcm", action="store_true", help="also the LCM rehearsal under load")
    parser.add_argument("--lcm-duration", type=float, default=30.0)
    parser.add_argument(
        "--lcm-scenario",
        default="paper_eval",
        help="the rehearsal's scenario (its car must keep real time in the bridge: a bridge "
        "that falls behind measures the stand-in car, not the station; see bridge_pace)",
    )
    parser.add_argument("--load-procs", type=int, default=1)
    parser.add_argument(
        "--priority",
        type=int,
        default=0,
        help="with --lcm: SCHED_FIFO priority of the bridge's and the station's loops (1-99; "
        "0: off; hardware.control_priority)",
    )
    parser.add_argument(
        "--lcm-only", action="store_true", help="with --lcm: only the LCM rehearsal, no loops"
    )
    parser.add_argument("--out", default=None, help="keep the runs here (default: a temp folder)")
    args = parser.parse_args()
    if args.quick:
        args.duration = 20.0
        args.repeats = 1
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    work = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="estimator_budget_"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"load average {os.getloadavg()[0]:.1f}; runs in {work}", flush=True)
    result = {"benchmark": "estimator_budget", "scenario": args.scenario, "seed": args.seed}
    meets = {}
    if not args.lcm_only:
        loops_result, meets = loops_budget(args, work)
        result.update(loops_result)
    result["targets"] = TARGETS
    if args.lcm or args.lcm_only:
        print(
            f"LCM rehearsal, {args.lcm_duration:g} s, {args.load_procs} busy process(es), "
            f"priority {args.priority} ..."
        )
        lcm = lcm_rehearsal(args, work / "lcm")
        result["lcm"] = lcm
        lat = lcm["latency_ms"]
        print(
            f"  state -> actuation p99 {lat['p99_ms']} ms (median {lat['median_ms']} ms, max "
            f"{lat.get('max_ms')} ms), state timeouts {lcm['state_timeouts']}, NMPC fallbacks "
            f"{lcm['nmpc_fallbacks']}, refits beside the loop {lcm['refits_after_first']} "
            f"({lcm['contexts_fitted']} contexts fitted), load average "
            f"{lcm['load_average_start']:.1f} -> {lcm['load_average_end']:.1f}"
        )
        fixed = lcm["fixed"]
        print(
            f"  a fixed friction (no estimator) over LCM, same load: p99 "
            f"{fixed['latency_ms']['p99_ms']} ms, state timeouts {fixed['state_timeouts']}, "
            f"NMPC fallbacks {fixed['nmpc_fallbacks']}"
        )
        p99 = lat.get("p99_ms")
        meets["lcm_actuation_latency_p99"] = (
            p99 is not None and p99 < TARGETS["lcm_actuation_latency_p99_ms_max"]
        )
        meets["lcm_no_timeout_beyond_the_fixed_mu"] = (
            lcm["state_timeouts"] <= fixed["state_timeouts"]
        )
    result["meets"] = meets
    print(json.dumps(result))
    return 0


def drive_pair(args, work: Path) -> dict:
    """One PC-VFE and one oracle loop (at the same time unless ``--sequential``): the two
    summaries."""
    names = ("pcvfe", "oracle")
    if args.sequential:
        summaries = {}
        for name in names:
            print(f"  {name} loop ...", flush=True)
            summaries[name] = finish_drive(start_drive(args, name, work / name), work / name)
        return summaries
    print("  the pcvfe and the oracle loop, at the same time ...", flush=True)
    running = {name: start_drive(args, name, work / name) for name in names}
    return {name: finish_drive(p, work / name) for name, p in running.items()}


def estimator_share(pc: dict, orc: dict) -> float:
    """The estimator's CPU seconds per driving second: the PC-VFE loop less the oracle loop
    scaled to the PC-VFE lap's driving time."""
    return (pc["cpu_s"] - orc["cpu_s"] * pc["driving_s"] / orc["driving_s"]) / pc["driving_s"]


def loops_budget(args, work: Path) -> tuple[dict, dict]:
    """``--repeats`` pairs of the PC-VFE and the oracle loop, each loop in its own process:
    the report's entries (the median pair's) and whether each meets its target."""
    pairs = []
    for k in range(args.repeats):
        print(f"pair {k + 1} of {args.repeats}:", flush=True)
        folder = work if args.repeats == 1 else work / f"pair_{k}"
        summaries = drive_pair(args, folder)
        pair = {name: loop_report(summary) for name, summary in summaries.items()}
        pair["_summaries"] = summaries
        pairs.append(pair)
        pc, orc = pair["pcvfe"], pair["oracle"]
        print(
            f"  pcvfe CPU {pc['cpu_s']:.1f} s, oracle CPU {orc['cpu_s']:.1f} s: ratio "
            f"{pc['cpu_s'] / orc['cpu_s']:.2f}, estimator {estimator_share(pc, orc):.3f} "
            "CPU-s per driving s",
            flush=True,
        )
    # The loops are deterministic: every pair drives the same laps; the pair with the median
    # ratio is reported (the ratios of one pair share the machine's state while they ran).
    ratios = [p["pcvfe"]["cpu_s"] / p["oracle"]["cpu_s"] for p in pairs]
    median = pairs[sorted(range(len(pairs)), key=ratios.__getitem__)[(len(pairs) - 1) // 2]]
    summaries = median.pop("_summaries")
    loops = {name: median[name] for name in ("pcvfe", "oracle")}
    for name, r in loops.items():
        r["cpu_s_each_pair"] = [p[name]["cpu_s"] for p in pairs]
        print(
            f"  {name}: CPU {r['cpu_s']:.1f} s for {r['driving_s']:.1f} s of driving "
            f"({r['realtime_by_cpu']:.2f}x real time by CPU), lap {r['lap_time_s']}",
            flush=True,
        )
    pc, orc = loops["pcvfe"], loops["oracle"]
    estimator = estimator_share(pc, orc)
    wait = delays(summaries["pcvfe"])
    mu = {
        int(e["id"]): e["mu_hat"] for e in summaries["pcvfe"].get("mu_estimates") or []
    }  # fmt: skip
    print(
        f"loop CPU ratio PC-VFE / oracle (the median pair): {pc['cpu_s'] / orc['cpu_s']:.2f} "
        f"(pairs: {', '.join(f'{r:.2f}' for r in ratios)})"
    )
    print(f"estimator: {estimator:.3f} CPU-s per driving s (oracle loop scaled to the same time)")
    for d in wait["contexts"]:
        later = d["after_first_fit"]
        print(
            f"  context {d['id']}: sample -> estimate p50 {d['p50']:.2f} s, p99 {d['p99']:.2f} s "
            f"({d['samples']} samples)"
            + (
                f"; after its first fit p50 {later['p50']:.2f} s, p99 {later['p99']:.2f} s "
                f"({later['samples']} samples)"
                if later
                else ""
            )
        )
    print(f"final mu_hat per context: {mu}")
    result = {
        "loops": loops,
        "loop_cpu_ratio": pc["cpu_s"] / orc["cpu_s"],
        "loop_cpu_ratio_each_pair": ratios,
        "estimator_cpu_s_per_driving_s": estimator,
        "realtime_by_cpu": pc["realtime_by_cpu"],
        "sample_to_estimate_s": wait,
        "final_mu_hat": mu,
    }
    meets = {
        "loop_cpu_ratio": result["loop_cpu_ratio"] <= TARGETS["loop_cpu_ratio_max"],
        "estimator_cpu": estimator <= TARGETS["estimator_cpu_s_per_driving_s_max"],
        "realtime_by_cpu": pc["realtime_by_cpu"] >= TARGETS["realtime_by_cpu_min"],
        "sample_to_estimate_p99": wait["p99_s"] is not None
        and wait["p99_s"] <= TARGETS["sample_to_estimate_p99_s_max"],
    }
    return result, meets


if __name__ == "__main__":
    raise SystemExit(main())
