"""The workbench's planted-effect proof over several seeds (robustness of the test criteria).

For each seed: a clean log and one log per named effect (drag, rolling_resistance,
steering_lag, input_delay, tire_saturation) from ``pcvfe_drake.workbench.synth`` (90 s at
20 Hz, GNSS/INS noise), each diagnosed with every library effect ranked and the planted effect
added. A planted case passes when the effect ranks first, is significant, removes >= 50 % of
the held-out model error and >= 50 % of the raw multi-step RMS error, and its parameter is
within 15 % of the planted value; a clean log passes when nothing is significant.

Usage: python benchmarks/workbench_proof_sweep.py [--quick] [--seeds 0 1 2 ...]
(--quick: seeds 0 and 1; default: seeds 0-5). Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import time

from pcvfe_drake.workbench import synth
from pcvfe_drake.workbench.data import prepare
from pcvfe_drake.workbench.report import diagnose

NAMED = ["drag", "rolling_resistance", "steering_lag", "input_delay", "tire_saturation"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="seeds 0 and 1")
    parser.add_argument("--seeds", type=int, nargs="*", default=None)
    args = parser.parse_args()
    seeds = args.seeds if args.seeds else ([0, 1] if args.quick else list(range(6)))
    cases = []
    t0 = time.perf_counter()
    for seed in seeds:
        truths = [synth.Truth()] + [synth.PLANTED[n][0] for n in NAMED]
        logs = synth.simulate_truths(truths, duration_s=90.0, rate_hz=20.0, seed=seed, substeps=2)
        for name, df in zip(["clean", *NAMED], logs, strict=True):
            report, _ = diagnose(prepare(df, name), add=None if name == "clean" else [name])
            if name == "clean":
                sig = [r["name"] for r in report["ranked_effects"] if r["significant"]]
                case = {"seed": seed, "log": name, "significant": sig, "passed": not sig}
            else:
                top = report["ranked_effects"][0]
                _, pname, planted = synth.PLANTED[name]
                value = report["added"]["params"][f"{name}.{pname}"]["value"]
                raw = 1.0 - (
                    report["added"]["heldout_multistep_error"]
                    / report["baseline"]["heldout_multistep_error"]
                )
                rel = abs(value - planted) / abs(planted)
                case = {
                    "seed": seed,
                    "log": name,
                    "ranked_first": top["name"],
                    "significant": bool(top["significant"]),
                    "p_value": top["p_value"],
                    "model_error_drop": report["error_drop"],
                    "raw_error_drop": raw,
                    "param": pname,
                    "fitted": value,
                    "planted": planted,
                    "param_error": rel,
                }
                case["passed"] = bool(
                    top["name"] == name
                    and top["significant"]
                    and report["error_drop"] >= 0.5
                    and raw >= 0.5
                    and rel <= 0.15
                )
            cases.append(case)
            print(json.dumps(case), flush=True)
    planted = [c for c in cases if c["log"] != "clean"]
    result = {
        "benchmark": "workbench_proof_sweep",
        "seeds": seeds,
        "planted_cases": len(planted),
        "planted_passed": sum(c["passed"] for c in planted),
        "clean_logs": len(cases) - len(planted),
        "false_discoveries": sum(not c["passed"] for c in cases if c["log"] == "clean"),
        "worst_param_error": max(c["param_error"] for c in planted),
        "min_raw_error_drop": min(c["raw_error_drop"] for c in planted),
        "min_model_error_drop": min(c["model_error_drop"] for c in planted),
        "wall_s": round(time.perf_counter() - t0, 1),
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
