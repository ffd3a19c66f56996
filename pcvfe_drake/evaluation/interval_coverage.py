"""Coverage of the fitter's 95 % friction intervals, offline, on an experiment's saved runs
(``pcvfe evaluate --report DIR --interval-coverage [--calibrate]``; no pydrake).

For every run (``drive_log.parquet`` with the final clustering's labels ``final_context``,
``summary.json`` with each context's majority terrain and true mu, ``scenario.yaml``), each
context's final buffer (its newest ``fitter.buffer_s`` of logged samples) is refitted as the live
fitter refits it: with the scenario's effect model (``fitter.effects``: ``EffectFitter`` with the
scenario's windows) or the single-track fit (windows of the live horizon and stride in seconds at
the log's rate, the newest ``fitter.max_windows``), each with the ``iid`` and the ``hac``
standard deviations. A context's 95 % interval is ``mu +- 1.96 std`` where the data came near
the limit (``mu_lower_bound >= near_limit_fraction x mu``); where they did not it is the
one-sided ``[mu_lower_bound, mu's upper bound]``, because data far below the peak bound it from
below only (``two_sided`` scores ``mu +- 1.96 std`` there too). Coverage is counted over
(context, seed) pairs, per group of seeds: the calibration seeds (the ones a setting was chosen
on) and the others, held out, so that a calibrated budget is judged on seeds it never saw.

``model_error_rel`` R adds the model-error budget (``FitOptions.model_error_rel``: mu's std
becomes ``sqrt(std^2 + (R mu)^2)``) to both stds. :func:`calibrate` chooses R on the calibration
seeds' near-limit pairs: per pair the smallest R whose ``hac`` interval holds the truth, and R =
their ``target`` quantile, rounded up to 0.01 (``on="live"``: from the runs' own final estimates
and their std without the budget the run carried).

The log is at its logging rate (20 Hz in the shipped scenarios), not the fitter's 100 Hz, so the
refits are close to, not equal to, the live ones (``live`` columns: the run's own estimate).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from pcvfe_drake.estimation.effect_fit import EffectFitter, friction_used
from pcvfe_drake.estimation.fit_dataset import build_windows
from pcvfe_drake.estimation.fit_options import MU_BOUNDS, FitOptions, with_model_error
from pcvfe_drake.estimation.fitting import fit_gauss_newton
from pcvfe_drake.vehicle.params import load_vehicle
from pcvfe_drake.vehicle.single_track import STATE_NAMES

METHODS = ("iid", "hac")
Z95 = 1.959964


def parse_seeds(spec: str) -> set[int]:
    """``"0-4,7"`` -> {0, 1, 2, 3, 4, 7}; ValueError naming the bad part."""
    out: set[int] = set()
    for part in filter(None, str(spec).replace(" ", "").split(",")):
        lo, _, hi = part.partition("-")
        try:
            out.update(range(int(lo), int(hi or lo) + 1))
        except ValueError:
            raise ValueError(f"--calibration-seeds: {part!r} is not N or N-M") from None
    return out


def context_rows(log: pd.DataFrame, n_keep: int) -> dict[int, np.ndarray]:
    """Per final-clustering context: its newest ``n_keep`` rows (the live store keeps each
    label's newest ``buffer_s``)."""
    labels = log["final_context"].to_numpy(int)
    return {int(k): np.flatnonzero(labels == k)[-n_keep:] for k in np.unique(labels) if int(k) >= 0}


def _fit_context(kind, fitter, t, x, u, fc: dict, dt: float, vehicle, period_s) -> dict | None:
    """mu and its std per method for one buffer (None: too little data)."""
    out = {}
    if kind == "effects":
        for method in METHODS:
            fitter.covariance = method
            res = fitter(t, x, u, None, vehicle.theta[0])
            if res is None:
                return None
            out[method] = (float(res.theta[0]), float(res.std[0]))
        out["upper"] = float(fitter.model.bounds()[1][0])
        return out
    horizon = max(1, round(fc["horizon_steps"] * period_s / dt))
    stride = max(1, round(fc["stride_steps"] * period_s / dt))
    split = build_windows(t, x, u, horizon=horizon, stride=stride, dt=dt, max_windows=None)
    data = split.by_context.get(0)
    if data is None or data.n_windows < fc["min_windows"]:
        return None
    if data.n_windows > fc["max_windows"]:
        data = data.subset(slice(data.n_windows - fc["max_windows"], None))
    for method in METHODS:
        res = fit_gauss_newton(data, vehicle, None, FitOptions(covariance=method))
        out[method] = (float(res.theta[0]), float(res.std[0]))
    out["upper"] = MU_BOUNDS[1]
    return out


def _live_data_std(entry: dict, fc: dict) -> float | None:
    """The live fit's own std of mu: the run's reported std without the model-error budget the
    run carried; None where the run reported none."""
    std, mu = entry.get("std"), entry.get("mu_hat")
    if std is None or mu is None:
        return None
    rel = float(fc.get("model_error_rel", 0.0) or 0.0)
    return math.sqrt(max(float(std) ** 2 - (rel * float(mu)) ** 2, 0.0))


def refit_run(folder: Path) -> list[dict]:
    """One row per (context with a known truth) of a run: the refits of its final buffer."""
    folder = Path(folder)
    for name in ("summary.json", "scenario.yaml", "drive_log.parquet"):
        if not (folder / name).is_file():
            raise FileNotFoundError(f"{folder}: no {name}")
    summary = json.loads((folder / "summary.json").read_text())
    scenario = yaml.safe_load((folder / "scenario.yaml").read_text())
    fc = scenario["fitter"]
    fc = {**fc, **fc.get("model", {})}  # the effect model as run (fitter.model)
    period_s = float(scenario.get("rates", {}).get("fitter_sample_period_s", 0.01))
    vehicle = load_vehicle(scenario.get("vehicle"))
    kind = "effects" if fc.get("effects") else "st"
    fitter = None
    if kind == "effects":
        fitter = EffectFitter(
            vehicle,
            fc["effects"],
            horizon_s=fc["effect_horizon_s"],
            stride_s=fc["effect_stride_s"],
            max_windows=fc["effect_max_windows"],
            max_iterations=fc["max_iterations"],
            min_windows=fc["effect_min_windows"],
        )
    log = pd.read_parquet(folder / "drive_log.parquet")
    if "final_context" not in log.columns:
        raise ValueError(f"{folder / 'drive_log.parquet'}: no final_context column")
    dt = float(np.median(np.diff(log["t"].to_numpy(float))))
    by_id = {int(c["id"]): c for c in summary.get("mu_estimates", [])}
    rows = []
    for k, idx in context_rows(log, int(round(fc["buffer_s"] / dt))).items():
        entry = by_id.get(k)
        if entry is None or entry.get("true_mu") is None:
            continue
        t = log["t"].to_numpy(float)[idx]
        x = log[list(STATE_NAMES)].to_numpy(float)[idx]
        u = log[["steer_rate", "accel"]].to_numpy(float)[idx]
        fits = _fit_context(kind, fitter, t, x, u, fc, dt, vehicle, period_s)
        if fits is None:
            continue
        used = friction_used(t, x, lateral_only=kind == "effects")
        row = {
            "run": folder.name,
            "kind": kind,
            "seed": int(summary.get("seed", scenario.get("seed", 0))),
            "terrain": entry["majority_terrain"],
            "true_mu": float(entry["true_mu"]),
            "live_mu": entry["mu_hat"],
            "live_std": entry.get("std"),
            "live_covered": entry.get("covered_95"),
            "live_near_limit": bool(entry.get("near_limit")),
            "live_std_data": _live_data_std(entry, fc),
            "mu_lower_bound": used,
            "upper": fits["upper"],
        }
        for method in METHODS:
            mu, std = fits[method]
            near = bool(math.isfinite(used) and used >= fc["near_limit_fraction"] * mu)
            row[method] = {"mu": mu, "std_data": std, "near_limit": near}
        rows.append(row)
    return rows


def needed_rel(mu: float, std_data: float, true_mu: float) -> float:
    """The smallest model-error budget whose 95 % interval around ``mu`` holds ``true_mu``."""
    gap = (abs(mu - true_mu) / Z95) ** 2 - std_data**2
    return math.sqrt(max(gap, 0.0)) / abs(mu)


def calibrate(
    rows: list[dict], calibration_seeds: set[int], *, on: str = "effects", target: float = 0.9
) -> dict:
    """The model-error budget R that makes the ``target`` share of the calibration seeds'
    near-limit pairs covered (rounded up to 0.01); ValueError when there are none."""
    if on == "live":
        need = sorted(
            needed_rel(r["live_mu"], r["live_std_data"], r["true_mu"])
            for r in rows
            if r["seed"] in calibration_seeds
            and r["live_near_limit"]
            and r["live_std_data"] is not None
        )
    else:
        need = sorted(
            needed_rel(r["hac"]["mu"], r["hac"]["std_data"], r["true_mu"])
            for r in rows
            if r["kind"] == on and r["seed"] in calibration_seeds and r["hac"]["near_limit"]
        )
    if not need:
        raise ValueError(f"--calibrate: no near-limit {on} pairs on the calibration seeds")
    if not 0 < target <= 1:
        raise ValueError(f"--target must be in (0, 1], got {target}")
    q = need[min(len(need) - 1, math.ceil(target * len(need)) - 1)]
    rel = math.ceil(q * 100 - 1e-9) / 100
    return {"on": on, "pairs": len(need), "needed_rel": need, "target": target, "rel": rel}


def score(rows: list[dict], rel: float, calibration_seeds: set[int], two_sided: bool) -> dict:
    """Intervals of every row with the budget ``rel``, and the coverage per run kind and seed
    group (``calibration``, ``held_out``, ``all``)."""
    for row in rows:
        for method in METHODS:
            c = row[method]
            c["std"] = with_model_error(c["mu"], c["std_data"], rel)
            if c["near_limit"] or two_sided:
                s = c["std"] if math.isfinite(c["std"]) else math.inf
                lo, hi = c["mu"] - Z95 * s, c["mu"] + Z95 * s
            else:
                lo, hi = row["mu_lower_bound"], row["upper"]
            c["interval"] = [lo, hi]
            c["covered"] = bool(lo <= row["true_mu"] <= hi)
    out: dict = {}
    for kind in sorted({r["kind"] for r in rows}):
        sel = [r for r in rows if r["kind"] == kind]
        out[kind] = {}
        for group, pick in (
            ("calibration", lambda r: r["seed"] in calibration_seeds),
            ("held_out", lambda r: r["seed"] not in calibration_seeds),
            ("all", lambda r: True),
        ):
            g = [r for r in sel if pick(r)]
            out[kind][group] = {
                "pairs": len(g),
                "live_covered": sum(bool(r["live_covered"]) for r in g),
                **{
                    m: {
                        "covered": sum(r[m]["covered"] for r in g),
                        "two_sided_pairs": sum(r[m]["near_limit"] for r in g),
                        "two_sided_covered": sum(r[m]["covered"] for r in g if r[m]["near_limit"]),
                    }
                    for m in METHODS
                },
            }
    return out


def experiment_coverage(
    root: Path,
    *,
    calibration_seeds: str = "0-4",
    model_error_rel: float = 0.0,
    calibrate_on: str | None = None,
    target: float = 0.9,
    two_sided: bool = False,
    sources: list[str] | None = None,
) -> dict:
    """Refit every finished run of an experiment folder (of ``sources`` when given) and score
    its intervals; ``calibrate_on`` (``effects``, ``st`` or ``live``) first chooses the budget."""
    runs_dir = Path(root) / "runs"
    folders = sorted(p for p in runs_dir.glob("*__*__s*") if (p / "summary.json").is_file())
    if sources:
        folders = [p for p in folders if p.name.rsplit("__", 2)[1] in sources]
    if not folders:
        raise FileNotFoundError(f"{runs_dir}: no finished runs to refit")
    calib = parse_seeds(calibration_seeds)
    rows = [row for folder in folders for row in refit_run(folder)]
    result: dict = {"runs": len(folders), "calibration_seeds": sorted(calib)}
    result["two_sided"] = two_sided
    rel = model_error_rel
    if calibrate_on is not None:
        result["calibration"] = calibrate(rows, calib, on=calibrate_on, target=target)
        rel = result["calibration"]["rel"]
    result["model_error_rel"] = rel
    result["coverage"] = score(rows, rel, calib, two_sided)
    result["rows"] = rows
    return result


def markdown(result: dict) -> str:
    """The coverage table of :func:`experiment_coverage` as Markdown."""
    lines = ["# 95 % interval coverage (offline refits)", ""]
    lines.append(
        f"{result['runs']} runs; each context's final buffer refitted with the iid and the hac "
        f"(sandwich) std; model-error budget {result['model_error_rel']:.2f}; calibration seeds "
        f"{', '.join(str(s) for s in result['calibration_seeds'])}; "
        + (
            "two-sided intervals everywhere."
            if result["two_sided"]
            else "one-sided where the data never came near the limit."
        )
    )
    cal = result.get("calibration")
    if cal:
        lines.append(
            f"\nCalibrated on {cal['pairs']} near-limit {cal['on']} pairs of the calibration "
            f"seeds: the {cal['target']:g} quantile of the budget each needed, rounded up: "
            f"**{cal['rel']:.2f}**."
        )
    head = ["fit", "seeds", "pairs", "live runs", "iid", "hac", "hac two-sided"]
    lines += ["", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for kind, groups in result["coverage"].items():
        for group, v in groups.items():
            lines.append(
                "| "
                + " | ".join(
                    [
                        kind,
                        group.replace("_", " "),
                        str(v["pairs"]),
                        str(v["live_covered"]),
                        str(v["iid"]["covered"]),
                        str(v["hac"]["covered"]),
                        f"{v['hac']['two_sided_covered']} of {v['hac']['two_sided_pairs']}",
                    ]
                )
                + " |"
            )
    return "\n".join(lines) + "\n"


def write_interval_coverage(root: Path, **options) -> tuple[Path, Path, str]:
    """Write ``interval_coverage.json`` (every row) and ``interval_coverage.md``."""
    result = experiment_coverage(root, **options)
    text = markdown(result)
    json_path = Path(root) / "interval_coverage.json"
    md_path = Path(root) / "interval_coverage.md"
    json_path.write_text(json.dumps(result, indent=1, default=float) + "\n")
    md_path.write_text(text)
    return json_path, md_path, text
