"""Run a whole diagnosis and write it: ``report.json``, a self-contained ``report.html`` (PNG
plots embedded as base64) and the PNGs. Files are written to a temporary folder beside the
target and moved into place only when all of them are complete."""

from __future__ import annotations

import base64
import html
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from pcvfe_drake.models.data import DriveData
from pcvfe_drake.vehicle.single_track import STATE_NAMES
from pcvfe_drake.workbench.compare import public
from pcvfe_drake.workbench.excitation import require_excitation
from pcvfe_drake.workbench.figures import CAPTIONS, all_figures
from pcvfe_drake.workbench.ranking import DiagnoseConfig, Workbench
from pcvfe_drake.workbench.residuals import breakdowns, whiteness


def diagnose(
    data: DriveData,
    vehicle=None,
    add: list[str] | None = None,
    candidates: list[str] | None = None,
    config: DiagnoseConfig | None = None,
) -> tuple[dict, Workbench]:
    """Compare, rank candidate effects and (with ``add``) refit; returns (report, workbench).

    Raises :class:`~pcvfe_drake.workbench.excitation.NotDiagnosable` before any fit when the log
    carries no yaw excitation; without a speed change the verdict says what was not tested."""
    ex = require_excitation(data)
    wb = Workbench(data, vehicle, config)
    base = wb.baseline
    report: dict = {
        "log": data.source,
        "duration_s": data.duration,
        "rate_hz": 1.0 / data.dt,
        "contexts": data.context_names,
        "vehicle": wb.base_model.vehicle.name,
        "noise_sigma": dict(zip(STATE_NAMES, data.sigma.tolist(), strict=True)),
        "windows": {"train": int(wb.train_starts.size), "heldout": int(wb.eval_starts.size)},
        "excitation": ex,
        "baseline": wb.baseline_summary(),
    }
    report["baseline"]["residuals"] = {
        "whiteness": whiteness(base.model, base.theta, data, wb.config.n_blocks),
        "breakdowns": breakdowns(wb.baseline_eval["_err"], wb.eval_starts, data),
    }
    report.update(wb.rank(candidates, start=add))
    if ex["missing"]:
        report["verdict"]["untested"] = ex["missing"]
        report["verdict"]["text"] += f"; not tested, the log carries {ex['text']}"
    final = wb.final_fit
    report["final"]["residuals"] = {
        "whiteness": whiteness(final.model, final.theta, data, wb.config.n_blocks),
        "breakdowns": breakdowns(wb.final_eval["_err"], wb.eval_starts, data),
    }
    report["selection_errors"] = [
        wb.selection["rounds"][0]["ranked"][0]["heldout_error_before"]
        if wb.selection["rounds"]
        else wb.final_eval["model_error"]
    ]
    if add:
        added = wb.add(add)
        fit = wb.added_fit
        added["residuals"] = {
            "whiteness": whiteness(fit.model, fit.theta, data, wb.config.n_blocks),
            "breakdowns": breakdowns(wb.added_eval["_err"], wb.eval_starts, data),
        }
        report["added"] = added
        report["error_drop"] = added["error_drop"]
    return report, wb


def _fmt_params(params: dict) -> str:
    out = []
    for n, p in params.items():
        if p.get("at_bound"):
            out.append(f"{n} = {p['value']:.4g} {p['unit']} (at a bound)")
        elif p["std"] is None or not np.isfinite(p["std"]):
            out.append(f"{n} = {p['value']:.4g} {p['unit']}")
        else:
            out.append(f"{n} = {p['value']:.4g} &plusmn; {p['std']:.2g} {p['unit']}")
    return ", ".join(out)


def _table(rows: list[dict], keys: list[str]) -> str:
    head = "".join(f"<th>{html.escape(k)}</th>" for k in keys)
    body = ""
    for r in rows:
        cells = []
        for k in keys:
            v = r.get(k, "")
            if isinstance(v, float):
                cells.append(f"<td>{v:.4g}</td>")
            elif isinstance(v, dict):
                cells.append(f"<td>{_fmt_params(v)}</td>")
            else:
                cells.append(f"<td>{html.escape(str(v))}</td>")
        body += "<tr>" + "".join(cells) + "</tr>"
    return f"<table><tr>{head}</tr>{body}</table>"


def _html(report: dict, pngs: list[str], folder: Path) -> str:
    imgs = ""
    for name in pngs:
        b64 = base64.b64encode((folder / name).read_bytes()).decode()
        caption = CAPTIONS.get(name, "")
        imgs += (
            f'<figure id="{html.escape(name.removesuffix(".png"))}"><img alt="{html.escape(name)}"'
            f' src="data:image/png;base64,{b64}"/><figcaption><b>{html.escape(name)}</b>: '
            f"{html.escape(caption)}</figcaption></figure>"
        )
    base = report["baseline"]
    verdict = report["verdict"]
    fit_rows = [{"state": k, "fit %": v} for k, v in base["fit_percent"].items()]
    path = [
        {
            "step": i + 1,
            "action": s["action"],
            "effect": s["name"],
            "p": s["p_value"],
            "error before": s["heldout_error_before"],
            "error after": s["heldout_error"],
            "note": s.get("drop_note", ""),
            "params": s.get("params", {}),
        }
        for i, s in enumerate(report["selection"]["path"])
    ]
    ranked = [
        {**r, "signature": r.get("signature", {}).get("text", "")} for r in report["ranked_effects"]
    ]
    tests = [
        {"test": t["what"], "p": t["p_value"], "threshold": t["threshold"], "fails": t["failed"]}
        for t in verdict["tests"]
    ]
    final = report["final"]
    where = verdict["where"] or "-"
    evidence = verdict.get("stand_in_evidence", {})
    stand_ins = ""
    if verdict.get("stand_ins"):
        rows = [{"effect": e, "evidence": evidence.get(e, "")} for e in verdict["stand_ins"]]
        stand_ins = (
            '<p id="stand-ins">Stand-ins: the loop added them and they lower the error, but '
            "they are not the cause:</p>" + _table(rows, ["effect", "evidence"])
        )
    return f"""<!DOCTYPE html><html><head><meta charset="utf-8"><title>pcvfe diagnose</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 6px;font-size:13px}}img{{max-width:100%}}
.verdict{{font-size:17px;padding:8px;border-left:6px solid #888}}</style></head>
<body><h1>Model-discrepancy report</h1>
<p>log {html.escape(str(report["log"]))}, {report["duration_s"]:.1f} s at
{report["rate_hz"]:.3g} Hz, vehicle {html.escape(report["vehicle"])}</p>
<h2>Verdict: <span id="verdict-kind">{html.escape(verdict["kind"])}</span></h2>
<p class="verdict" id="verdict">{html.escape(verdict["text"])}</p>
<p id="where">Where: {html.escape(where)}</p>
<p>Tests of the final model (alpha {verdict["alpha"]:g}: half for the error test, half
shared by the residual tests):</p>
{_table(tests, ["test", "p", "threshold", "fails"])}
{stand_ins}
<h2>The loop</h2>
{_table(path, ["step", "action", "effect", "p", "error before", "error after", "note", "params"])}
<p>Final model: {html.escape(" + ".join(final["effects"]) or "baseline")}; held-out model error
{final["heldout_error"]:.4g}, noise floor {final["noise_floor"]:.4g}.
{_fmt_params(final["params"])}</p>
<p>Significance: {html.escape(report["method"])}</p>
<h2>Baseline</h2><p>held-out model error {base["heldout_error"]:.4g} (multi-step
{base["heldout_multistep_error"]:.4g}, noise floor {base["noise_floor"]:.4g}); fit % at
{html.escape(base["fit_percent_horizon"])} ahead:</p>
{_table(fit_rows, ["state", "fit %"])}
<h2>First round: each effect alone</h2>
{
        _table(
            ranked,
            [
                "name",
                "significant",
                "p_value",
                "heldout_error_drop",
                "drop_p_value",
                "drop_note",
                "params",
                "signature",
            ],
        )
    }
<h2>Where the model fails</h2>{imgs}</body></html>"""


def write_report(report: dict, wb: Workbench, out_dir: str | Path) -> Path:
    """Write report.json, report.html and PNGs into ``out_dir`` atomically per file set."""
    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    tmp.chmod(0o755)
    try:
        pngs = all_figures(report, wb, tmp)
        (tmp / "report.json").write_text(json.dumps(to_jsonable(report), indent=1))
        (tmp / "report.html").write_text(_html(report, pngs, tmp))
        if out.exists():
            if not out.is_dir():
                raise ValueError(f"--out {out}: exists and is not a folder")
            for f in tmp.iterdir():
                os.replace(f, out / f.name)
            tmp.rmdir()
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def to_jsonable(obj):
    """Drop private arrays (keys starting with '_') and convert numpy scalars."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items() if not str(k).startswith("_")}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


__all__ = ["diagnose", "write_report", "to_jsonable", "public"]
