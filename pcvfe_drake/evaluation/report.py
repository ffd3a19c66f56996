"""The report of an experiment, rebuilt from the stored tables (``pcvfe evaluate --report DIR``).

:func:`build_report` reads a results folder (``pcvfe_drake.evaluation.store``) and writes
``report.md`` and ``report.html`` (standalone: figures embedded) with

- per scenario, the table per source: every metric of ``tables.METRICS`` that the runs have, as
  the mean over seeds with its 95 % confidence interval, and the paired difference to the
  reference source (PC-VFE in the shipped experiment) seed by seed, with its interval;
- the per-seed differences of mean speed and failures;
- the friction estimates per terrain (from the ``contexts`` table): how many (context, seed)
  pairs stayed within 0.05 of the truth after their first 20 s, how many 95 % intervals held
  the truth, and the range of the final estimates;
- the figures (``figures/``): speed and failure bars with intervals, mu_hat over time of every
  source on one seed, and the map of failures;
- failed runs with their errors, and the experiment as run with the package versions.

No pydrake: the report needs only this folder.
"""

from __future__ import annotations

import base64
import html
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from pcvfe_drake.evaluation import plots
from pcvfe_drake.evaluation.stats import LEVEL, mean_ci, paired_differences
from pcvfe_drake.evaluation.store import ResultsFolderError, ResultStore
from pcvfe_drake.evaluation.tables import METRICS, MU_TOLERANCE, terrain_rows


@dataclass
class _Doc:
    """A report as blocks, rendered both as Markdown and as HTML."""

    blocks: list[tuple] = field(default_factory=list)

    def h(self, level: int, text: str) -> None:
        self.blocks.append(("h", level, text))

    def p(self, text: str) -> None:
        self.blocks.append(("p", text))

    def table(self, header: list[str], rows: list[list[str]]) -> None:
        self.blocks.append(("table", header, rows))

    def image(self, path: Path, alt: str) -> None:
        self.blocks.append(("image", path, alt))

    def code(self, text: str) -> None:
        self.blocks.append(("code", text))

    def markdown(self, root: Path) -> str:
        out = []
        for b in self.blocks:
            if b[0] == "h":
                out.append(f"{'#' * b[1]} {b[2]}\n")
            elif b[0] == "p":
                out.append(f"{b[1]}\n")
            elif b[0] == "table":
                out.append("| " + " | ".join(b[1]) + " |")
                out.append("|" + "---|" * len(b[1]))
                out.extend("| " + " | ".join(r) + " |" for r in b[2])
                out.append("")
            elif b[0] == "image":
                out.append(f"![{b[2]}]({b[1].relative_to(root).as_posix()})\n")
            elif b[0] == "code":
                out.append(f"```\n{b[1].rstrip()}\n```\n")
        return "\n".join(out)

    def html(self, title: str) -> str:
        esc = html.escape
        out = [
            "<!doctype html><html><head><meta charset='utf-8'>",
            f"<title>{esc(title)}</title><style>body{{font-family:sans-serif;max-width:1200px;"
            "margin:2em auto}}table{{border-collapse:collapse;margin:1em 0}}td,th{{border:1px "
            "solid #ccc;padding:3px 8px;text-align:right}}th{{background:#f3f3f3}}"
            "img{{max-width:100%}}pre{{background:#f6f6f6;padding:1em;overflow:auto}}</style>",
            "</head><body>",
        ]
        for b in self.blocks:
            if b[0] == "h":
                out.append(f"<h{b[1]}>{esc(b[2])}</h{b[1]}>")
            elif b[0] == "p":
                out.append(f"<p>{esc(b[1])}</p>")
            elif b[0] == "table":
                out.append("<table><tr>" + "".join(f"<th>{esc(c)}</th>" for c in b[1]) + "</tr>")
                out.extend(
                    "<tr>" + "".join(f"<td>{esc(c)}</td>" for c in r) + "</tr>" for r in b[2]
                )
                out.append("</table>")
            elif b[0] == "image":
                data = base64.b64encode(b[1].read_bytes()).decode()
                out.append(f"<p><img alt='{esc(b[2])}' src='data:image/png;base64,{data}'></p>")
            elif b[0] == "code":
                out.append(f"<pre>{esc(b[1])}</pre>")
        out.append("</body></html>")
        return "\n".join(out)


def fmt_number(x: float) -> str:
    """A number in 3 significant digits (whole above 1000; "-" for None or NaN)."""
    if x is None or not math.isfinite(x):
        return "-"
    if x == 0:
        return "0"
    return f"{x:.3g}" if abs(x) < 1000 else f"{x:.0f}"


def ci_text(values) -> str:
    """``mean [lo, hi]`` of ``values`` with its 95 % interval (``(n=1)`` for a single value)."""
    ci = mean_ci(values)
    if ci.n == 0:
        return "-"
    if ci.n == 1 or not math.isfinite(ci.lo):
        return f"{fmt_number(ci.mean)} (n=1)"
    return f"{fmt_number(ci.mean)} [{fmt_number(ci.lo)}, {fmt_number(ci.hi)}]"


def _sources(store: ResultStore, runs: pd.DataFrame) -> list[str]:
    names = [s.get("name") for s in store.experiment_dict().get("sources") or []]
    seen = [s for s in names if s in set(runs["source"])]
    return seen + [s for s in dict.fromkeys(runs["source"]) if s not in seen]


def _reference(store: ResultStore, sources: list[str]) -> str:
    ref = store.experiment_dict().get("reference") or ""
    return ref if ref in sources else (sources[0] if sources else "")


def _label(m) -> str:
    arrow = "higher is better" if m.better == "higher" else "lower is better"
    unit = f" [{m.unit}]" if m.unit else ""
    return f"{m.label}{unit} ({arrow})"


def _scenario_maps(store: ResultStore, runs: pd.DataFrame) -> dict:
    """Per scenario: terrain map image, its bounds and the course polyline (from a run's
    scenario.yaml)."""
    from pcvfe_drake.diagrams.world_io import build_world
    from pcvfe_drake.perception.ground_render import render_topdown
    from pcvfe_drake.worlds.world_file import TerrainOverride

    maps = {}
    for sc, group in runs.groupby("scenario"):
        path = store.run_dir(group["run_id"].iloc[0]) / "scenario.yaml"
        if not path.is_file():
            continue
        try:
            raw = yaml.safe_load(path.read_text()) or {}
        except (yaml.YAMLError, UnicodeDecodeError):
            continue  # no map for this scenario (the failure map draws without it)
        if not isinstance(raw, dict):
            continue
        try:
            overrides = {
                name: TerrainOverride(**change)
                for name, change in (raw.get("terrains") or {}).items()
            }
            world = build_world(
                raw.get("world", "paper"),
                terrains=overrides,
                course=raw.get("course") or "",
                check_course=False,
            )
            image = render_topdown(world.terrain_map, px_per_m=2.0)
            bounds = world.terrain_map.bounds_m
            course = world.course
        except (ValueError, FileNotFoundError, TypeError):
            continue
        maps[sc] = (image, bounds, np.column_stack([course.x, course.y]))
    return maps


def world_table(runs: pd.DataFrame, metric, sources: list[str]) -> list[dict]:
    """Per source, over the worlds of the world axis: the per-world means of ``metric`` (over
    seeds), their median, the worst world and its value, the count of worlds and failed runs.
    Rows of runs without a world are left out."""
    if "world" not in runs.columns:
        return []
    done = runs[(runs["status"] == "done") & (runs["world"].astype(str) != "")]
    out = []
    for src in sources:
        mine = done[done["source"] == src]
        per_world = mine.groupby("world")[metric.column].mean().dropna()
        if per_world.empty:
            continue
        worst = per_world.idxmax() if metric.better == "lower" else per_world.idxmin()
        failed = runs[(runs["source"] == src) & (runs["status"] != "done")]
        out.append(
            {
                "source": src,
                "worlds": int(per_world.size),
                "mean": float(per_world.mean()),
                "median": float(per_world.median()),
                "worst_world": str(worst),
                "worst": float(per_world[worst]),
                "failed_runs": int(len(failed)),
            }
        )
    return out


WORLD_COLUMN = "world"
"""A runs-table column that, when present, splits a scenario's runs into worlds."""


def scenario_groups(runs: pd.DataFrame) -> pd.Series:
    """Each run's scenario without its world: an experiment over worlds names a scenario
    ``NAME@WORLD`` per world, and its runs on every world make one group (one table, with the
    median and the worst world) instead of one per world."""
    names = runs["scenario"].astype(str)
    if WORLD_COLUMN not in runs.columns:
        return names
    suffixes = "@" + runs[WORLD_COLUMN].astype(str)
    return pd.Series(
        [n[: -len(x)] if n.endswith(x) else n for n, x in zip(names, suffixes, strict=True)],
        index=runs.index,
    )


def _worlds(runs: pd.DataFrame) -> set[str]:
    """The worlds the runs were made on (empty without a world axis)."""
    if WORLD_COLUMN not in runs.columns:
        return set()
    return set(runs[WORLD_COLUMN].astype(str)) - {""}


def oracle_failed_worlds(runs: pd.DataFrame) -> list[str]:
    """The worlds where a finished run of the ``oracle`` source had a catastrophic failure:
    knowing the friction under the car exactly was not enough there (typically a friction drop
    inside a bend), so no source is expected to drive that world, and a ratio to the oracle's
    speed is not defined."""
    if not {"world", "source", "failures", "status"} <= set(runs.columns):
        return []
    mine = runs[(runs["source"] == "oracle") & (runs["status"] == "done")]
    mine = mine[mine["world"].astype(str) != ""]
    return sorted(str(w) for w in mine.loc[mine["failures"].fillna(0) > 0, "world"].unique())


def _worlds_section(doc: _Doc, runs: pd.DataFrame, sources: list[str], metrics) -> None:
    """Results of one scenario over the worlds of the world axis: per source, each metric's
    per-world mean (over seeds), its median and its worst world, since a mean over worlds hides
    the world a method fails in; then each world's mean speed and failures per source."""
    n_worlds = len(_worlds(runs))
    if not n_worlds:
        return
    doc.h(3, f"Over its {n_worlds} world{'s' if n_worlds != 1 else ''}")
    doc.p(
        "Per source and metric: the mean over seeds in each world, then the median and the "
        "mean of those over the worlds, and the worst world (the lowest, or the highest where "
        "lower is better) with its value."
    )
    header = ["metric", "source", "worlds", "median", "mean", "worst world", "worst"]
    rows = []
    for m in metrics:
        for r in world_table(runs, m, sources):
            rows.append(
                [
                    _label(m),
                    r["source"],
                    str(r["worlds"]),
                    fmt_number(r["median"]),
                    fmt_number(r["mean"]),
                    r["worst_world"],
                    fmt_number(r["worst"]),
                ]
            )
    doc.table(header, rows)
    failed = oracle_failed_worlds(runs)
    if failed:
        doc.p(
            f"The oracle itself failed in {len(failed)} world{'s' if len(failed) != 1 else ''}: "
            f"{', '.join(failed)}. Knowing the friction under the car exactly was not enough "
            "there, so these worlds say more about the world than about a friction source; "
            "judge speeds against the oracle over the other worlds."
        )
    done = runs[(runs["status"] == "done") & (runs["world"].astype(str) != "")]
    per = done.pivot_table(index="world", columns="source", values="mean_speed_mps", aggfunc="mean")
    if per.empty:
        return
    fails = done.pivot_table(index="world", columns="source", values="failures", aggfunc="sum")
    cols = [s for s in sources if s in per.columns]

    def cell(w, c) -> str:
        n = fails.loc[w, c] if w in fails.index and c in fails.columns else math.nan
        lost = f" ({fmt_number(n)} failed)" if math.isfinite(n) and n > 0 else ""
        return fmt_number(per.loc[w, c]) + lost

    doc.p(
        "Per world: mean speed [m/s] (mean over seeds), with the failures summed over its "
        "seeds where there were any."
    )
    doc.table(["world", *cols], [[w] + [cell(w, c) for c in cols] for w in per.index])


def _terrain_table(doc: _Doc, rows: list[dict], sources: list[str]) -> None:
    """The friction estimates per source and terrain of one scenario (``tables.terrain_rows``)
    with a total per source."""
    if not rows:
        return
    doc.h(3, "Friction estimates per terrain")
    doc.p(
        f"Per (context, seed) pair, by the context's majority terrain: within "
        f"{MU_TOLERANCE:g} = |mu_hat - mu| stayed <= {MU_TOLERANCE:g} from the context's 20th "
        "second of driving on (of the pairs driven that long); covered = the run's 95 % "
        "interval held the truth; final fit = the range of the fitted mu at the run's end (where "
        "the peak was not identifiable the controller was handed an explored value instead, "
        "which is what the within column scores)."
    )

    out = []
    for src, mine in _by_source(rows, sources):
        for r in mine:
            out.append(
                [
                    src,
                    str(r["terrain"]),
                    fmt_number(r["true_mu"]),
                    str(r["pairs"]),
                    _share(r["within"], r["scored"]),
                    _share(r["covered"], r["interval_known"]),
                    f"{fmt_number(r['mu_hat_min'])}-{fmt_number(r['mu_hat_max'])}",
                ]
            )
        total = {k: sum(r[k] for r in mine) for k in ("pairs", "within", "scored")}
        total |= {k: sum(r[k] for r in mine) for k in ("covered", "interval_known")}
        out.append(
            [
                f"**{src}**",
                "all",
                "",
                str(total["pairs"]),
                _share(total["within"], total["scored"]),
                _share(total["covered"], total["interval_known"]),
                "",
            ]
        )
    doc.table(
        [
            "source",
            "terrain",
            "true mu",
            "contexts",
            f"within {MU_TOLERANCE:g} after 20 s",
            "95 % interval covers",
            "final fit",
        ],
        out,
    )


def _per_seed_tables(doc: _Doc, diffs: dict, sources: list[str], ref: str) -> None:
    """The paired differences of mean speed and failures to ``ref``, seed by seed."""
    for col, label in (("mean_speed_mps", "mean speed [m/s]"), ("failures", "failures")):
        if col not in diffs:
            continue
        d = diffs[col].pivot_table(index="seed", columns="source", values="diff")
        if d.empty:
            continue
        doc.p(f"Per seed: {label}, source minus {ref}.")
        cols = [s for s in sources if s in d.columns]
        doc.table(
            ["seed", *cols],
            [[str(seed)] + [fmt_number(d.loc[seed, c]) for c in cols] for seed in d.index],
        )


def _terrain_totals(doc: _Doc, rows: list[dict], sources: list[str]) -> None:
    """The friction estimates of one scenario over its worlds, per source (``terrain_rows`` of
    each world's scenario, summed): a terrain's name has another friction in each world, so
    the rows per terrain stay in the contexts table."""
    if not rows:
        return
    doc.h(3, "Friction estimates over the worlds")
    doc.p(
        f"Per (context, world, seed) triple, summed over the worlds' terrains: within "
        f"{MU_TOLERANCE:g} = |mu_hat - mu| stayed <= {MU_TOLERANCE:g} from the context's 20th "
        "second of driving on (of those driven that long); covered = the run's 95 % interval "
        "held the truth. Per terrain and world: contexts.parquet."
    )
    out = []
    for src, mine in _by_source(rows, sources):
        total = {
            k: sum(r[k] for r in mine)
            for k in ("pairs", "within", "scored", "covered", "interval_known")
        }
        out.append(
            [
                src,
                str(total["pairs"]),
                _share(total["within"], total["scored"]),
                _share(total["covered"], total["interval_known"]),
            ]
        )
    doc.table(
        ["source", "contexts", f"within {MU_TOLERANCE:g} after 20 s", "95 % interval covers"],
        out,
    )


def _by_source(rows: list[dict], sources: list[str]):
    """``(source, its rows)`` per source of ``rows``, in the order of ``sources`` (others
    after them)."""
    order = {s: i for i, s in enumerate(sources)}
    for src in sorted({r["source"] for r in rows}, key=lambda s: order.get(s, len(order))):
        yield src, [r for r in rows if r["source"] == src]


def _share(k: int, n: int) -> str:
    return f"{k} of {n} ({k / n:.2f})" if n else "-"


MU_PLOT_COLUMNS = ("t", "mu_hat", "mu_true")
"""Drive-log columns the mu-over-time figure draws."""


def build_report(root: str | Path) -> tuple[Path, Path]:
    """Write ``report.md``, ``report.html`` and ``figures/`` of the results folder ``root``."""
    store = ResultStore(root)
    if not store.exists():
        raise FileNotFoundError(
            f"{store.root}: no runs.parquet here; run `pcvfe evaluate EXPERIMENT --out "
            f"{store.root}` first"
        )
    runs = store.table("runs")
    if runs.empty:  # an evaluation stopped before its first run: a report of nothing misleads
        raise ValueError(
            f"{store.root / 'runs.parquet'}: no runs recorded yet, nothing to report; run "
            f"`pcvfe evaluate EXPERIMENT --out {store.root}` to record some"
        )
    exp = store.experiment_dict()
    sources = _sources(store, runs)
    ref = _reference(store, sources)
    done = runs[runs["status"] == "done"]
    failed = runs[runs["status"] != "done"]
    metrics = [
        m
        for m in METRICS
        if m.column in done.columns and np.isfinite(done[m.column].astype(float)).any()
    ]
    missing = [m.label for m in METRICS if m not in metrics]
    store.figures.mkdir(parents=True, exist_ok=True)

    doc = _Doc()
    name = exp.get("name", store.root.name)
    doc.h(1, f"Experiment {name}")
    if exp.get("description"):
        doc.p(exp["description"])
    names = sorted(scenario_groups(runs).unique())
    worlds = _worlds(runs)
    on_worlds = f", each on {len(worlds)} worlds (NAME@WORLD)" if worlds else ""
    doc.p(
        f"{len(runs)} runs: {len(done)} done, {len(failed)} failed; scenarios "
        f"{', '.join(names)}{on_worlds}; sources {', '.join(sources)}; seeds "
        f"{', '.join(str(s) for s in sorted(runs['seed'].unique()))}. Every cell is the mean over "
        f"seeds with its {LEVEL:.0%} confidence interval (Student t) in brackets; differences are "
        f"paired by seed against {ref}."
    )
    if missing:
        doc.p(f"Not in these runs' summary.json (not shown): {', '.join(missing)}.")
    terrain = terrain_rows(store.table("contexts"))
    groups = scenario_groups(done)
    failed_groups = scenario_groups(failed)
    for sc in sorted(groups.unique()):
        here = done[groups == sc]
        n_worlds = len(_worlds(here))
        over_worlds = n_worlds > 1
        doc.h(2, f"Scenario {sc}")
        if over_worlds:
            doc.p(
                f"Over {n_worlds} worlds (scenarios {sc}@WORLD): every cell "
                "is the mean over the worlds and seeds, differences are paired by seed and world."
            )
        header = ["source", "runs"] + [_label(m) for m in metrics]
        rows = []
        for src in sources:
            r = here[here["source"] == src]
            n_failed = int(((failed_groups == sc) & (failed["source"] == src)).sum())
            count = f"{len(r)}" + (f" (+{n_failed} failed)" if n_failed else "")
            rows.append([src, count] + [ci_text(r[m.column].astype(float)) for m in metrics])
        doc.table(header, rows)
        same = "same seed and world" if over_worlds else "same seed"
        doc.h(3, f"Paired difference to {ref} (source minus {ref}, {same})")
        header = ["source", "pairs"] + [_label(m) for m in metrics]
        rows = []
        by = ("seed", WORLD_COLUMN) if over_worlds else ("seed",)
        diffs = {m.column: paired_differences(here, m.column, ref, by=by) for m in metrics}
        for src in sources:
            if src == ref:
                continue
            mine = [d[d["source"] == src]["diff"] for d in diffs.values()]
            pairs = max((len(d) for d in mine), default=0)
            rows.append([src, str(pairs)] + [ci_text(d) for d in mine])
        doc.table(header, rows)
        scenarios = set(here["scenario"])
        mine = [r for r in terrain if r["scenario"] in scenarios]
        if over_worlds:
            _worlds_section(doc, here, sources, metrics)
            _terrain_totals(doc, mine, sources)
        else:
            _per_seed_tables(doc, diffs, sources, ref)
            _terrain_table(doc, mine, sources)
        stopped = here[here["error"].astype(str) != ""]
        if len(stopped):
            doc.p(
                "Runs whose simulation stopped early with an error (their metrics cover the "
                "time before it): "
                + "; ".join(f"{r.run_id}: {r.error}" for r in stopped.itertuples())
            )

    doc.h(2, "Figures")
    bars = plots.plot_bars(runs, sources, store.figures / "speed_failures.png")
    doc.image(bars, "mean speed and failures per source with 95 % intervals")
    plot_seed = exp.get("plot_seed")
    if plot_seed is None and len(done):
        plot_seed = int(done["seed"].min())
    if len(done):
        sc0 = sorted(done["scenario"].unique())[0]
        logs = {}
        no_log = []
        for r in done[(done["scenario"] == sc0) & (done["seed"] == plot_seed)].itertuples():
            try:
                log = store.drive_log(r.run_id)
            except ResultsFolderError as exc:  # one damaged run: the rest is still drawn
                no_log.append(f"{r.run_id} ({exc})")
                continue
            lacking = [c for c in MU_PLOT_COLUMNS if log is not None and c not in log.columns]
            if log is None:
                no_log.append(f"{r.run_id} (missing)")
            elif lacking:
                no_log.append(f"{r.run_id} (no column(s) {', '.join(lacking)})")
            else:
                logs[r.source] = log
        if no_log:
            doc.p(f"Drive logs not drawn over time: {'; '.join(no_log)}.")
        if logs:
            title = f"mu_hat over time, scenario {sc0}, seed {plot_seed}"
            mu = plots.plot_mu_over_time(logs, sources, title, store.figures / "mu_over_time.png")
            doc.image(mu, title)
    failures = store.table("failures")
    fmap = plots.plot_failure_map(
        failures, sources, _scenario_maps(store, runs), store.figures / "failure_map.png"
    )
    doc.image(fmap, "where each catastrophic failure happened")

    if len(failed):
        doc.h(2, "Failed runs")
        doc.table(["run", "error"], [[r.run_id, str(r.error)] for r in failed.itertuples()])
    doc.h(2, "The experiment as run")
    doc.code(yaml.safe_dump(exp, sort_keys=False) if exp else "(experiment.yaml missing)")
    doc.h(2, "Versions")
    env = store.environment()
    if env:
        doc.code(yaml.safe_dump(env, sort_keys=False))
    workers = sorted(set(runs["versions"].astype(str)) - {""})
    if workers:
        doc.p("Package versions on the workers (one line per distinct set):")
        doc.code("\n".join(workers))

    md_path = store.root / "report.md"
    html_path = store.root / "report.html"
    md_path.write_text(doc.markdown(store.root))
    html_path.write_text(doc.html(f"Experiment {name}"))
    return md_path, html_path
