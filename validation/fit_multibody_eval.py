"""Friction estimates on the multi-body truth (``paper_eval``): the effect model against the ST fit.

For each friction mapping of the multi-body truth (``lateral_peak``: the public simulator's, only
the lateral peak is mu; ``peak_and_stiffness``: the project's default, mu scales the whole tyre)
and each seed, one lap of ``paper_eval`` (sensing on, friction-limited speeds, the run ends at
the first catastrophic failure) is simulated with these friction sources:

* ``st``: PC-VFE with today's single-track fitter (``fitter.effects`` empty);
* ``effects``: PC-VFE with the effect model the workbench found for that mapping
  (``fitter.effects``, ``EFFECTS`` below or ``--effects``), the controller gets the estimate;
* ``effects_lb``: the same with ``fitter.handing.unidentified: !LowerBound`` (a context whose mu is
  not identifiable hands the controller its used-friction lower bound);
* ``oracle``: the true mu under the car (the reference for speed).

Per run: whether the lap completed (``laps_fraction``), mean speed, failures, and per context
(``summary.json``'s ``mu_estimates``): true mu, the final estimate and its std, the largest and
mean |mu_hat - mu| from the context's first 20 s on (``mu_hat`` as the controller got it),
whether the final 95 % interval covers the truth, the used-friction lower bound and the
near-limit / identifiable flags. Aggregates per (mapping, source): the fraction of (context,
seed) pairs within 0.05 after 20 s (contexts that reached 20 s), of runs within 0.05 on every
scored context, and the 95 % interval coverage; mean speed relative to the oracle of the same
seed.

Usage: python validation/fit_multibody_eval.py [--quick] [--seeds 1] [--sources st,effects,oracle]
       [--mappings lateral_peak,peak_and_stiffness] [--effects MAPPING=E1,E2 ...]
Runs take minutes each (multi-body truth). Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

from pcvfe_drake.progress import progress_bar

EFFECTS = {
    "lateral_peak": ["peak_tyre:k_s=0"],
    "peak_and_stiffness": ["peak_tyre:k_s=1"],
}
"""The effect model per mapping (``fitter.effects``): what ``pcvfe diagnose`` found on
multi-body logs of that mapping (docs/workbench.md); ``--effects`` replaces it."""
TOLERANCE = 0.05
SOURCES = ("st", "effects", "effects_lb", "oracle")


def run_one(mapping: str, source: str, seed: int, effects: list[str], laps: float) -> dict:
    from pcvfe_drake.diagrams.run_simulation import simulate_summary
    from pcvfe_drake.diagrams.scenario_io import load_scenario
    from pcvfe_drake.handing.config import Estimate, LowerBound
    from pcvfe_drake.models.effect_model import EffectModel, parse_effects

    scenario = load_scenario("paper_eval")
    fitter = scenario.fitter
    estimator = "pcvfe_paper"  # the single-track fitter
    if source in ("effects", "effects_lb"):
        estimator = "pcvfe"
        fitter = dataclasses.replace(
            fitter,
            model=EffectModel(effects=parse_effects(effects)),
            handing=dataclasses.replace(
                fitter.handing,
                unidentified=LowerBound() if source == "effects_lb" else Estimate(),
            ),
        )
    elif source == "oracle":
        estimator = "oracle"
    scenario = dataclasses.replace(
        scenario, friction_mapping=mapping, fitter=fitter, estimator=estimator, laps=laps
    )
    c0, w0 = time.process_time(), time.perf_counter()
    s = simulate_summary(scenario, seed)
    contexts = [
        {
            k: e.get(k)
            for k in (
                "id",
                "majority_terrain",
                "true_mu",
                "mu_hat",
                "std",
                "abs_error_after_settle_max",
                "abs_error_after_settle_mean",
                "scored_time_s",
                "covered_95",
                "mu_lower_bound",
                "near_limit",
                "identifiable",
                "fit_status",
                "time_in_context_s",
            )
        }
        for e in s.get("mu_estimates", [])
    ]
    return {
        "mapping": mapping,
        "source": source,
        "seed": seed,
        "effects": effects if source.startswith("effects") else [],
        "laps_fraction": s.get("laps_fraction"),
        "lap_time_s": s.get("lap_time_s"),
        "mean_speed_mps": s.get("mean_speed_mps"),
        "catastrophic_failures": s.get("catastrophic_failures"),
        "failure_events": s.get("failure_events"),
        "sim_time_s": s.get("sim_time_s"),
        "cpu_s": time.process_time() - c0,
        "wall_s": time.perf_counter() - w0,
        "contexts": contexts,
    }


def aggregate(runs: list[dict]) -> dict:
    out: dict = {}
    oracle_speed = {
        (r["mapping"], r["seed"]): r["mean_speed_mps"] for r in runs if r["source"] == "oracle"
    }
    for key in sorted({(r["mapping"], r["source"]) for r in runs}):
        rs = [r for r in runs if (r["mapping"], r["source"]) == key]
        pairs = [
            c
            for r in rs
            for c in r["contexts"]
            if c["true_mu"] is not None and c["abs_error_after_settle_max"] is not None
        ]
        covered = [
            c["covered_95"] for r in rs for c in r["contexts"] if c["covered_95"] is not None
        ]
        within_runs = [
            all(
                c["abs_error_after_settle_max"] <= TOLERANCE
                for c in r["contexts"]
                if c["abs_error_after_settle_max"] is not None
            )
            and any(c["abs_error_after_settle_max"] is not None for c in r["contexts"])
            for r in rs
        ]
        speed_ratio = [
            r["mean_speed_mps"] / oracle_speed[(r["mapping"], r["seed"])]
            for r in rs
            if oracle_speed.get((r["mapping"], r["seed"])) and r["mean_speed_mps"]
        ]
        out[f"{key[0]}/{key[1]}"] = {
            "runs": len(rs),
            "laps_completed": sum(1 for r in rs if (r["laps_fraction"] or 0) >= 0.999),
            "mean_laps_fraction": sum(r["laps_fraction"] or 0 for r in rs) / len(rs),
            "context_seed_pairs_scored": len(pairs),
            "pairs_within_tolerance": sum(
                1 for c in pairs if c["abs_error_after_settle_max"] <= TOLERANCE
            ),
            "runs_within_tolerance_on_every_context": sum(within_runs),
            "max_abs_error_after_20s": max(
                (c["abs_error_after_settle_max"] for c in pairs), default=None
            ),
            "coverage_95": (sum(covered) / len(covered)) if covered else None,
            "coverage_pairs": len(covered),
            "speed_vs_oracle_mean": (sum(speed_ratio) / len(speed_ratio)) if speed_ratio else None,
        }
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1, help="seeds 0..N-1")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--sources", default=",".join(SOURCES))
    parser.add_argument("--mappings", default="lateral_peak,peak_and_stiffness")
    parser.add_argument("--laps", type=float, default=1.0)
    parser.add_argument(
        "--effects",
        action="append",
        default=[],
        metavar="MAPPING=E1,E2",
        help="the effect model for a mapping (replaces EFFECTS[MAPPING])",
    )
    parser.add_argument("--out", default=None, help="also write the JSON here")
    parser.add_argument(
        "--quick", action="store_true", help="a quarter lap per run, seed 0 (run_all --quick)"
    )
    args = parser.parse_args()
    if args.quick:
        args.laps, args.seeds = min(args.laps, 0.25), 1
    effects = {k: list(v) for k, v in EFFECTS.items()}
    for item in args.effects:
        mapping, _, names = item.partition("=")
        effects[mapping.strip()] = [n.strip() for n in names.split(";") if n.strip()]
    sources = [s.strip() for s in args.sources.split(",") if s.strip()]
    bad = [s for s in sources if s not in SOURCES]
    if bad:
        raise SystemExit(f"--sources: unknown {bad}; choose from {SOURCES}")
    mappings = [m.strip() for m in args.mappings.split(",") if m.strip()]
    jobs = [
        (m, s, seed)
        for seed in range(args.first_seed, args.first_seed + args.seeds)
        for m in mappings
        for s in sources
    ]
    runs = []
    bar = progress_bar(jobs, desc="paper_eval runs")
    for mapping, source, seed in bar:
        r = run_one(mapping, source, seed, effects.get(mapping, []), args.laps)
        runs.append(r)
        ctx = ", ".join(
            f"{c['majority_terrain']} "
            f"{'no fit' if c['mu_hat'] is None else format(c['mu_hat'], '.3f')}/{c['true_mu']} "
            f"(20 s+: {c['abs_error_after_settle_max']})"
            for c in r["contexts"]
            if c["true_mu"] is not None
        )
        bar.write(
            f"{mapping} {source} seed {seed}: laps {r['laps_fraction']:.2f}, "
            f"{r['mean_speed_mps']:.2f} m/s, failures {r['catastrophic_failures']}, "
            f"cpu {r['cpu_s']:.0f} s; {ctx}"
        )
        if args.out:
            with open(args.out, "w") as f:
                json.dump({"runs": runs, "aggregate": aggregate(runs)}, f, indent=1)
    result = {
        "benchmark": "fit_multibody_eval",
        "scenario": "paper_eval",
        "seeds": list(range(args.first_seed, args.first_seed + args.seeds)),
        "effects": {m: effects.get(m, []) for m in mappings},
        "tolerance": TOLERANCE,
        "aggregate": aggregate(runs),
        "runs": runs,
    }
    effect_runs = [r for r in runs if r["source"] == "effects"]
    result["target"] = (
        "PC-VFE with the effect model drives every run to its end (a lap, or --laps) without "
        "a catastrophic failure (the single-track rows are the comparison)"
    )
    result["passed"] = bool(effect_runs) and all(
        (r["laps_fraction"] or 0) >= 0.999 * min(args.laps, 1.0) and not r["catastrophic_failures"]
        for r in effect_runs
    )
    print(json.dumps(result, default=lambda v: None))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
