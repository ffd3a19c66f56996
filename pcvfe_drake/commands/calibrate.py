"""``pcvfe calibrate``: a car's effect model for the context fitter, from a calibration drive."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

from pcvfe_drake.runs.output_paths import write_failed

MAPPINGS = ("lateral_peak", "peak_and_stiffness", "peak")

CHECK_FRACTION = 0.3
"""--simulate's default check surface, as a fraction of the calibration surface's friction: a
loose or wet surface (about a third of dry asphalt's grip), the low end of what an off-road car
meets, so that the held constants are checked across the range the fitter will use them on."""

CHECK_SLOWDOWN = 5.0
"""The check drive may take this many times the wall time per simulated second that the
calibration drive took (times the check programme's simulated seconds): the same programme at a
lower friction costs the integrator a few times more steps where the tyres slide; a drive far
slower than that is a multi-body state the integrator crawls through (a wheel's speed near zero,
which the CommonRoad model divides by), which it does not leave."""
CHECK_MIN_S = 30.0
"""The least time [s] the check drive is given, whatever the calibration drive took: starting
the drive's process and the truth's setup cost seconds however short the programme."""


class CheckDriveTimeout(RuntimeError):
    """The check surface's drive ran past its bound (``check_drive_limit_s``)."""


def check_drive_limit_s(calibration_wall_s: float, calibration_sim_s: float, check_sim_s: float):
    """The wall-time bound [s] of the check drive: ``CHECK_SLOWDOWN`` times the calibration
    drive's wall time per simulated second, times the check programme's simulated seconds, at
    least ``CHECK_MIN_S``."""
    rate = calibration_wall_s / max(calibration_sim_s, 1e-9)
    return max(CHECK_MIN_S, CHECK_SLOWDOWN * rate * check_sim_s)


def _drive_child(conn, drive, args, kwargs) -> None:  # pragma: no cover - runs in the child
    try:
        conn.send(("ok", drive(*args, **kwargs)))
    except BaseException as exc:  # noqa: BLE001 - every failure goes back to the parent
        try:
            conn.send(("error", exc))
        except Exception:  # noqa: BLE001 - an exception that does not pickle
            conn.send(("error", RuntimeError(f"{type(exc).__name__}: {exc}")))
    finally:
        conn.close()


def bounded_drive(drive, limit_s: float, *args, **kwargs):
    """``drive(*args, **kwargs)`` in a child process, ended after ``limit_s`` [s] of wall time
    (:class:`CheckDriveTimeout`); the child's exception is raised here. A drive may hang inside
    one integrator call (no progress callback runs there), so only a process can bound it.
    Where processes cannot be forked the drive runs here, unbounded."""
    import multiprocessing

    if "fork" not in multiprocessing.get_all_start_methods():
        return drive(*args, **kwargs)
    ctx = multiprocessing.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_drive_child, args=(child, drive, args, kwargs), daemon=True)
    proc.start()
    child.close()
    try:
        if not parent.poll(limit_s):
            raise CheckDriveTimeout(
                f"the drive ran past its bound of {limit_s:.0f} s (wall time) and was stopped"
            )
        try:
            kind, value = parent.recv()
        except EOFError:
            raise RuntimeError(f"the drive's process ended (exit code {proc.exitcode})") from None
    finally:
        if proc.is_alive():
            proc.terminate()
        proc.join(5.0)
        if proc.is_alive():
            proc.kill()
            proc.join()
        parent.close()
    if kind == "error":
        raise value
    return value


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "calibrate",
        help="calibrate a car's effect model (the context fitter's) on a calibration drive",
        description=(
            "Run the workbench's loop on a calibration drive and write the car's effect model "
            "for the context fitter (docs/vehicles.md): which effects, the values held and "
            "their standard deviations, and a model-error budget. The loop starts from the "
            "effects a car has by construction, with the constants the vehicle's own data "
            "give (track width, the tyre's camber offsets) held, and adds what is significant. "
            "Only what a car measures is read: the drive log's measured state and commanded "
            "inputs. With --simulate the drive is first driven on the multi-body truth: "
            "steady-state circles at rising speed, steering steps, a sine sweep and braking, "
            "on one surface of known friction, then again on a low-friction check surface where "
            "the held model fits only the friction (its offset joins the model-error budget)."
        ),
    )
    p.add_argument("log", nargs="?", help="calibration drive log (.csv/.parquet) or run folder")
    p.add_argument(
        "--simulate",
        metavar="VEHICLE",
        default=None,
        help="drive the calibration programme with this vehicle on the multi-body truth first "
        "(ford_escort, bmw_320i, vw_vanagon)",
    )
    p.add_argument("--vehicle", default=None, help="vehicle preset or YAML file (with a log)")
    p.add_argument(
        "--mapping",
        choices=MAPPINGS,
        default="peak_and_stiffness",
        help="--simulate: the multi-body truth's friction mapping; it states the tyre's "
        "stiffness law (peak_tyre k_s: 1 for peak_and_stiffness, else 0)",
    )
    p.add_argument(
        "--k-s",
        type=float,
        default=None,
        help="with a log: peak_tyre's stiffness exponent (how the tyre's stiffness follows the "
        "friction; one surface cannot show it; default 0: only the peak changes)",
    )
    p.add_argument(
        "--surface-mu",
        type=float,
        default=None,
        help="the calibration surface's friction peak (--simulate: default the tyre's nominal "
        "peak; with a log: known friction adds the fit's offset from it to the model-error "
        "budget)",
    )
    p.add_argument(
        "--check-mu",
        type=float,
        default=None,
        help="--simulate: friction of a second surface the programme is driven on, where the "
        "calibrated model fits only mu; its offset from the known value joins the model-error "
        f"budget and the model counts as measured between the two frictions (default "
        f"{CHECK_FRACTION:g} x the calibration surface's; 0: no check)",
    )
    p.add_argument("--seed", type=int, default=0, help="--simulate: seed of the sensor noise")
    p.add_argument("--context-column", default=None, help="column with surface labels")
    p.add_argument("--out", default=None, help="model file to write (default: print only)")
    p.add_argument("--save-log", default=None, help="--simulate: also write the drive log here")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def _progress(enabled: bool):
    start = time.monotonic()

    def report(text: str) -> None:
        if enabled:
            print(f"[{time.monotonic() - start:6.1f} s] {text}", file=sys.stderr, flush=True)

    return report


def run(args: argparse.Namespace) -> int:
    import pandas as pd

    from pcvfe_drake.models.data import find_log, prepare
    from pcvfe_drake.models.effect_model import STIFFNESS_LAW, write_model_file
    from pcvfe_drake.runs.drivelog import REQUIRED_COLUMNS, read_drive_log, write_drive_log
    from pcvfe_drake.vehicle.mb_truth import MbSingularity
    from pcvfe_drake.vehicle.params import load_vehicle
    from pcvfe_drake.workbench.calibration import calibrate

    if (args.log is None) == (args.simulate is None):
        raise ValueError("give a calibration drive LOG or --simulate VEHICLE (one of them)")
    if args.log is not None and args.vehicle is None:
        raise ValueError("a calibration LOG needs --vehicle (the car that drove it)")
    if args.simulate is not None and args.vehicle not in (None, args.simulate):
        raise ValueError("--simulate names the vehicle; leave out --vehicle or give the same")
    if args.out and Path(args.out).is_dir():
        raise ValueError(f"--out {args.out}: is a folder; give the model file's name")
    if args.check_mu is not None:
        if args.simulate is None:
            raise ValueError("--check-mu drives a second surface: it needs --simulate")
        if not (math.isfinite(args.check_mu) and 0 <= args.check_mu <= 2):
            raise ValueError(
                f"--check-mu must be a friction in (0, 2] or 0 (none), got {args.check_mu}"
            )
    report = _progress(not args.no_progress and not args.json)
    vehicle = args.simulate or args.vehicle
    params = load_vehicle(vehicle)
    cpu0 = time.process_time()
    known_mu = args.surface_mu
    if args.simulate is not None:
        from pcvfe_drake.vehicle.mb_truth import commonroad_parameters
        from pcvfe_drake.workbench.calibration_drive import (
            calibration_drive,
            programme,
            programme_duration_s,
        )

        commonroad_parameters(vehicle)  # a vehicle without multi-body parameters fails here
        if known_mu is None:
            known_mu = float(commonroad_parameters(vehicle).tire.p_dy1)
        k_s = STIFFNESS_LAW[args.mapping] if args.k_s is None else args.k_s
        last = [-1]

        def drive_progress(fraction: float) -> None:
            step = int(fraction * 10)
            if step > last[0]:
                last[0] = step
                report(f"calibration drive {fraction:4.0%}")

        report(f"driving the calibration programme: {vehicle}, {args.mapping}, mu {known_mu:g}")
        wall0 = time.monotonic()
        df = calibration_drive(
            vehicle, args.mapping, known_mu, seed=args.seed, progress=drive_progress
        )
        drive_wall_s = time.monotonic() - wall0
        if args.save_log:
            try:
                write_drive_log(df, args.save_log, validate=False)
            except OSError as exc:
                raise write_failed(exc, "--save-log", args.save_log) from exc
        source = f"calibration programme ({vehicle}, {args.mapping})"
        command = f"pcvfe calibrate --simulate {vehicle} --mapping {args.mapping}"
    else:
        k_s = 0.0 if args.k_s is None else args.k_s
        df = read_drive_log(find_log(args.log), max_gap_s=None)
        source = str(args.log)
        command = f"pcvfe calibrate {args.log} --vehicle {vehicle}"
    keep = [c for c in REQUIRED_COLUMNS if c in df.columns]  # only what a car measures
    if args.context_column and args.context_column in df.columns:
        keep.append(args.context_column)
    data = prepare(pd.DataFrame(df[keep]), source, args.context_column)
    report(f"the workbench's loop on {data.n} samples ({data.t[-1] - data.t[0]:.0f} s)")
    result = calibrate(data, vehicle, params, k_s, progress=report)
    summary = result.summary()
    check = None
    if args.simulate is not None and (args.check_mu is None or args.check_mu > 0):
        check_mu = CHECK_FRACTION * known_mu if args.check_mu is None else args.check_mu
        limit_s = check_drive_limit_s(
            drive_wall_s,
            programme_duration_s(programme(vehicle, known_mu)),
            programme_duration_s(programme(vehicle, check_mu)),
        )
        report(
            f"driving the programme on the check surface: mu {check_mu:.3g} "
            f"(at most {limit_s:.0f} s)"
        )
        last[0] = -1
        try:
            check_df = bounded_drive(
                calibration_drive,
                limit_s,
                vehicle,
                args.mapping,
                check_mu,
                seed=args.seed,
                progress=drive_progress,
            )
        except (MbSingularity, FloatingPointError, RuntimeError) as exc:
            # the multi-body truth cannot drive the programme there (the car spun or reversed
            # out of the model, or it crawls: the bound):
            # the model is written without a check (its error is extrapolated below the
            # calibration surface)
            print(
                f"warning: the check surface (mu {check_mu:g}) could not be driven on the "
                f"multi-body truth ({type(exc).__name__}: {exc}); the model has no checked_mu",
                file=sys.stderr,
            )
            check_df = None
        if check_df is not None:
            check = check_surface(check_df, keep, source, params, result.model, check_mu)
            result.model.checked_mu = round(float(check_mu), 4)
    if known_mu is not None:
        offsets = [abs(mu - known_mu) / known_mu for mu in result.surface_mu.values()]
        if check is not None:
            offsets.append(check["offset_rel"])
        bias = max(offsets)
        budget = round((result.model.model_error_rel**2 + bias**2) ** 0.5, 4)
        result.model.model_error_rel = budget
        summary["surface_mu_known"] = float(known_mu)
    if check is not None:
        summary["check_surface"] = check
    summary["cpu_s"] = round(time.process_time() - cpu0, 1)
    summary["source"] = source
    out = {"vehicle": vehicle, **result.model.to_dict(), "calibration": summary}
    if args.json:
        print(json.dumps(out))
    else:
        _print(vehicle, result, summary)
    if args.out:
        header = (
            f"Effect model of {vehicle} for the context fitter (docs/vehicles.md).\n"
            f"Written by `{command}`; the values are held by the fitter."
        )
        try:
            write_model_file(args.out, result.model, vehicle, header, summary)
        except OSError as exc:
            raise write_failed(exc, "--out", args.out) from exc
        print(f"model written to {args.out}", file=sys.stderr)
    return 0


def check_surface(df, keep: list[str], source: str, params, model, check_mu: float) -> dict:
    """The calibrated ``model`` on a drive over a second surface of known friction ``check_mu``:
    only mu fitted (the held values kept), as the context fitter would; the relative offset
    from the known friction is the model's error there."""
    import pandas as pd

    from pcvfe_drake.commands.fit_effects import fit_log
    from pcvfe_drake.models.data import prepare

    data = prepare(pd.DataFrame(df[[c for c in keep if c in df.columns]]), source + " check")
    fitted = next(iter(fit_log(data, params, model.effects)["contexts"].values()))
    mu, std = float(fitted["theta"]["mu"]), fitted["mu_std"]
    return {
        "mu_known": round(float(check_mu), 4),
        "mu_fitted": round(mu, 4),
        "mu_std": None if std is None else round(float(std), 4),
        "offset_rel": round(abs(mu - check_mu) / check_mu, 4),
    }


def _print(vehicle: str, result, summary: dict) -> None:
    print(
        f"{vehicle}: held-out error {result.baseline_heldout_error:.3g} (single-track) -> "
        f"{result.heldout_error:.3g} (noise floor {result.noise_floor:.3g}); effects: "
        + ", ".join(result.effects)
    )
    for effect in result.model.effects:
        values = ", ".join(
            f"{k} {v:.4g}" + (f" +- {effect.std[k]:.2g}" if effect.std.get(k) else "")
            for k, v in effect.fixed.items()
        )
        print(f"  {effect.name:18s} {values}")
    surface = ", ".join(
        f"{k} {v:.4f} +- {result.surface_mu_std[k]:.3f}" for k, v in result.surface_mu.items()
    )
    known = summary.get("surface_mu_known")
    print(f"  surface mu (fitted) {surface}" + (f" (known {known:.4f})" if known else ""))
    check = summary.get("check_surface")
    if check:
        print(
            f"  check surface mu {check['mu_fitted']:.4f} (known {check['mu_known']:.4f}, "
            f"offset {100 * check['offset_rel']:.1f} %)"
        )
    print(f"  model_error_rel {result.model.model_error_rel:.4f}; cpu {summary['cpu_s']} s")
