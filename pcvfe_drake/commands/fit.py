"""``pcvfe fit``: fit the friction per context of a drive log, with the live estimator's model.

The model is the one the live estimator uses (:func:`default_fit_model`): a run folder's own
``scenario.yaml`` fitter (its effect model, if any), a scenario named with ``--scenario``, or
else the single-track model. Each context's headline states mu as the friction and is judged
as the live estimator judges a friction peak and by the fit-quality checks
(``pcvfe_drake.estimation.fit_answer``): an identifiable mu is printed with its std; where
the data never came near the friction limit, the std is too large, the fit lies below the
friction used or does not explain the data, the headline is the lower bound, the lateral
friction the data used, with the words "not identifiable": a fit that converged on such data
is a stiffness scale or a prior, not the friction."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.estimation.estimate_table import Z95
from pcvfe_drake.estimation.fit_answer import distrust, judge_friction, mu_headline
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
    STATUS_DIVERGED,
    STATUS_TOO_LITTLE_DATA,
    FitOptions,
    joint_options,
    without_model_error,
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
            "Fit the friction of a drive log (CSV or Parquet, the drive-log format) per "
            "context with the live estimator's model: a run folder's scenario.yaml fitter (its "
            "effect model, if any), --scenario's, or else the single-track model (rollouts of H "
            "steps from the measured states with the recorded inputs, windows only from stable "
            "segments in one context with v >= --min-speed, paper eq. 5a-6; only mu fitted, "
            "--joint also fits C_Sf, C_Sr with Gaussian priors). Each context's mu is judged as "
            "the live estimator judges it: where the data never came near the friction limit "
            "the answer is a lower bound, the friction used, marked 'not identifiable'. Prints "
            "the answers and a table (or one JSON object with --json)."
        ),
    )
    parser.add_argument(
        "log",
        type=Path,
        help="drive log (.csv, .csv.gz, .parquet) or a run folder holding one",
    )
    parser.add_argument(
        "--vehicle",
        default=None,
        help="vehicle preset or YAML file (default: the scenario's, else ford_escort)",
    )
    parser.add_argument(
        "--scenario",
        default=None,
        metavar="NAME|FILE",
        help="fit with this scenario's live-estimator model (fitter.effects) and judge "
        "identifiability with its fitter settings (default: the run folder's scenario.yaml "
        "beside the log, else the single-track model)",
    )
    parser.add_argument(
        "--context-column",
        choices=("terrain", "context", "none"),
        default=None,
        help="column holding the context of each row (default: context, else terrain, as "
        "pcvfe diagnose; none: the whole log is one context)",
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
        help="fit the workbench model with this effect instead of the scenario's (repeatable; "
        "PARAM=VALUE fixes a parameter, e.g. steering_lag:tau=0.15; 'none': the single-track "
        "model): the log is fitted as `pcvfe diagnose --add` fits it (one model, mu per "
        "context, effect parameters shared, the diagnosis's training windows), so both give "
        "the same parameters (docs/fitting.md)",
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
        default=None,
        metavar="REL",
        help="model-error budget: mu's std becomes sqrt(std^2 + (REL mu)^2) (default: the "
        "scenario's fitter.model_error_rel, else 0; for a model error every window shares, "
        "calibrated against ground truth: docs/fitting.md)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(func=run)


ST_MODEL_NOTE = (
    "the single-track model (no scenario beside the log: give --scenario NAME|FILE or --effects "
    "to fit the live estimator's model)"
)


@dataclass
class FitModel:
    """The model ``pcvfe fit`` fits and the live estimator's settings it judges with.

    Attributes:
        effects: the effect model's effects (``FitterEffect``; empty: the single-track model).
        fitter: the live estimator's fitter settings (``LiveFitConfig``: ``identifiable_std``,
            ``near_limit_fraction``, ``model_error_rel``).
        vehicle: the scenario's vehicle (preset name or resolved file; None: not given).
        source: where the model came from, for the printed header.
        note: printed before the table when the model is a fallback (None: no note).
    """

    effects: list = field(default_factory=list)
    fitter: object = None
    vehicle: str | None = None
    source: str = "single-track model"
    note: str | None = None


def default_fit_model(log: Path, scenario: str | Path | None = None) -> FitModel:
    """The model the live estimator uses for ``log``: ``scenario`` (a shipped name or a YAML
    file) if given, else the ``scenario.yaml`` of the run folder holding ``log``, else the
    single-track model with a note. The one place that decides the default model (a vehicle's
    calibrated model file can take the fallback's place). The scenario is loaded as a run loads
    it (``load_scenario``, then ``Scenario.fit_config``), so ``estimator: pcvfe`` fits the
    vehicle's calibrated effect model and ``pcvfe_paper`` the single-track model.

    Raises ValueError naming the file when the scenario cannot be read or its ``fitter`` section
    is invalid (a run's model is never swapped silently for another)."""
    from pcvfe_drake.estimation.live_fit_config import LiveFitConfig

    if scenario is not None:
        from pcvfe_drake.runs.scenario_files import resolve_scenario_path

        path = resolve_scenario_path(scenario)
        source = f"scenario {path}"
    else:
        folder = log if log.is_dir() else log.parent
        path = folder / "scenario.yaml"
        if not path.is_file():
            return FitModel(fitter=LiveFitConfig(), note=ST_MODEL_NOTE)
        source = f"the run's scenario {path}"
    from pcvfe_drake.diagrams.scenario_io import load_scenario

    try:  # the scenario as a run loads it: the vehicle's calibrated model filled in
        loaded = load_scenario(path)
        fitter = loaded.fit_config()
    except FileNotFoundError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    vehicle = loaded.vehicle
    return FitModel(
        effects=list(fitter.effects),
        fitter=fitter,
        vehicle=vehicle if isinstance(vehicle, str) else None,
        source=source + (" (effect model)" if fitter.effects else " (single-track model)"),
    )


NOISE_LABELS = ("-1", "unknown")
"""Labels of the run log's ``context`` column for frames no context claimed (noise, empty)."""
NOISE_HEADLINE = {
    "kind": "noise",
    "text": "noise",
    "reason": "samples no context claimed (several terrains): not a context, no answer",
}


def _json(obj) -> str:
    """One JSON object: non-finite numbers as null (strict JSON), numpy scalars as numbers."""
    from pcvfe_drake.workbench.report import to_jsonable

    return json.dumps(to_jsonable(obj), default=lambda v: None, allow_nan=False)


def _note(model: FitModel, args: argparse.Namespace) -> None:
    """The fallback model's note, once the log has been read (not with ``--json``)."""
    if model.note and not args.json:
        print(f"note: fitting {model.note}")


def _context_column(log: pd.DataFrame, choice: str | None) -> str | None:
    """``--context-column``: None picks ``context``, else ``terrain`` (as ``pcvfe diagnose``)."""
    if choice == "none":
        return None
    if choice is not None:
        return choice
    return next((c for c in ("context", "terrain") if c in log.columns), None)


def _rows_of(log: pd.DataFrame, column: str | None, label) -> np.ndarray:
    if column is None:
        return np.ones(len(log), dtype=bool)
    values = log[column]
    if pd.api.types.is_numeric_dtype(values):
        return values.to_numpy(dtype=float) == float(label)
    return values.astype(str).to_numpy() == str(label)


def _print_headlines(contexts: dict, source: str) -> None:
    print(f"friction per context ({source}):")
    for label, c in contexts.items():
        h = c["headline"]
        if h["kind"] == "estimate":
            print(f"  {label:>12}  mu = {h['text']}")
        else:
            print(f"  {label:>12}  {h['text']}: {h['reason']}")


def run_effects(args: argparse.Namespace, model: FitModel) -> int:
    """The effect model on the whole log (``fit_effects.fit_log``), judged as the live estimator
    judges a context (``effect_fit.identifiability``)."""
    from pcvfe_drake.commands.fit_effects import fit_log
    from pcvfe_drake.models.data import find_log, prepare

    path = find_log(args.log)
    log = read_drive_log(path, max_gap_s=None)
    if args.resample is not None:
        log = resample_log(log, args.resample, source=str(path))
    _note(model, args)
    column = _context_column(log, args.context_column)
    if column is None:
        log = log.drop(columns=[c for c in ("context", "terrain") if c in log.columns])
    data = prepare(log, str(path), column)
    fitter = model.fitter
    model_error_rel = (
        fitter.model_error_rel if args.model_error_rel is None else args.model_error_rel
    )
    out = fit_log(
        data,
        load_vehicle(args.vehicle or model.vehicle),
        model.effects,
        identifiable_std=fitter.identifiable_std,
        near_limit_fraction=fitter.near_limit_fraction,
        covariance=args.covariance,
        model_error_rel=model_error_rel,
    )
    for k, (label, c) in enumerate(out["contexts"].items()):
        # no finite std: the data (too few samples) leave mu where it started, nothing fitted
        fitted = c["mu_std"] is not None and math.isfinite(c["mu_std"])
        if fitted:
            c["mu_std_data"] = without_model_error(c["theta"]["mu"], c["mu_std"], model_error_rel)
        judged = c
        if fitted and not out["mu_is_peak"]:
            # fit_log judged the model's mu as it is (a stiffness scale); the headline states it
            # as the friction, so it is judged as one (kept beside fit_log's fields)
            rows = data.context == k
            judged = c["judged_as_friction"] = judge_friction(
                data.t[rows],
                data.x[rows],
                c["theta"]["mu"],
                c["mu_std_data"],
                fitter.near_limit_fraction,
                fitter.identifiable_std,
            )
        c["headline"] = mu_headline(
            c["theta"]["mu"], c["mu_std"], {**c, **judged}, fitted, fitter.identifiable_std
        )
        if column == "context" and label in NOISE_LABELS:
            c["headline"] = NOISE_HEADLINE
    out = {
        "log": str(path),
        "model": model.source,
        "contexts_column": column,
        "identifiable_std": fitter.identifiable_std,
        "near_limit_fraction": fitter.near_limit_fraction,
        **out,
    }
    if args.json:
        print(_json(out))
        return 0
    names = ", ".join(
        s.name
        + ("" if not s.fixed else f" ({', '.join(f'{k}={v:g}' for k, v in s.fixed.items())})")
        for s in model.effects
    )
    print(
        f"{path}: effect model {names}; mu is the "
        + ("friction peak" if out["mu_is_peak"] else "single-track model's mu (a stiffness scale)")
        + f"; {out['training_windows']} training windows (as pcvfe diagnose)"
    )
    _print_headlines(out["contexts"], model.source)
    print(
        f"{'context':>12} {'mu fit':>8} {'+-std':>8} {'95 % interval':>16} {'C_Sf':>8} "
        f"{'C_Sr':>8} {'mu >=':>7}  limit"
    )
    for label, c in out["contexts"].items():
        th = c["theta"]
        lo, hi = (math.inf if v is None else v for v in c["mu_interval_95"])
        print(
            f"{label:>12} {_fmt(th['mu'], 4):>8} {_fmt(c['mu_std'], 2):>8} "
            f"{'[' + _fmt(lo, 3) + ', ' + (_fmt(hi, 3) if math.isfinite(hi) else 'inf') + ']':>16} "
            f"{_fmt(th['C_Sf'], 4):>8} {_fmt(th['C_Sr'], 4):>8} {_fmt(c['mu_lower_bound'], 3):>7}  "
            + _limit_words(c.get("judged_as_friction", c))
        )
    for name, p in out["params"].items():
        if "." in name:
            print(f"  {name} = {_fmt(p['value'], 5)} +- {_fmt(p['std'], 2)} {p['unit']}")
    return 0


def _limit_words(judged: dict) -> str:
    if judged.get("distrust"):
        return "fit not trustworthy: not identifiable"
    if judged.get("below_used"):
        return "peak below the friction used: not identifiable"
    if not judged["near_limit"]:
        return "never near: not identifiable"
    return "near" if judged["identifiable"] else "near, std large: not identifiable"


def _fmt(value: float, digits: int = 4) -> str:
    return f"{value:.{digits}g}" if value is not None and math.isfinite(value) else "-"


def run(args: argparse.Namespace) -> int:
    if args.resample is not None:
        check_resample_rate(args.resample)  # bounded before any work
    if args.effects == ["none"]:
        model = default_fit_model(args.log, args.scenario)
        model = FitModel(fitter=model.fitter, vehicle=model.vehicle, source="single-track model")
    elif args.effects:
        from pcvfe_drake.models.effect_model import parse_effects

        model = default_fit_model(args.log, args.scenario)
        model = FitModel(
            parse_effects(args.effects), model.fitter, model.vehicle, "--effects (effect model)"
        )
    else:
        model = default_fit_model(args.log, args.scenario)
    if model.effects:
        return run_effects(args, model)
    fitter = model.fitter
    params = load_vehicle(args.vehicle or model.vehicle)
    model_error_rel = (
        fitter.model_error_rel if args.model_error_rel is None else args.model_error_rel
    )
    if args.prior_rel < 0 or not math.isfinite(args.prior_rel):
        raise ValueError(f"--prior-rel must be >= 0, got {args.prior_rel}")
    if not (math.isfinite(args.min_speed) and args.min_speed >= 0):
        raise ValueError(f"--min-speed must be >= 0 m/s, got {args.min_speed}")
    if args.max_windows < 0 or args.max_windows == 1:
        raise ValueError(f"--max-windows must be 0 (all) or >= 2, got {args.max_windows}")
    from pcvfe_drake.models.data import find_log

    path = find_log(args.log)
    log = read_drive_log(path, validate=not args.lenient, max_gap_s=math.inf)
    if args.resample is not None:
        log = resample_log(log, args.resample, source=str(path))
    _note(model, args)
    column = _context_column(log, args.context_column)
    split = windows_from_log(
        log,
        column,
        horizon=args.horizon,
        stride=args.stride,
        v_min=args.min_speed,
        x0_smoothing_s=args.x0_smoothing_s,
        max_windows=args.max_windows or None,
    )
    if args.joint:
        options = joint_options(
            params,
            rel_sigma=args.prior_rel or None,
            covariance=args.covariance,
            model_error_rel=model_error_rel,
        )
    else:
        options = FitOptions(covariance=args.covariance, model_error_rel=model_error_rel)
    results = fit_contexts(split, params, options, solver=args.solver)
    judged = _judge(log, column, results, fitter, model_error_rel)
    n_rows = len(log)
    del log  # the windows hold what the fit needs; a long log's table is large

    if args.json:
        contexts = {}
        for label, result in results.items():
            entry = result.to_dict()
            entry["samples"] = int(split.samples.get(label, 0))
            entry["windows_available"] = int(split.available.get(label, 0))
            entry.update(judged[label])
            contexts[str(label)] = entry
        print(
            _json(
                {
                    "log": str(path),
                    "model": model.source,
                    "vehicle": params.name,
                    "nominal_theta": dict(zip(THETA_NAMES, map(float, params.theta), strict=True)),
                    "context_column": column,
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
                    "identifiable_std": fitter.identifiable_std,
                    "near_limit_fraction": fitter.near_limit_fraction,
                    "free": list(options.free),
                    "prior_sigma": dict(options.prior_sigma or {}),
                    "candidate_windows": split.n_candidates,
                    "windows_skipped": split.skipped,
                    "contexts": contexts,
                },
            )
        )
        return 0

    print(
        f"{path}: {n_rows} samples, dt {split.dt:.4g} s, vehicle {params.name}, "
        f"H {split.horizon}, stride {args.stride}, v >= {args.min_speed:g} m/s, "
        f"fitted {', '.join(options.free)} ({args.solver})"
    )
    _print_headlines({str(k): v for k, v in judged.items()}, model.source)
    header = f"{'context':>12} {'samples':>8} {'windows':>8} "
    header += " ".join(f"{n:>9} {'+-std':>9}" for n in THETA_NAMES)
    header += f" {'loss':>9} {'iters':>5} {'mu >=':>7}  solver; limit"
    print(header)
    for label, result in results.items():
        row = f"{str(label):>12} {split.samples.get(label, 0):>8d} {result.n_windows:>8d} "
        row += " ".join(
            f"{_fmt(result.theta[i], 5):>9} {_fmt(result.std[i], 2):>9}" for i in range(3)
        )
        j = judged[label]
        row += f" {_fmt(result.loss, 3):>9} {result.iterations:>5d} "
        row += f"{_fmt(j['mu_lower_bound'], 3):>7}  {result.status}; " + _limit_words(j)
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


def _judge(log: pd.DataFrame, column, results: dict, fitter, model_error_rel: float) -> dict:
    """Per context: ``fit_answer.judge_friction`` of the single-track fit on the context's rows
    (the std the data leave), its fit-quality verdict (``fit_answer.distrust``), the headline
    and the 95 % interval (``ContextEstimate.mu_interval_95``'s rule)."""
    t = log["t"].to_numpy(dtype=float)
    states = log[["sx", "sy", "delta", "v", "psi", "psi_dot", "beta"]].to_numpy(dtype=float)
    out = {}
    for label, result in results.items():
        rows = _rows_of(log, column, label) & np.all(np.isfinite(states), axis=1)
        mu, std = float(result.theta[0]), float(result.std[0])
        data_std = without_model_error(mu, std, model_error_rel)
        judged = judge_friction(
            t[rows],
            states[rows],
            mu,
            data_std,
            fitter.near_limit_fraction,
            fitter.identifiable_std,
        )
        judged["mu_std_data"] = data_std
        used = judged["mu_lower_bound"]
        fitted = result.status not in (STATUS_TOO_LITTLE_DATA, STATUS_DIVERGED)
        judged["distrust"] = distrust(result.quality) if fitted else None
        judged["identifiable"] = judged["identifiable"] and fitted and not judged["distrust"]
        if not fitted:
            interval = [None, None]
        elif judged["near_limit"] or not math.isfinite(used):
            interval = [mu - Z95 * std, mu + Z95 * std]
        else:
            interval = [used, None]
        judged["mu_interval_95"] = interval
        judged["headline"] = mu_headline(mu, std, judged, fitted, fitter.identifiable_std)
        out[label] = judged
    return out
