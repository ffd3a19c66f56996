"""``pcvfe diagnose``: compare the model with a drive log, rank missing effects, add them."""

from __future__ import annotations

import argparse
import json
import sys

from pcvfe_drake.models.data import EXCERPTS, load
from pcvfe_drake.models.effects import get_effect, known_effects
from pcvfe_drake.runs.output_paths import check_output_dir, write_failed
from pcvfe_drake.runs.resample import check_resample_rate
from pcvfe_drake.vehicle.params import load_vehicle


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "diagnose",
        help="compare the model with a drive log, find the missing physical effects one by one",
        description=(
            "Fit the single-track model on the training blocks of a drive log and compare it "
            "on held-out blocks (fit percent, k-step and free-run errors, residual analysis). "
            "Then the loop: rank every library effect on top of the current model "
            "(likelihood-ratio test, held-out error drop and its paired test), add the best "
            "significant one, check that the earlier ones are still needed, and repeat until "
            "nothing significant is left; finally test the residuals for structure outside "
            "the library and say where it shows. --add starts the loop from a given model. "
            f"Effects: {', '.join(known_effects())}."
        ),
    )
    p.add_argument("log", help="drive log (.csv/.parquet) or a run folder containing one")
    p.add_argument(
        "--add",
        action="append",
        default=[],
        metavar="EFFECT",
        help="start from a model with this effect and rank the library on top of it; report "
        "before/after against the baseline (repeatable)",
    )
    p.add_argument(
        "--candidates",
        default=None,
        help="comma-separated effects to rank (default: the whole library)",
    )
    p.add_argument(
        "--effects-file",
        action="append",
        default=[],
        metavar="FILE.py",
        help="a Python file that registers effects of your own (repeatable; docs/workbench.md). "
        "It is imported, i.e. its code RUNS with your permissions: use only files you trust",
    )
    p.add_argument("--vehicle", default=None, help="vehicle preset or YAML file (default: Ford)")
    p.add_argument(
        "--context-column",
        default=None,
        help="column with context labels (default: context, terrain)",
    )
    p.add_argument(
        "--resample",
        type=float,
        default=None,
        metavar="HZ",
        help="resample the log to HZ first (jittered or uneven time stamps): states "
        "interpolated linearly, inputs averaged over each new step, labels from the nearest row",
    )
    p.add_argument(
        "--accept-units",
        default=None,
        metavar="REASON",
        help="skip the unit heuristics (e.g. 'degrees instead of rad?') for a log you know is "
        "right; the reason is recorded in the report",
    )
    p.add_argument(
        "--out",
        default=None,
        help="folder for report.json, report.html and PNGs (checked before the work starts; "
        "written after the report is printed)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def load_effects_file(path: str) -> None:
    """Import (i.e. execute) a Python file; it registers effects with ``register_effect``.

    The file runs with the user's permissions, like any script they start. An exception or a
    ``sys.exit`` inside it is reported as a ``ValueError`` naming the file.
    """
    import importlib.util
    from pathlib import Path

    file = Path(path)
    if not file.is_file():
        raise FileNotFoundError(f"--effects-file {file}: no such file")
    spec = importlib.util.spec_from_file_location(f"pcvfe_user_effects_{file.stem}", file)
    if spec is None or spec.loader is None:
        raise ValueError(f"--effects-file {file}: not an importable Python file")
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except SystemExit as exc:
        raise ValueError(
            f"--effects-file {file}: the file called sys.exit({exc.code!r}) while being imported; "
            "an effects file should only define and register effects"
        ) from exc
    except Exception as exc:  # a user's file can fail in any way; report it cleanly
        raise ValueError(f"--effects-file {file}: {type(exc).__name__}: {exc}") from exc


def run(args: argparse.Namespace) -> int:
    from pcvfe_drake.workbench.report import diagnose, to_jsonable, write_report

    if args.out:
        check_output_dir(args.out)
    if args.resample is not None:
        check_resample_rate(args.resample)  # bounded before any work
    for path in args.effects_file:
        load_effects_file(path)
    add = [get_effect(e).name for e in args.add]  # unknown names fail before any work
    candidates = None
    if args.candidates:
        candidates = [get_effect(c.strip()).name for c in args.candidates.split(",") if c.strip()]
    vehicle = load_vehicle(args.vehicle)
    if args.accept_units is not None and not args.accept_units.strip():
        raise ValueError("--accept-units needs a reason (e.g. --accept-units 'drift test')")
    data = load(
        args.log,
        context_column=args.context_column,
        resample_hz=args.resample,
        check_units=args.accept_units is None,
    )
    if data.rows_in_log > data.n:
        print(
            f"note: {args.log} has {data.rows_in_log} samples; diagnose analyses {data.n} of "
            f"them, {EXCERPTS} excerpts of {data.n // EXCERPTS} consecutive samples evenly "
            "spaced over the log (bounded memory and time; docs/workbench.md)",
            file=sys.stderr,
        )
    report, wb = diagnose(data, vehicle, add=add, candidates=candidates)
    report["resampled_hz"] = args.resample
    report["unit_checks"] = (
        {"run": True}
        if args.accept_units is None
        else {"run": False, "reason": args.accept_units.strip()}
    )
    if args.json:
        print(json.dumps(to_jsonable(report)))
    else:
        base = report["baseline"]
        print(f"log {report['log']}: {report['duration_s']:.1f} s, contexts {report['contexts']}")
        print(
            f"baseline held-out model error {base['heldout_error']:.3g} "
            f"(multi-step {base['heldout_multistep_error']:.3g}, noise floor "
            f"{base['noise_floor']:.3g}); fit % at {base['fit_percent_horizon']}: "
            + ", ".join(f"{k} {v:.1f}" for k, v in base["fit_percent"].items())
        )
        start = report["selection"]["start"]
        print(f"the loop, from {' + '.join(start) if start else 'the baseline'}:")
        for i, step in enumerate(report["selection"]["path"], 1):
            sign = "+" if step["action"] == "add" else "-"
            params = ", ".join(f"{k}={v['value']:.4g}" for k, v in step.get("params", {}).items())
            note = f"  ({step['drop_note']})" if step.get("drop_note") else ""
            print(
                f"  {i}. {sign} {step['name']:20s} held-out error "
                f"{step['heldout_error_before']:.3g} -> {step['heldout_error']:.3g}  "
                f"p={step['p_value']:.2g}  {params}{note}"
            )
        if not report["selection"]["path"]:
            print("  no effect is significant; first round:")
            for r in report["ranked_effects"][:5]:
                note = f"  ({r['drop_note']})" if r["drop_note"] else ""
                print(
                    f"     {r['name']:20s} held-out error {r['heldout_error_drop']:+7.1%} "
                    f"(p={r['drop_p_value']:.2g})  LR p={r['p_value']:.2g}{note}"
                )
        final = report["final"]
        print(
            f"final model: {' + '.join(final['effects']) or 'baseline'}; "
            + ", ".join(
                f"{k} = {v['value']:.4g}" + (" (at a bound)" if v["at_bound"] else "")
                for k, v in final["params"].items()
            )
        )
        print(f"verdict: {report['verdict']['text']}")
        if "added" in report:
            added = report["added"]
            print(
                f"added {', '.join(added['effects'])}: held-out error drop "
                f"{report['error_drop']:.1%} (model error {base['heldout_error']:.3g} -> "
                f"{added['heldout_error']:.3g}, multi-step {base['heldout_multistep_error']:.3g}"
                f" -> {added['heldout_multistep_error']:.3g}, p={added['p_value']:.2g})"
            )
            for name, p in added["params"].items():
                print(f"  {name:24s} {p['value']:.5g} +- {p['std']:.2g} {p['unit']}")
            horizon = base["fit_percent_horizon"]
            after = added["heldout"]["fit_percent_kstep"].get(horizon, {})
            print(
                f"  fit % at {horizon} before -> after: "
                + ", ".join(
                    f"{k} {v:.1f} -> {after[k]:.1f}"
                    for k, v in base["fit_percent"].items()
                    if k in after
                )
            )
    if args.out:
        # Written after the report is printed: a full disk or a vanished folder loses no result.
        try:
            write_report(report, wb, args.out)
        except OSError as exc:
            raise write_failed(exc, "--out", args.out) from exc
        print(f"report written to {args.out}", file=sys.stderr)
    return 0
