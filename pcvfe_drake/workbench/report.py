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

from pcvfe_drake.vehicle.single_track import STATE_NAMES
from pcvfe_drake.workbench.compare import public
from pcvfe_drake.workbench.data import DriveData
from pcvfe_drake.workbench.ranking import DiagnoseConfig, Workbench
from pcvfe_drake.workbench.residuals import breakdowns, whiteness


def diagnose(
    data: DriveData,
    vehicle=None,
    add: list[str] | None = None,
    candidates: list[str] | None = None,
    config: DiagnoseConfig | None = None,
) -> tuple[dict, Workbench]:
    """Compare, rank candidate effects and (with ``add``) refit; returns (report, workbench)."""
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
        "baseline": wb.baseline_summary(),
    }
    report["baseline"]["residuals"] = {
        "whiteness": whiteness(base.model, base.theta, data, wb.config.n_blocks),
        "breakdowns": breakdowns(wb.baseline_eval["_err"], wb.eval_starts, data),
    }
    report.update(wb.rank(candidates, start=add))
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


# ---------------------------------------------------------------------- plots
def _plots(report: dict, wb: Workbench, folder: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = []
    data = wb.data
    after_fit = getattr(wb, "added_fit", None)
    after_eval = getattr(wb, "added_eval", None)
    if after_fit is None and report.get("best"):
        best = next(c for c in wb.candidates if c.name == report["best"])
        after_fit, after_eval = best.fit, wb.evaluate(best.fit)
    label_after = "+ " + " + ".join(after_fit.model.effect_names) if after_fit else ""

    # 1. measured vs free-run overlays
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    for ax, state in zip(axes, ("v", "psi_dot", "beta"), strict=True):
        i = STATE_NAMES.index(state)
        for k, (idx, sim) in enumerate(wb.baseline_eval["_free_run"]):
            ax.plot(data.t[idx], data.x[idx, i], "k", lw=0.8, label="measured" if k == 0 else None)
            ax.plot(data.t[idx], sim[:, i], "C0", lw=0.8, label="baseline" if k == 0 else None)
        if after_eval is not None:
            for k, (idx, sim) in enumerate(after_eval["_free_run"]):
                ax.plot(data.t[idx], sim[:, i], "C3", lw=0.8, label=label_after if k == 0 else None)
        ax.set_ylabel(state)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("t [s] (held-out blocks, free run)")
    fig.tight_layout()
    fig.savefig(folder / "overlay.png", dpi=80)
    plt.close(fig)
    names.append("overlay.png")

    # 2. residual autocorrelation, before / after side by side
    cols = 2 if after_fit is not None else 1
    fig, axes = plt.subplots(1, cols, figsize=(6 * cols, 3.5), squeeze=False)
    sets = [("baseline", report["baseline"]["residuals"]["whiteness"])]
    if after_fit is not None:
        w = report.get("added", {}).get("residuals", {}).get("whiteness")
        if w is None:
            from pcvfe_drake.workbench.residuals import whiteness as _wh

            w = _wh(after_fit.model, after_fit.theta, data, wb.config.n_blocks)
        sets.append((label_after, w))
    for ax, (title, w) in zip(axes[0], sets, strict=True):
        for name, st in w["states"].items():
            ax.plot(range(1, len(st["autocorr"]) + 1), st["autocorr"], lw=1, label=name)
        ax.axhspan(-w["band_99"], w["band_99"], color="0.85")
        ax.set_title(f"one-step residual autocorrelation: {title}", fontsize=9)
        ax.set_xlabel("lag [samples]")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(folder / "residual_autocorr.png", dpi=80)
    plt.close(fig)
    names.append("residual_autocorr.png")

    # 3. ranking
    ranked = report["ranked_effects"]
    fig, ax = plt.subplots(figsize=(7, 3.5))
    drops = [max(r["heldout_error_drop"], -0.1) for r in ranked]
    colors = ["C2" if r["significant"] else "0.6" for r in ranked]
    ax.barh([r["name"] for r in ranked][::-1], drops[::-1], color=colors[::-1])
    ax.set_xlabel("held-out model error drop (green: significant)")
    fig.tight_layout()
    fig.savefig(folder / "ranking.png", dpi=80)
    plt.close(fig)
    names.append("ranking.png")

    # 4. error by operating regime, before / after
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.2))
    for ax, key in zip(axes, ("speed", "lateral_accel", "drive_mode"), strict=True):
        rows = report["baseline"]["residuals"]["breakdowns"][key]
        xs = np.arange(len(rows))
        ax.bar(xs - 0.2, [r["rms"] for r in rows], 0.4, label="baseline")
        if after_eval is not None:
            after = breakdowns(after_eval["_err"], wb.eval_starts, data)[key]
            ax.bar(xs + 0.2, [r["rms"] for r in after], 0.4, label=label_after)
        ax.set_xticks(xs, [r["bin"] for r in rows], rotation=20, fontsize=7)
        ax.set_title(f"whitened multi-step RMS by {key}", fontsize=9)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(folder / "breakdown.png", dpi=80)
    plt.close(fig)
    names.append("breakdown.png")
    return names


def _table(rows: list[dict], keys: list[str]) -> str:
    head = "".join(f"<th>{html.escape(k)}</th>" for k in keys)
    body = ""
    for r in rows:
        cells = []
        for k in keys:
            v = r.get(k, "")
            if isinstance(v, float):
                v = f"{v:.4g}"
            elif isinstance(v, dict):
                v = ", ".join(
                    f"{n} = {p['value']:.4g} &plusmn; {p['std']:.2g} {p['unit']}"
                    if isinstance(p, dict)
                    else f"{n}: {p}"
                    for n, p in v.items()
                )
                cells.append(f"<td>{v}</td>")
                continue
            cells.append(f"<td>{html.escape(str(v))}</td>")
        body += "<tr>" + "".join(cells) + "</tr>"
    return f"<table><tr>{head}</tr>{body}</table>"


def _html(report: dict, pngs: list[str], folder: Path) -> str:
    imgs = ""
    for name in pngs:
        b64 = base64.b64encode((folder / name).read_bytes()).decode()
        imgs += f'<h3>{html.escape(name)}</h3><img src="data:image/png;base64,{b64}"/>'
    base = report["baseline"]
    fit_rows = [{"state": k, "fit %": v} for k, v in base["fit_percent"].items()]
    ranked = [
        {**r, "signature": r.get("signature", {}).get("text", "")} for r in report["ranked_effects"]
    ]
    tables = ""
    sections = [("baseline", base["residuals"])]
    if "added" in report:
        sections.append(
            ("+ " + " + ".join(report["added"]["effects"]), report["added"]["residuals"])
        )
    for title, res in sections:
        white = [
            {"state": k, "fraction of lags 2-25 outside 99% band": v["fraction_outside_band"]}
            for k, v in res["whiteness"]["states"].items()
        ]
        tables += f"<h3>Residual whiteness, {html.escape(title)}</h3>"
        tables += _table(white, ["state", "fraction of lags 2-25 outside 99% band"])
        for key, rows in res["breakdowns"].items():
            tables += (
                f"<h4>{html.escape(title)}: whitened multi-step RMS by {html.escape(key)}</h4>"
            )
            tables += _table(rows, ["bin", "n", "rms"])
    added = ""
    if "added" in report:
        a = report["added"]
        added = (
            f"<h2>Added: {html.escape(', '.join(a['effects']))}</h2>"
            f"<p>held-out model error {base['heldout_error']:.4g} &rarr; {a['heldout_error']:.4g}"
            f" (drop {a['error_drop']:.1%})</p>" + _table([{"params": a["params"]}], ["params"])
        )
    return f"""<!DOCTYPE html><html><head><meta charset="utf-8"><title>pcvfe diagnose</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 6px;font-size:13px}}img{{max-width:100%}}</style></head>
<body><h1>Model-discrepancy report</h1>
<p>log {html.escape(str(report["log"]))}, {report["duration_s"]:.1f} s at
{report["rate_hz"]:.3g} Hz, vehicle {html.escape(report["vehicle"])}</p>
<h2>Verdict</h2><p><b>{html.escape(report["verdict"])}</b></p>
<p>Significance: {html.escape(report["method"])}</p>
<h2>Baseline</h2><p>held-out model error {base["heldout_error"]:.4g} (multi-step
{base["heldout_multistep_error"]:.4g}, noise floor {base["noise_floor"]:.4g}); fit % at
{html.escape(base["fit_percent_horizon"])} ahead:</p>
{_table(fit_rows, ["state", "fit %"])}
{_table([{"params": base["params"]}], ["params"])}
<h2>Ranked candidate effects</h2>
{
        _table(
            ranked,
            ["name", "significant", "p_value", "heldout_error_drop", "params", "signature"],
        )
    }
{added}
<h2>Plots</h2>{imgs}
<h2>Where the model fails</h2>{tables}</body></html>"""


def write_report(report: dict, wb: Workbench, out_dir: str | Path) -> Path:
    """Write report.json, report.html and PNGs into ``out_dir`` atomically per file set."""
    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    tmp.chmod(0o755)
    try:
        pngs = _plots(report, wb, tmp)
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
