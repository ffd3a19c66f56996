"""``pcvfe fit``: fit the single-track friction parameters per context of a drive log."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from pcvfe_drake.estimation.fit_dataset import (
    DEFAULT_HORIZON,
    DEFAULT_MAX_WINDOWS,
    DEFAULT_STRIDE,
    DEFAULT_V_MIN_MPS,
    DEFAULT_X0_SMOOTHING_S,
    windows_from_log,
)
from pcvfe_drake.estimation.fit_options import (
    COVARIANCES,
    JOINT_PRIOR_REL_SIGMA,
    FitOptions,
    joint_options,
)
from pcvfe_drake.estimation.fitting import fit_contexts
from pcvfe_drake.runs.drivelog import read_drive_log
from pcvfe_drake.runs.resample import check_resample_rate, resample_log
from pcvfe_drake.vehicle.params import THETA_NAMES, load_vehicle


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "fit",
        help="fit mu (and optionally C_Sf, C_Sr) per context of a drive log, with uncertainty",
        description=(
            "Fit the single-track model's friction parameters to a drive log (CSV or Parquet, "
            "the drive-log format) per context: rollouts of H steps from the measured states "
            "with the recorded inputs, windows only from stable segments in one context with "
            "v >= --min-speed (paper eq. 5a-6). By default only mu is fitted, the stiffnesses "
            "stay at the vehicle's nominal values; --joint also fits C_Sf, C_Sr with Gaussian "
            "priors. Prints a table (or one JSON object with --json)."
        ),
    )
    parser.add_argument("log", type=Path, help="drive log (.csv, .csv.gz, .parquet)")
    parser.add_argument(
        "--vehicle", default=None, help="vehicle preset or YAML file (default: ford_escort)"
    )
    parser.add_argument(
        "--context-column",
        choices=("terrain", "context"),
        default=None,
        help="column holding the context of each row (default: the whole log is one context)",
    )
    parser.add_argument(
        "--joint",
        action="store_true",
        help=f"also fit C_Sf, C_Sr, with Gaussian priors of {JOINT_PRIOR_REL_SIGMA:g} x nominal "
        "(see --prior-rel)",
    )
    parser.add_argument(
        "--prior-rel",
        type=float,
        default=JOINT_PRIOR_REL_SIGMA,
        help="with --joint: prior std of the stiffnesses relative to nominal; 0 = no priors "
        "(ill-posed: mu and C_S enter the ST model only as products)",
    )
    parser.add_argument("--horizon", type=int, default=DEFAULT_HORIZON, help="window length H")
    parser.add_argument("--stride", type=int, default=DEFAULT_STRIDE, help="window start stride")
    parser.add_argument(
        "--min-speed", type=float, default=DEFAULT_V_MIN_MPS, help="speed filter [m/s] (eq. 6)"
    )
    parser.add_argument(
        "--x0-smoothing-s",
        type=float,
        default=DEFAULT_X0_SMOOTHING_S,
        help="half-width [s] of the initial-state smoothing (0 = raw measurement, eq. 5b)",
    )
    parser.add_argument(
        "--max-windows",
        type=int,
        default=DEFAULT_MAX_WINDOWS,
        help="most windows fitted per context, evenly spaced over the log (bounds memory and "
        f"time on long logs; default {DEFAULT_MAX_WINDOWS}; 0 = all; docs/fitting.md)",
    )
    parser.add_argument(
        "--solver",
        choices=("gauss_newton", "adam"),
        default="gauss_newton",
        help="bounded Gauss-Newton (default) or the paper's Adam (lr 0.01, batch 1024)",
    )
    parser.add_argument(
        "--lenient",
        action="store_true",
        help="read the log without validation: rows with NaN or time gaps are skipped by the "
        "window filter (and counted) instead of rejecting the file",
    )
    parser.add_argument(
        "--resample",
        type=float,
        default=None,
        metavar="HZ",
        help="resample the log to HZ first (for jittered or uneven time stamps): states "
        "interpolated linearly, inputs averaged over each new step, labels from the nearest "
        "row (docs/drive_log.md)",
    )
    parser.add_argument(
        "--effects",
        action="append",
        default=[],
        metavar="EFFECT[:PARAM=VALUE,...]",
        help="fit the workbench model with this effect (repeatable; PARAM=VALUE fixes a "
        "parameter, e.g. steering_lag:tau=0.15): the log is fitted as `pcvfe diagnose --add` "
        "fits it (one model, mu per context, effect parameters shared, the diagnosis's "
        "training windows), so both give the same parameters (docs/fitting.md)",
    )
    parser.add_argument(
        "--covariance",
        choices=COVARIANCES,
        default="hac",
        help="standard deviations: hac (default: the sandwich with a Newey-West estimate over "
        "the time-ordered windows, honest under model error and correlated residuals) or iid "
        "(independent residuals; optimistic under model error) (docs/fitting.md)",
    )
    parser.add_argument(
        "--model-error-rel",
        type=float,
        default=0.0,
        metavar="REL",
        help="model-error budget: mu's std becomes sqrt(std^2 + (REL mu)^2) (default 0: none; "
        "for a model error every window shares, calibrated against ground truth: "
        "docs/fitting.md)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(func=run)


def run_effects(args: argparse.Namespace) -> int:
    """``--effects``: the effect model on the whole log (``fit_effects.fit_log``)."""
    from pcvfe_drake.commands.fit_effects import fit_log
    from pcvfe_drake.estimation.effect_fit import parse_effects
    from pcvfe_drake.models.data import load

    specs = parse_effects(args.effects)  # unknown effects fail before reading the log
    data = load(args.log, context_column=args.context_column, resample_hz=args.resample)
    out = fit_log(
        data,
        load_vehicle(args.vehicle),
        specs,
        covariance=args.covariance,
        model_error_rel=args.model_error_rel,
    )
    out = {"log": str(args.log), "contexts_column": args.context_column, **out}
    if args.json:
        print(json.dumps(out, default=lambda v: None))
        return 0
    names = ", ".join(
        s.name
        + ("" if not s.fixed else f" ({', '.join(f'{k}={v:g}' for k, v in s.fixed.items())})")
        for s in specs
    )
    print(
        f"{args.log}: effect model {names}; mu is the "
        + ("friction peak" if out["mu_is_peak"] else "single-track model's mu (a stiffness scale)")
        + f"; {out['training_windows']} training windows (as pcvfe diagnose)"
    )
    print(
        f"{'context':>12} {'mu':>8} {'+-std':>8} {'95 % interval':>16} {'C_Sf':>8} {'C_Sr':>8} "
        f"{'mu >=':>7}  limit"
    )
    for label, c in out["contexts"].items():
        th = c["theta"]
        lo, hi = (math.inf if v is None else v for v in c["mu_interval_95"])
        print(
            f"{label:>12} {_fmt(th['mu'], 4):>8} {_fmt(c['mu_std'], 2):>8} "
            f"{'[' + _fmt(lo, 3) + ', ' + (_fmt(hi, 3) if math.isfinite(hi) else 'inf') + ']':>16} "
            f"{_fmt(th['C_Sf'], 4):>8} {_fmt(th['C_Sr'], 4):>8} {_fmt(c['mu_lower_bound'], 3):>7}  "
            + ("near" if c["near_limit"] else "never near: mu barely observable")
        )
    for name, p in out["params"].items():
        if "." in name:
            print(f"  {name} = {_fmt(p['value'], 5)} +- {_fmt(p['std'], 2)} {p['unit']}")
    return 0


def _fmt(value: float, digits: int = 4) -> str:
    return f"{value:.{digits}g}" if math.isfinite(value) else "-"


def run(args: argparse.Namespace) -> int:
    if args.resample is not None:
        check_resample_rate(args.resample)  # bounded before any work
    if args.effects:
        return run_effects(args)
    params = load_vehicle(args.vehicle)
    if args.prior_rel < 0 or not math.isfinite(args.prior_rel):
        raise ValueError(f"--prior-rel must be >= 0, got {args.prior_rel}")
    if args.max_windows < 0 or args.max_windows == 1:
        raise ValueError(f"--max-windows must be 0 (all) or >= 2, got {args.max_windows}")
    log = read_drive_log(args.log, validate=not args.lenient, max_gap_s=math.inf)
    if args.resample is not None:
        log = resample_log(log, args.resample, source=str(args.log))
    split = windows_from_log(
        log,
        args.context_column,
        horizon=args.horizon,
        stride=args.stride,
        v_min=args.min_speed,
        x0_smoothing_s=args.x0_smoothing_s,
        max_windows=args.max_windows or None,
    )
    n_rows = len(log)
    del log  # the windows hold what the fit needs; a long log's table is large
    if args.joint:
        options = joint_options(
            params,
            rel_sigma=args.prior_rel or None,
            covariance=args.covariance,
            model_error_rel=args.model_error_rel,
        )
    else:
        options = FitOptions(covariance=args.covariance, model_error_rel=args.model_error_rel)
    results = fit_contexts(split, params, options, solver=args.solver)

    if args.json:
        contexts = {}
        for label, result in results.items():
            entry = result.to_dict()
            entry["samples"] = int(split.samples.get(label, 0))
            entry["windows_available"] = int(split.available.get(label, 0))
            contexts[str(label)] = entry
        print(
            json.dumps(
                {
                    "log": str(args.log),
                    "vehicle": params.name,
                    "nominal_theta": dict(zip(THETA_NAMES, map(float, params.theta), strict=True)),
                    "context_column": args.context_column,
                    "samples": n_rows,
                    "resampled_hz": args.resample,
                    "dt_s": split.dt,
                    "horizon": split.horizon,
                    "stride": args.stride,
                    "min_speed_mps": args.min_speed,
                    "max_windows": args.max_windows or None,
                    "solver": args.solver,
                    "covariance": options.covariance,
                    "model_error_rel": options.model_error_rel,
                    "free": list(options.free),
                    "prior_sigma": dict(options.prior_sigma or {}),
                    "candidate_windows": split.n_candidates,
                    "windows_skipped": split.skipped,
                    "contexts": contexts,
                }
            )
        )
        return 0

    print(
        f"{args.log}: {n_rows} samples, dt {split.dt:.4g} s, vehicle {params.name}, "
        f"H {split.horizon}, stride {args.stride}, v >= {args.min_speed:g} m/s, "
        f"fitted {', '.join(options.free)} ({args.solver})"
    )
    header = f"{'context':>12} {'samples':>8} {'windows':>8} "
    header += " ".join(f"{n:>9} {'+-std':>9}" for n in THETA_NAMES)
    header += f" {'loss':>9} {'iters':>5}  status"
    print(header)
    for label, result in results.items():
        row = f"{str(label):>12} {split.samples.get(label, 0):>8d} {result.n_windows:>8d} "
        row += " ".join(
            f"{_fmt(result.theta[i], 5):>9} {_fmt(result.std[i], 2):>9}" for i in range(3)
        )
        row += f" {_fmt(result.loss, 3):>9} {result.iterations:>5d}  {result.status}"
        print(row)
    skipped = ", ".join(f"{k} {v}" for k, v in split.skipped.items())
    print(f"candidate windows {split.n_candidates}; skipped: {skipped}")
    for label, result in results.items():
        available = split.available.get(label, 0)
        if available > result.n_windows > 0:
            print(
                f"note [{label}]: {result.n_windows} of {available} windows fitted, evenly spaced "
                "(--max-windows)"
            )
    for label, result in results.items():
        for warning in result.warnings:
            print(f"warning [{label}]: {warning}")
    return 0
